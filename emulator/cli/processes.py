"""`--processes K`: one farm served by K processes, so that its printers use K cores.

This process plans the whole farm, as one process would (numbers, {n} paths, ports, seeds), and
starts K children: each `fake-marlin` with the same arguments, a contiguous part of the plan
(the hidden --slice) and a control socket of its own in a private directory. Each child prints
its printers' paths when they are up; this process prints them all, in order, once every
printer is up, as one process does, and then any later line a child prints (a pty that came
back under a new name). It serves the farm's one --control socket (control/fanout.py hands each
request to the process serving its printer) and the live view (--web).

It stops them all together: on SIGINT, SIGTERM or SIGHUP (the children run in sessions of
their own, so a terminal's Ctrl-C reaches only this process, which passes it on as SIGTERM), or
when a child stops of itself (its own message on stderr says why). A child whose parent dies
without a word sees its standard input close and stops too: no printer outlives the farm.
"""

import os
import signal
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field

import trio

from fake_marlin.emulator.cli.farm import PrinterPlan
from fake_marlin.emulator.cli.links import Address
from fake_marlin.emulator.cli.web import WebUnavailable, said
from fake_marlin.emulator.control.fanout import ChildChannel, FanOut
from fake_marlin.emulator.control.server import serve_control

STOP_GRACE = 30.0  # seconds a child has to stop after SIGTERM (5,000 printers take 6) before it is killed


def split(count: int, processes: int) -> list[tuple[int, int]]:
    """`count` printers in `processes` contiguous parts, as even as can be: (start, stop)."""
    base, extra = divmod(count, processes)
    parts, start = [], 0
    for index in range(processes):
        stop = start + base + (index < extra)
        parts.append((start, stop))
        start = stop
    return parts


def child_command(argv: Sequence[str], start: int, stop: int, control: str) -> list[str]:
    """The command line of the child serving plans[start:stop]: the farm's own arguments, and
    after them the child's (argparse keeps an option's last value)."""
    return [sys.executable, "-m", "fake_marlin.emulator.cli", *argv, "--processes", "1",
            "--slice", f"{start}:{stop}", "--control", control]


class _Lines:
    """Lines of a child's standard output."""

    def __init__(self, stream: trio.abc.ReceiveStream) -> None:
        self._stream = stream
        self._buffer = b""

    async def next(self) -> str | None:
        while b"\n" not in self._buffer:
            data = await self._stream.receive_some(65536)
            if not data:
                return None
            self._buffer += data
        line, self._buffer = self._buffer.split(b"\n", 1)
        return line.decode(errors="replace")


@dataclass
class _Child:
    start: int
    stop: int
    numbers: list[int]
    control: str
    process: trio.Process | None = None
    paths: list[str] = field(default_factory=list)

    @property
    def what(self) -> str:
        return f"the process serving printers {self.numbers[0]} to {self.numbers[-1]}"


@dataclass
class _Farm:
    children: list[_Child]
    ready: trio.Event = field(default_factory=trio.Event)
    stopping: bool = False
    code: int | None = None  # why it ended, if a child ended it

    def child_ended(self, child: _Child, code: int, up: bool, scope: trio.CancelScope) -> None:
        if self.stopping or self.code is not None:
            return
        if up:
            print(f"fake-marlin: {child.what} stopped (exit code {code}); stopping the others",
                  file=sys.stderr, flush=True)
            self.code = 1
        else:
            # Before its printers were up: it said why (a port in use, a file it cannot open).
            self.code = code if code > 0 else 2
        scope.cancel()


def serve_processes(argv: Sequence[str], plans: list[PrinterPlan], processes: int,
                    control: str | None, web: Address | None) -> int:
    """Serve `plans` over `processes` children until a signal or a child's end; the exit code."""
    with tempfile.TemporaryDirectory(prefix="fake-marlin-farm-") as private:
        children = [
            _Child(start, stop, [plan.number for plan in plans[start:stop]],
                   os.path.join(private, f"process-{index + 1}.control"))
            for index, (start, stop) in enumerate(split(len(plans), processes))
        ]
        farm = _Farm(children)
        try:
            try:
                trio.run(_serve, argv, farm, control, web)
            except* WebUnavailable as group:
                farm.code = said(group)
        except KeyboardInterrupt:  # a signal before trio took them over
            pass
        return farm.code or 0


async def _serve(argv: Sequence[str], farm: _Farm, control: str | None,
                 web: Address | None) -> None:
    with trio.open_signal_receiver(signal.SIGINT, signal.SIGTERM, signal.SIGHUP) as signals:
        try:
            async with trio.open_nursery() as nursery:
                for child in farm.children:
                    child.process = await trio.lowlevel.open_process(
                        child_command(argv, child.start, child.stop, child.control),
                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, start_new_session=True,
                    )
                    nursery.start_soon(_watch, farm, child, nursery.cancel_scope)
                nursery.start_soon(_stop_on_signal, farm, signals, nursery.cancel_scope)
                await farm.ready.wait()
                fanout = FanOut([ChildChannel(child.control, child.numbers)
                                 for child in farm.children])
                if control:
                    await nursery.start(serve_control, control, fanout)
                if web is not None:
                    from fake_marlin.emulator.cli.web import start_web

                    await start_web(nursery, web, fanout.farm_source())
                print("\n".join(path for child in farm.children for path in child.paths),
                      flush=True)
        finally:
            with trio.CancelScope(shield=True):
                await _stop_children(farm.children)


async def _watch(farm: _Farm, child: _Child, scope: trio.CancelScope) -> None:
    """Take the child's paths, then pass its later lines on; mark the farm when it ends."""
    assert child.process is not None and child.process.stdout is not None
    lines = _Lines(child.process.stdout)
    while len(child.paths) < len(child.numbers):
        line = await lines.next()
        if line is None:
            farm.child_ended(child, await child.process.wait(), False, scope)
            return
        child.paths.append(line)
    if all(len(other.paths) == len(other.numbers) for other in farm.children):
        farm.ready.set()
    while (line := await lines.next()) is not None:
        print(line, flush=True)
    farm.child_ended(child, await child.process.wait(), True, scope)


async def _stop_on_signal(farm: _Farm, signals, scope: trio.CancelScope) -> None:
    async for _ in signals:
        farm.stopping = True
        scope.cancel()
        return


async def _stop_children(children: list[_Child]) -> None:
    """SIGTERM to every child still running; SIGKILL to any still running STOP_GRACE later."""
    running = [child.process for child in children
               if child.process is not None and child.process.returncode is None]
    for process in running:
        process.terminate()
    with trio.move_on_after(STOP_GRACE):
        for process in running:
            await process.wait()
    for process in running:
        if process.returncode is None:
            process.kill()
            await process.wait()
