"""A link waiting for its next bytes straight in poll(2) while trio is idle (link/direct_wait.py):
it must save trio's round per command, and never delay or starve anything trio would have run;
it reads trio's private run state only on the releases verified, and nowhere when told not to.

These run on trio's real clock, with a thread as the host on the other end of a pipe: the direct
wait is only taken where trio would block in epoll_wait itself, which an autojump clock never
does.
"""

import os
import termios
import threading
import tty
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
import trio

from fake_marlin.emulator.link import direct_wait
from fake_marlin.emulator.link.base import HostOpened
from fake_marlin.emulator.link.pty import PtyLink
from fake_marlin.emulator.link.direct_wait import (
    VERIFIED_TRIO,
    WAITS_VARIABLE,
    DirectWait,
    direct_waits_available,
    waits_in_use,
)

HOST_GIVES_UP = 10.0  # seconds: a wait that hangs fails the test instead of the suite
# What only direct waits do (no trip through trio per line): shown where they are in use.
needs_direct_waits = pytest.mark.skipif(not waits_in_use()[0], reason=waits_in_use()[1])


@contextmanager
def pipes() -> Iterator[tuple[int, int, int, int]]:
    """(printer reads, host writes, host reads, printer writes)."""
    to_printer_r, to_printer_w = os.pipe()
    to_host_r, to_host_w = os.pipe()
    os.set_blocking(to_printer_r, False)
    try:
        yield to_printer_r, to_printer_w, to_host_r, to_host_w
    finally:
        for fd in (to_printer_r, to_printer_w, to_host_r, to_host_w):
            os.close(fd)


def start_thread(target, *args) -> threading.Thread:
    thread = threading.Thread(target=target, args=args, daemon=True)
    thread.start()
    return thread


@pytest.fixture
def trio_waits(monkeypatch) -> list[int]:
    """The fds waited for through trio's own wait_readable, in order."""
    waited: list[int] = []
    real = trio.lowlevel.wait_readable

    async def counting(fd):
        waited.append(fd)
        await real(fd)

    monkeypatch.setattr(direct_wait.trio.lowlevel, "wait_readable", counting)
    return waited


@pytest.fixture
def fresh_verdict(monkeypatch) -> Iterator[None]:
    """waits_in_use() decided again under the test's environment, and again after it."""
    monkeypatch.delenv(WAITS_VARIABLE, raising=False)
    waits_in_use.cache_clear()
    yield
    waits_in_use.cache_clear()


async def test_a_verified_trio_lets_a_link_wait_directly(fresh_verdict):
    # The verification itself: on a release in the list, trio's run state has the shape read
    # (if not, every wait still works, through trio, at a scheduler round per command).
    if trio.__version__ not in VERIFIED_TRIO:
        pytest.skip(f"trio {trio.__version__} is not verified (see link/direct_wait.py)")
    assert waits_in_use()[0] and direct_waits_available()
    assert waits_in_use()[1] == (
        f"trio {trio.__version__}: direct waits (a verified release; "
        "FAKE_MARLIN_WAITS=trio turns them off)"
    )


async def test_an_unverified_trio_gets_trios_own_waits(fresh_verdict, monkeypatch, trio_waits):
    monkeypatch.setattr(direct_wait.trio, "__version__", "0.99.0")
    assert not waits_in_use()[0] and not direct_waits_available()
    assert waits_in_use()[1] == (
        f"trio 0.99.0: trio's own waits (direct waits are verified on trio {VERIFIED_TRIO[0]} "
        f"to {VERIFIED_TRIO[-1]} only)"
    )
    printer_in = await answer_lines(20)
    assert trio_waits.count(printer_in) == 20  # every wait through trio, and every line read


async def test_the_variable_turns_direct_waits_off(fresh_verdict, monkeypatch, trio_waits):
    monkeypatch.setenv(WAITS_VARIABLE, "trio")
    assert waits_in_use()[1] == f"trio {trio.__version__}: trio's own waits (FAKE_MARLIN_WAITS=trio)"
    printer_in = await answer_lines(20)
    assert trio_waits.count(printer_in) == 20


async def answer_lines(lines: int) -> int:
    """A host thread sends `lines` lines, each once the one before is answered; the printer
    waits for each with one DirectWait and answers `ok`. Returns the fd the printer read."""
    with pipes() as (printer_in, host_out, host_in, printer_out):
        def host() -> None:
            for number in range(lines):
                os.write(host_out, b"G1 X%d\n" % number)
                assert os.read(host_in, 16) == b"ok\n"

        wait = DirectWait(printer_in)
        thread = start_thread(host)
        with trio.fail_after(HOST_GIVES_UP):
            for _ in range(lines):
                await wait.readable()
                assert os.read(printer_in, 64).startswith(b"G1 X")
                os.write(printer_out, b"ok\n")
        thread.join()
    return printer_in


@needs_direct_waits
async def test_a_host_sending_a_line_at_a_time_costs_no_trip_through_trio(trio_waits):
    printer_in = await answer_lines(200)
    # The first wait, before the loop was alone, may go through trio; the steady state never.
    assert trio_waits.count(printer_in) <= 2


async def test_a_task_woken_with_the_waiter_runs_before_the_waiter_blocks():
    # Woken in one batch, the other task sits in trio's loop, not in its run queue: the waiter
    # must not block in poll(2) ahead of it. Here that task is the only one that makes the fd
    # readable, so a wrong wait sleeps until the watchdog writes. Trio runs a batch in either
    # order, so the waiter goes first in some of the rounds.
    with pipes() as (printer_in, host_out, _, _):
        wait = DirectWait(printer_in)  # one, as a link has: what it knows must not mislead it
        for _ in range(12):
            go = trio.Event()
            order: list[str] = []

            async def waiter() -> None:
                await go.wait()
                await wait.readable()
                order.append("readable")

            async def writer() -> None:
                await go.wait()
                order.append("writer ran")
                os.write(host_out, b"x")

            watchdog = threading.Timer(2.0, os.write, (host_out, b"w"))
            watchdog.start()
            try:
                async with trio.open_nursery() as nursery:
                    nursery.start_soon(waiter)
                    nursery.start_soon(writer)
                    await trio.sleep(0.001)
                    go.set()
            finally:
                watchdog.cancel()
            assert order == ["writer ran", "readable"]
            os.read(printer_in, 16)


async def test_a_task_the_waiter_wakes_runs_before_its_next_direct_wait():
    # The printer's own work wakes a task (as a session wakes its executor): that task is in
    # the run queue and must run before the printer blocks for the next line. Every other line
    # is answered by that task, woken right after a direct wait, the others by the printer; the
    # host sends each line once the one before is answered: a wrong wait hangs.
    lines = 20
    with pipes() as (printer_in, host_out, answers, answer):
        def host() -> None:
            for _ in range(lines):
                os.write(host_out, b"G28\n")
                os.read(answers, 1)

        send, receive = trio.open_memory_channel[int](lines)

        async def woken() -> None:
            async for _ in receive:
                os.write(answer, b"w")

        wait = DirectWait(printer_in)
        thread = start_thread(host)
        with trio.fail_after(5):
            async with trio.open_nursery() as nursery:
                nursery.start_soon(woken)
                for number in range(lines):
                    await wait.readable()
                    os.read(printer_in, 64)
                    if number % 2:
                        send.send_nowait(number)
                    else:
                        os.write(answer, b"p")
                send.close()
        thread.join()


async def wait_while(host, *tasks) -> list[str]:
    """The printer waits for its fd while `tasks` wait for theirs and the host thread acts;
    what happened, in order."""
    with pipes() as (printer_in, host_out, _, _):
        order: list[str] = []
        with trio.fail_after(HOST_GIVES_UP):
            async with trio.open_nursery() as nursery:
                for task in tasks:
                    nursery.start_soon(task, order)
                await trio.sleep(0.01)  # each waits now
                start_thread(host, host_out)
                await DirectWait(printer_in).readable()
                order.append("printer")
        return order


def printer_bytes_after(seconds: float):
    def host(host_out: int) -> None:
        threading.Event().wait(seconds)
        os.write(host_out, b"G28\n")
    return host


async def test_a_timer_fires_on_time_while_the_link_waits_directly():
    async def sleeper(order: list[str]) -> None:
        await trio.sleep(0.1)
        order.append("timer")

    assert await wait_while(printer_bytes_after(0.6), sleeper) == ["timer", "printer"]


async def test_another_fd_is_served_while_the_link_waits_directly():
    other_r, other_w = os.pipe()

    async def other_reader(order: list[str]) -> None:
        await trio.lowlevel.wait_readable(other_r)
        order.append("other fd")

    def host(host_out: int) -> None:
        threading.Event().wait(0.1)
        os.write(other_w, b"x")
        printer_bytes_after(0.5)(host_out)

    try:
        assert await wait_while(host, other_reader) == ["other fd", "printer"]
    finally:
        os.close(other_r)
        os.close(other_w)


async def test_a_thread_finishing_is_heard_while_the_link_waits_directly():
    async def thread_result(order: list[str]) -> None:
        await trio.to_thread.run_sync(threading.Event().wait, 0.1)
        order.append("thread")

    assert await wait_while(printer_bytes_after(0.6), thread_result) == ["thread", "printer"]


async def test_a_task_waiting_for_all_to_block_is_woken_while_the_link_waits_directly():
    async def idle_waiter(order: list[str]) -> None:
        await trio.testing.wait_all_tasks_blocked(0.05)
        order.append("all blocked")

    assert await wait_while(printer_bytes_after(0.6), idle_waiter) == ["all blocked", "printer"]


async def cut_off_by(seconds: float) -> bool:
    """Whether a direct wait is cancelled by a deadline `seconds` away, where the host's bytes
    come only after HOST_GIVES_UP real seconds: a wait that slept past the deadline returns
    readable instead."""
    with pipes() as (printer_in, host_out, _, _):
        late = threading.Timer(HOST_GIVES_UP, os.write, (host_out, b"late\n"))
        late.start()
        try:
            with trio.move_on_after(seconds) as scope:
                await DirectWait(printer_in).readable()
        finally:
            late.cancel()
        return scope.cancelled_caught


async def test_a_deadline_cancels_a_direct_wait_on_time():
    assert await cut_off_by(0.05)


async def test_an_autojump_clock_is_never_blocked_by_a_direct_wait(autojump_clock):
    # The autojump clock moves time when every task is blocked; a wait in poll(2) would stop
    # it, and 1000 virtual seconds would take the late bytes' real ones.
    assert await cut_off_by(1000)


async def test_an_instrument_of_io_waits_hears_every_wait():
    # An instrument's before_io_wait/after_io_wait hooks are trio's promise to tell of each of
    # its waits: with one installed, every wait is trio's own.
    class CountWaits(trio.abc.Instrument):
        waits = 0

        def before_io_wait(self, timeout: float) -> None:
            self.waits += 1

    lines = 50
    instrument = CountWaits()
    trio.lowlevel.add_instrument(instrument)
    try:
        await answer_lines(lines)
    finally:
        trio.lowlevel.remove_instrument(instrument)
    assert instrument.waits >= lines


# -- PtyLink.receive_now: the printer's read loop without receive()'s awaits -----------------
@contextmanager
def pty_host() -> Iterator[tuple[PtyLink, int]]:
    """A PtyLink and a host's fd on it, opened (and flushed, as pyserial's open does)."""
    link = PtyLink()
    host = os.open(link.path, os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(host)
        termios.tcflush(host, termios.TCIFLUSH)
        yield link, host
    finally:
        os.close(host)
        link.close()


@needs_direct_waits
async def test_a_pty_link_reads_line_after_line_without_awaiting_while_trio_is_idle():
    lines = 100
    with pty_host() as (link, host):
        def host_side() -> None:
            for number in range(lines):
                os.write(host, b"G1 X%d\n" % number)
                assert os.read(host, 16) == b"ok\n"

        with trio.fail_after(HOST_GIVES_UP):
            assert isinstance(await link.receive(), HostOpened)  # the open
            thread = start_thread(host_side)
            received, awaited = b"", 0
            while received.count(b"\n") < lines:
                data = link.receive_now()
                if data is None:
                    awaited += 1
                    data = await link.receive()
                    assert isinstance(data, bytes)
                received += data
                link.send(b"ok\n")
        thread.join()
    assert received == b"".join(b"G1 X%d\n" % number for number in range(lines))
    assert awaited <= 2


async def test_what_receive_now_reads_but_is_no_data_comes_from_receive():
    # The host opens the port again (a reset): the notice receive_now() reads on its way is
    # neither lost nor taken for data.
    with pty_host() as (link, host):
        with trio.fail_after(HOST_GIVES_UP):
            assert isinstance(await link.receive(), HostOpened)
            start_thread(lambda: termios.tcflush(os.open(link.path, os.O_RDWR | os.O_NOCTTY),
                                                 termios.TCIFLUSH))
            assert link.receive_now() is None
            assert isinstance(await link.receive(), HostOpened)


async def test_receive_now_leaves_the_bytes_to_receive_while_another_task_is_due():
    with pty_host() as (link, host):
        with trio.fail_after(HOST_GIVES_UP):
            assert isinstance(await link.receive(), HostOpened)
            os.write(host, b"G28\n")
            async with trio.open_nursery() as nursery:
                nursery.start_soon(trio.sleep, 0)  # due to run: the link must not block
                assert link.receive_now() is None
            assert await link.receive() == b"G28\n"
