"""Our host's g2core protocol: the sans-IO core against scripted board bytes, and the client
over in-memory streams (and the command line over a pty) against a small fake board written
here, until the emulator speaks g2core."""

import os
import threading
import tty
from collections import deque

import pytest
import trio
import trio.testing
from hypothesis import given, settings
from hypothesis import strategies as st

from fake_marlin.host import CommandFailed, open_printer
from fake_marlin.host.cli import main
from fake_marlin.host.codecs import g2core as codec
from fake_marlin.host.connect import PROTOCOLS, connect
from fake_marlin.host.cores.g2core import (
    DRAIN_POLL,
    GREETING_WINDOW,
    SETUP,
    G2coreCore,
    Phase,
)
from fake_marlin.host.errors import (
    CommandError,
    HostError,
    PrinterHalted,
    PrinterNotResponding,
    PrinterReset,
    RemoteError,
)
from fake_marlin.host.shell import ClientOptions
from fake_marlin.wire import g2core as wire

BANNER = (b'{"r":{"fv":0.99,"fb":101.03,"fbs":"101.03","fbc":"settings_default.h","hp":"g2v9",'
          b'"hv":"k","id":"0084-d639-18c6-7bd0","msg":"SYSTEM READY"},"f":[1,0,1]}\n')
SETUP_BYTES = [f"{text}\n".encode() for _, text in SETUP]
SETUP_ANSWERS = {
    "ej": wire.response({"ej": 1}, 0, 10),
    "jv": wire.response({"jv": 4}, 0, 10),
    "qv": wire.response({"qv": 0}, 0, 10),
    "sv": wire.response({"sv": 1}, 0, 10),
    "fb": wire.response({"fb": wire.Number(101.03, 2)}, 0, 10),
    "fv": wire.response({"fv": wire.Number(0.99, 2)}, 0, 10),
    "qr": wire.response({"qr": 48}, 0, 10),
}


def answer(core: G2coreCore, data: bytes, now: float = 0.0) -> list[codec.Line]:
    """The board says `data`; the lines the caller is shown."""
    core.receive_data(data, now)
    shown = []
    while (line := core.next_event()) is not None:
        shown.append(line)
    return shown


def ok(n: int, length: int = 9, status: int = 0, **extra: object) -> bytes:
    return wire.response({"n": n, **extra}, status, length)


def sr(stat: int) -> bytes:
    return wire.response({"sr": {"stat": stat}}, 0, 10)


def qr(room: int) -> bytes:
    return wire.response({"qr": room}, 0, 10)


def connected(window: int = 4, now: float = 0.0) -> G2coreCore:
    """A core that has set the board up, the bytes checked on the way."""
    core = G2coreCore(window=window)
    for (name, _), sent in zip(SETUP, SETUP_BYTES, strict=True):
        assert core.poll(now) == [sent]
        assert answer(core, SETUP_ANSWERS[name], now) == []
    assert core.poll(now) == []
    assert core.phase is Phase.READY and core.firmware_build == 101.03
    return core


def drain(core: G2coreCore, now: float = 0.0, stat: int = 3, room: int = 48) -> None:
    core.request_drained()
    assert core.poll(now) == [b'{"sr":n}\n']
    answer(core, sr(stat), now)
    assert core.poll(now) == [b'{"qr":n}\n']
    answer(core, qr(room), now)
    assert core.poll(now) == []


# -- the core against scripted bytes -------------------------------------------------------
def test_a_small_job_goes_out_as_numbered_lines_and_ends_when_the_board_has_run_it():
    core = connected()
    tickets = [core.submit(text) for text in ("G21", "G0 X1", "M3 S1000")]
    assert core.poll(0) == [b"N1 G21\n", b"N2 G0 X1\n", b"N3 M3 S1000\n"]
    answer(core, ok(1, 7) + ok(2, 9) + ok(3, 12))
    assert [t.done and t.confirmed and t.response == () for t in tickets] == [True] * 3
    assert core.take_completed() == tickets
    assert core.idle  # not asked to wait for the board: every line is answered
    core.request_drained()
    assert not core.idle
    assert core.poll(0) == [b'{"sr":n}\n']
    answer(core, sr(5))  # still moving
    assert core.poll(0) == [b'{"qr":n}\n']
    answer(core, qr(46))
    assert core.poll(0) == [] and not core.idle
    assert core.next_deadline() == DRAIN_POLL
    assert core.poll(DRAIN_POLL) == [b'{"sr":n}\n']
    answer(core, sr(3), DRAIN_POLL)
    assert core.poll(DRAIN_POLL) == [b'{"qr":n}\n']
    answer(core, qr(48), DRAIN_POLL)
    assert core.idle and core.poll(DRAIN_POLL) == []
    assert core.stats.packets_sent == len(SETUP) + 3 + 4 and core.stats.resends == 0


def test_the_board_reporting_program_end_on_its_own_is_checked_at_once():
    core = connected()
    core.submit("G1 X5 F100")
    core.poll(0)
    answer(core, ok(1, 13))
    core.request_drained()
    assert core.poll(0) == [b'{"sr":n}\n']
    answer(core, sr(5))
    core.poll(0)
    answer(core, qr(47))
    assert core.next_deadline() == DRAIN_POLL
    shown = answer(core, b'{"sr":{"stat":4}}\n', 0.1)
    assert [line.kind for line in shown] == [codec.LineKind.REPORT]
    assert core.poll(0.1) == [b'{"sr":n}\n']
    answer(core, sr(4), 0.1)
    core.poll(0.1)
    answer(core, qr(48), 0.1)
    assert core.idle


def test_a_queued_m30_that_has_not_run_is_not_the_end():
    """The stat can still be the last program stop while a queued command waits: the planner
    must be as empty as it was too."""
    core = connected()
    core.submit("M30")
    core.poll(0)
    answer(core, ok(1, 7))
    core.request_drained()
    core.poll(0)
    answer(core, sr(3))
    core.poll(0)
    answer(core, qr(47))
    assert not core.idle


def test_window_lines_in_flight_one_more_per_response():
    core = connected(window=4)
    for n in range(10):
        core.submit(f"G1 X{n}")
    assert core.poll(0) == [f"N{n + 1} G1 X{n}\n".encode() for n in range(4)]
    assert core.poll(0) == []
    answer(core, ok(1))
    assert core.poll(0) == [b"N5 G1 X4\n"]
    answer(core, ok(2) + ok(3))
    assert core.poll(0) == [b"N6 G1 X5\n", b"N7 G1 X6\n"]
    assert core.in_flight == 4


def test_long_lines_are_kept_within_the_boards_receive_ring():
    core = connected(window=8)
    long = "G1 X1 " + "Y1 " * 70  # 216 characters
    for _ in range(6):
        core.submit(long.strip())
    sent = core.poll(0)
    assert len(sent) == 3 and sum(map(len, sent)) <= 768  # not 6: the ring takes 1024


def test_reports_interleaved_with_responses_acknowledge_nothing():
    core = connected(window=2)
    for n in range(4):
        core.submit(f"G1 X{n}")
    assert len(core.poll(0)) == 2
    shown = answer(core, b'{"sr":{"line":0,"posx":0.5,"stat":5}}\n{"qr":44}\n'
                         b'{"prb":{"e":1, "z":-3.210}}\n{"er":{"fb":101.03,"st":29,"msg":"x"}}\n')
    assert [line.kind for line in shown] == [codec.LineKind.REPORT] * 3 + [codec.LineKind.EXCEPTION]
    assert core.poll(0) == [] and core.take_completed() == []
    assert core.room == 44 and core.machine_state == 5
    answer(core, b'{"sr":{"posx":1}}\n' + ok(1) + b'{"qr":45}\n' + ok(2))
    assert core.poll(0) == [b"N3 G1 X2\n", b"N4 G1 X3\n"]
    assert [t.text for t in core.take_completed()] == ["G1 X0", "G1 X1"]


def test_a_non_zero_status_is_an_error_naming_the_line_status_and_message():
    core = connected()
    core.submit("G0 X1")
    core.submit("M999")
    core.poll(0)
    answer(core, ok(1))
    with pytest.raises(CommandFailed) as raised:
        answer(core, ok(2, 7, status=132, msg="M code unsupported"))
    assert raised.value.status == 132
    assert str(raised.value) == "the board refused line 2 ('M999'): status 132 (M code unsupported)"
    assert isinstance(raised.value, RemoteError)


def test_the_boards_own_words_are_added_to_the_message():
    core = connected()
    core.submit("G1 X900")
    core.poll(0)
    with pytest.raises(CommandFailed, match=r"status 220 \(a status g2core does not list\): Soft limit"):
        answer(core, ok(1, status=220, msg="Soft limit exceeded - X max"))


@pytest.mark.parametrize("status", [3, 4])
def test_informational_statuses_complete_the_line(status):
    core = connected()
    ticket = core.submit("/G1 X1")
    core.poll(0)
    answer(core, ok(1, status=status))
    assert ticket.done and core.stats.noops == 1 and core.stats.rejects == 0


def test_the_banner_first_is_the_greeting_and_gives_the_firmware():
    core = G2coreCore()
    assert [line.kind for line in answer(core, BANNER)] == [codec.LineKind.BOOT]
    assert core.greeted and core.firmware_build == 101.03 and core.firmware_version == 0.99
    assert core.poll(0) == [SETUP_BYTES[0]]


def test_the_banner_arriving_mid_connect_starts_the_settings_again():
    core = G2coreCore()
    assert core.poll(0) == [b'{"ej":1}\n']
    answer(core, SETUP_ANSWERS["ej"])
    assert core.poll(0) == [b'{"jv":4}\n']
    answer(core, BANNER, 0.1)  # not jv's answer, however it looks
    assert core.poll(0.1) == [b'{"ej":1}\n']  # the board reset ej, sv, qv before it
    answer(core, SETUP_ANSWERS["jv"], 0.1)  # jv's late answer is passed over
    assert core.poll(0.1) == []
    for (asked, _), sent in zip(SETUP, SETUP_BYTES[1:]):
        answer(core, SETUP_ANSWERS[asked], 0.1)
        assert core.poll(0.1) == [sent]
    answer(core, SETUP_ANSWERS["qr"], 0.1)
    assert core.phase is Phase.READY


def test_the_banner_while_lines_are_in_flight_is_no_answer_but_a_restart():
    core = connected()
    core.submit("G0 X1")
    core.poll(GREETING_WINDOW + 1)
    with pytest.raises(PrinterReset, match="restarted"):
        answer(core, BANNER, GREETING_WINDOW + 1)


def test_a_late_greeting_of_a_marlin_compatible_build_is_no_restart():
    """Such a build greets a USB host 2 s after the port opens; the host may have begun."""
    core = connected()
    ticket = core.submit("G0 X1")
    core.poll(0.6)
    answer(core, BANNER, 2.0)
    assert not ticket.done
    answer(core, ok(1), 2.1)
    assert ticket.done
    core.submit("G0 X2")
    core.poll(2.2)
    with pytest.raises(PrinterReset):
        answer(core, BANNER, 2.3)  # a second one is a restart


def test_garbage_and_non_json_lines_are_shown_and_passed_over():
    core = connected()
    ticket = core.submit("G0 X1")
    core.poll(0)
    shown = answer(core, b"g2core[mm] ok> \n\xff\xfe{\"r\n{\"r\":{\"n\":1},\"f\":[1,0\n[1,2]\n\r\n")
    assert [line.kind for line in shown] == [codec.LineKind.NOISE] * 4
    assert core.corrupt_frames == 2  # the bytes no board sends, and the broken `{` line
    assert not ticket.done
    answer(core, ok(1))
    assert ticket.done


def test_a_response_to_a_later_line_means_one_was_lost():
    core = connected()
    for n in range(3):
        core.submit(f"G1 X{n}")
    core.poll(0)
    answer(core, ok(1))
    with pytest.raises(PrinterNotResponding, match="answered line 3 before line.s. 2"):
        answer(core, ok(3))


def test_a_response_without_n_is_matched_in_order():
    core = connected()
    first, second = core.submit("G1 X1"), core.submit("G1 X2")
    core.poll(0)
    answer(core, wire.response({}, 0, 9))
    assert first.done and not second.done


def test_a_callers_json_request_goes_alone_and_its_answer_is_the_response():
    core = connected()
    core.submit("G1 X1")
    request = core.submit('{"posx":n}')
    core.submit("G1 X2")
    assert core.poll(0) == [b"N1 G1 X1\n"]
    answer(core, ok(1))
    assert core.poll(0) == [b'{"posx":n}\n']
    assert core.poll(0) == []
    answer(core, wire.response({"posx": 1}, 0, 12))
    assert request.response == ('{"posx":1}',)
    assert core.poll(0) == [b"N2 G1 X2\n"]


def test_a_callers_request_the_board_refuses_is_an_error():
    core = connected()
    core.submit('{"foo":n}')
    core.poll(0)
    with pytest.raises(CommandFailed, match=r'\{"foo":n\}: status 100 \(Unrecognized command'):
        answer(core, wire.response({"foo": None}, 100, 11))


def test_a_silent_board_is_asked_for_its_status_and_lines_are_never_sent_twice():
    core = connected()
    core.submit("G4 P30")
    assert core.poll(0) == [b"N1 G4 P30\n"]
    assert core.next_deadline() == 2.0
    assert core.poll(2.0) == [b'{"sr":n}\n']
    answer(core, sr(5), 2.1)
    assert core.poll(2.1) == [b'{"qr":n}\n']
    answer(core, qr(3), 2.1)  # the planner is full: it reads nothing, rightly
    for t in (4.1, 6.1, 8.1):
        assert core.poll(t) == [b'{"sr":n}\n']
        answer(core, sr(5), t)
        assert core.poll(t) == [b'{"qr":n}\n']
        answer(core, qr(3), t)
    answer(core, ok(1), 9)
    assert core.stats.timeouts == 4 and core.stats.resends == 0


def test_a_line_unanswered_by_a_board_with_room_to_read_it_was_lost():
    core = connected()
    core.submit("G0 X1")
    core.poll(0)
    core.poll(2.0)
    answer(core, sr(3), 2.0)
    core.poll(2.0)
    answer(core, qr(48), 2.0)
    assert core.poll(4.0) == [b'{"sr":n}\n']
    answer(core, sr(3), 4.0)
    core.poll(4.0)
    with pytest.raises(PrinterNotResponding, match="line 1 .'G0 X1'. has had no answer"):
        answer(core, qr(48), 4.0)


def test_lines_held_by_a_feedhold_wait_for_resume():
    core = connected()
    core.submit("G1 X100 F10")
    core.submit("G1 X0")
    core.poll(0)
    answer(core, ok(1, 13))
    core.feedhold()
    assert core.poll(0.5) == [b"!"]
    for t in (2.5, 4.5, 6.5, 8.5):
        assert core.poll(t) == [b'{"sr":n}\n']
        answer(core, sr(6), t)
        assert core.poll(t) == []  # held: no queue check, no stall
    core.resume()
    assert core.poll(9) == [b"~"]
    answer(core, ok(2), 9.5)
    assert core.idle


def test_an_unanswered_setup_is_asked_again_then_given_up():
    core = G2coreCore(timeout=1.0, max_transmissions=3)
    assert core.poll(0) == [b'{"ej":1}\n']
    assert core.poll(1.0) == [b'{"ej":1}\n']
    assert core.poll(2.0) == [b'{"ej":1}\n']
    with pytest.raises(PrinterNotResponding, match="is a g2core board on the port"):
        core.poll(3.0)
    assert core.stats.resends == 2


def test_an_alarm_while_draining_is_a_halt():
    core = connected()
    core.submit("G1 X1")
    core.poll(0)
    answer(core, ok(1))
    core.request_drained()
    core.poll(0)
    with pytest.raises(PrinterHalted, match="ALARM"):
        answer(core, sr(2))


def test_an_alarm_reported_while_lines_are_in_flight_is_a_halt():
    core = connected()
    core.submit("G1 X1")
    core.poll(0)
    answer(core, b'{"er":{"fb":101.03,"st":203,"msg":"Limit hit"}}\n')
    with pytest.raises(PrinterHalted, match="ALARM"):
        answer(core, b'{"sr":{"stat":2}}\n')


def test_cancel_kills_the_job_and_drops_what_the_board_did_not_read():
    core = connected()
    tickets = [core.submit(f"G1 X{n}") for n in range(8)]
    core.poll(0)
    answer(core, ok(1))
    core.poll(0)
    core.cancel()
    assert core.poll(0.1) == [b"\x04", b'{"sr":n}\n']
    answer(core, ok(2) + b'{"er":{"fb":101.03,"st":207,"msg":"Kill job - Job killed by ^d"}}\n'
           + b'{"sr":{"stat":4}}\n', 0.1)
    assert not core.idle
    answer(core, sr(4), 0.1)
    assert [t.confirmed for t in tickets] == [True, True] + [False] * 6
    assert all(t.done for t in tickets) and core.stats.cancelled == 6
    drain(core, 0.1, stat=4)
    assert core.idle


def test_cancel_on_a_100_board_clears_the_alarm_its_kill_leaves():
    core = G2coreCore()
    answers = dict(SETUP_ANSWERS, fb=wire.response({"fb": wire.Number(100.26, 2)}, 0, 10))
    for name, _ in SETUP:
        core.poll(0)
        answer(core, answers[name])
    core.submit("G1 X1")
    core.poll(0)
    core.cancel()
    assert core.poll(0) == [b"\x04", b'{"sr":n}\n']
    answer(core, sr(2))  # the kill is an alarm on 100.x
    assert core.poll(0) == [b'{"clear":n}\n']
    answer(core, wire.response({}, 0, 12))
    drain(core, stat=1)
    assert core.idle


@pytest.mark.parametrize("command, reason", [
    ("", "white space"),
    (" G1", "white space"),
    ("G1 X1\x04", "not printable"),
    ("!", "single-character"),
    ("~", "single-character"),
    ("%", "single-character"),
    ("$xvm", "text-mode"),
    ("N5 G1 X1", "numbers the lines"),
    ("G1 X1*23", "checksum"),
    ("M100.1 ({sr:n})", "M100.1"),
    ("G1" + " X1" * 90, "characters"),
    ("{xvm:", "refuse"),
    ('{"jv":0}', "keeps jv"),
    ("{ej:0}", "keeps ej"),
])
def test_commands_that_cannot_be_sent_are_refused(command, reason):
    with pytest.raises(CommandError, match=reason):
        codec.check_command(command)


@pytest.mark.parametrize("command", ["G1 X1 Y2 F3000", "M117 hello", '{"sr":n}', "{xvm:n}",
                                     '{"jv":n}', "/G1 X1", "(a comment only)"])
def test_commands_that_can_be_sent(command):
    assert codec.check_command(command) == command


# -- never a traceback ---------------------------------------------------------------------
BOARD_LINES = st.one_of(
    st.binary(max_size=40),
    st.sampled_from([BANNER, b'{"sr":{"stat":5}}\n', b'{"sr":{"stat":2}}\n', b'{"qr":47}\n',
                     b'{"er":{"fb":101.03,"st":207,"msg":"Kill job"}}\n', b'{"sr":[1]}\n',
                     b'{"r":[],"f":[1,0,9]}\n', b'{"r":{"n":"x"},"f":[1,0,9]}\n', b"[" * 3000 + b"\n",
                     b'{"r":{"sr":{"stat":"5"}},"f":[1,0,9]}\n', b'{"r":{"qr":1e999},"f":[1,0,9]}\n',
                     b'{"f":[true,false,true]}\n', b'{"r":{"fb":NaN},"f":[1,0,2]}\n']),
    st.builds(lambda n, status, length: ok(n, length, status),
              st.integers(-2, 12), st.sampled_from([0, 0, 0, 3, 4, 100, 132]), st.integers(0, 12)),
    st.builds(lambda name, value, status: wire.response({name: value}, status, 10),
              st.sampled_from([name for name, _ in SETUP] + ["sr", "clear", "posx"]),
              st.one_of(st.integers(-5, 60), st.none(), st.just({"stat": 3})), st.sampled_from([0, 100])),
)


@settings(max_examples=500, deadline=None)
@given(lines=st.lists(st.tuples(BOARD_LINES, st.integers(1, 30), st.floats(0, 3)), max_size=25),
       setup_done=st.booleans(), cancel_at=st.integers(0, 30))
def test_the_core_never_raises_on_arbitrary_board_bytes(lines, setup_done, cancel_at):
    core = connected() if setup_done else G2coreCore()
    for n in range(10):
        core.submit(f"G1 X{n}")
    core.submit('{"posx":n}')
    core.request_drained()
    now = 0.0
    try:
        for index, (data, cut, later) in enumerate(lines):
            now += later
            if index == cancel_at:
                core.cancel()
            core.poll(now)
            for chunk in (data[:cut], data[cut:]):
                answer(core, chunk, now)
            core.poll(now)
            deadline = core.next_deadline()
            assert deadline is None or deadline > now  # the shell would poll in a busy loop
            core.take_completed()
    except RemoteError:
        pass  # the board's words ended the session: said as the error it is


# -- the client over a stream, against a fake board ----------------------------------------
class FakeBoard:
    """A few lines of g2core: JSON requests scanned ahead of G-code waiting in its receive
    buffer, G-code read only while its planner has 4 of 48 buffers free, one response per line,
    moves that take `move_time` each, and filtered status reports of `stat` as it changes."""

    PLANNER = 48

    def __init__(self, stream, move_time=0.05, statuses=None, banner=True, fb=101.03) -> None:
        self.stream = stream
        self._sending = trio.Lock()  # the reader and the motion task both write
        self.move_time = move_time
        self.statuses = statuses or {}  # G-code text -> the status its response carries
        self.banner = banner
        self.fb = fb
        self.rx = bytearray()
        self.planner: deque[str] = deque()
        self.stat = 1
        self.lines: list[str] = []  # G-code read, without its N
        self.requests: list[str] = []
        self.ran: list[str] = []
        self.most_in_rx = 0
        self._moved = trio.Event()

    async def _send(self, data: bytes) -> None:
        async with self._sending:
            await self.stream.send_all(data)

    async def run(self) -> None:
        async with trio.open_nursery() as nursery:
            nursery.start_soon(self._motion)
            if self.banner:
                await self._send(BANNER)
            while True:
                data = await self.stream.receive_some(4096)
                if not data:
                    return
                self.rx += data
                await self._read()

    async def _read(self) -> None:
        at = 0
        while at < len(self.rx):  # single characters, first on a line, need no line feed
            if (at == 0 or self.rx[at - 1] == ord("\n")) and self.rx[at] in b"!~\x04":
                char = self.rx[at]
                del self.rx[(0 if char == wire.KILL_JOB else at):at + 1]  # ^D drops what came before it
                await self._control(bytes([char]))
                at = 0
                continue
            at += 1
        while True:
            lines = bytes(self.rx).split(b"\n")[:-1]
            self.most_in_rx = max(self.most_in_rx, len([line for line in lines if not line.startswith(b"{")]))
            control = next((line for line in lines if line.startswith(b"{")), None)
            if control is not None:
                index = self.rx.index(control + b"\n")
                del self.rx[index:index + len(control) + 1]
                await self._control(control)
                continue
            if lines and self.PLANNER - len(self.planner) >= wire.PLANNER_HEADROOM:
                line = lines[0]
                del self.rx[:len(line) + 1]
                await self._gcode(line.decode())
                continue
            return

    async def _control(self, line: bytes) -> None:
        text = line.decode()
        self.requests.append(text)
        if text in "!~":
            return  # (no cycle to hold in this board)
        if text == "\x04":  # (what came before it is dropped already)
            self.planner.clear()
            await self._send(wire.report("er", {"fb": wire.Number(self.fb, 2), "st": 207,
                                                          "msg": "Kill job - Job killed by ^d"}))
            await self._state(4)
            return
        (name, value), = wire.parse_request(text).items()
        values = {"fb": wire.Number(self.fb, 2), "fv": wire.Number(0.99, 2),
                  "qr": self.PLANNER - len(self.planner), "sr": {"stat": self.stat},
                  "posx": wire.Number(1.5, 3)}
        if name in ("ej", "jv", "qv", "sv"):
            body, status = {name: value}, 0
        elif name in values:
            body, status = {name: values[name]}, 0
        else:
            body, status = {name: None}, 100
        await self._send(wire.response(body, status, len(line) + 2))

    async def _gcode(self, line: str) -> None:
        number, _, text = line.partition(" ")
        self.lines.append(text)
        status = self.statuses.get(text, 0)
        if status == 0 and text.startswith(("G0", "G1")):
            self.planner.append(text)
            self._moved.set()
            await self._state(5)
        await self._send(wire.response({"n": int(number[1:])}, status, len(line) + 1))

    async def _state(self, stat: int) -> None:
        if stat != self.stat:
            self.stat = stat
            await self._send(wire.report("sr", {"stat": stat}))

    async def _motion(self) -> None:
        while True:
            while not self.planner:
                self._moved = trio.Event()
                await self._moved.wait()
            await trio.sleep(self.move_time)
            if self.planner:
                self.ran.append(self.planner.popleft())
            if not self.planner:
                await self._state(3)
            await self._read()


async def with_board(board_kwargs, body, protocol="g2core", options=ClientOptions()):
    host_end, board_end = trio.testing.memory_stream_pair()
    board = FakeBoard(board_end, **board_kwargs)
    failure = None
    async with trio.open_nursery() as nursery:
        nursery.start_soon(board.run)
        try:
            async with connect(host_end, protocol, options) as client:
                await body(client, board)
        except HostError as error:  # raised as itself, not in the board's nursery's group
            failure = error
        finally:
            nursery.cancel_scope.cancel()
    if failure is not None:
        raise failure
    return board


JOB = ["G21", "G90", *(f"G1 X{n % 20} Y{n % 7} F6000" for n in range(120)), "M5"]


def test_g2core_is_a_protocol_of_the_host():
    assert "g2core" in PROTOCOLS


async def test_a_print_sends_every_line_once_in_order_and_ends_when_the_board_has_run_it(autojump_clock):
    async def body(client, board):
        done = []
        summary = await client.print_commands(JOB, progress=done.append)
        assert summary.commands == len(JOB) and done[-1] == len(JOB)
        assert board.stat == 3 and not board.planner  # it returned once the moves had run
        assert board.ran == [line for line in JOB if line.startswith("G1")]
        assert summary.resends == summary.timeouts == summary.unconfirmed == 0
        assert client.firmware_build == 101.03

    board = await with_board({}, body)
    assert board.lines == JOB
    assert board.requests[:len(SETUP)] == [text for _, text in SETUP]
    assert board.most_in_rx == 3  # the window (ClientOptions' default), once the planner is full


async def test_the_window_option_sets_the_lines_in_flight(autojump_clock):
    async def body(client, board):
        await client.print_commands(JOB)

    board = await with_board({"move_time": 0.01}, body, options=ClientOptions(window=6))
    assert board.most_in_rx == 6


async def test_send_returns_a_requests_answer_and_waits_for_a_move(autojump_clock):
    async def body(client, board):
        assert await client.send("G0 X1") == ()
        assert board.ran == ["G0 X1"] and board.stat == 3
        assert await client.send('{"posx":n}') == ('{"posx":1.5}',)

    await with_board({"banner": False}, body)


async def test_a_refused_line_ends_the_session_with_the_error(autojump_clock):
    async def body(client, board):
        await client.print_commands(["G21", "M104 S200", "G1 X1"])

    with pytest.raises(CommandFailed, match=r"line 2 \('M104 S200'\): status 132 \(M code unsupported\)"):
        await with_board({"statuses": {"M104 S200": 132}}, body)


async def test_cancel_stops_the_board_and_the_client_is_idle_again(autojump_clock):
    async def body(client, board):
        async with trio.open_nursery() as nursery:
            async def printing():
                await client.print_commands(JOB)

            nursery.start_soon(printing)
            while len(board.ran) < 10:
                await trio.sleep(0.01)
            nursery.cancel_scope.cancel()
        await client.cancel()
        assert board.stat == 4 and not board.planner
        assert await client.send("G0 X0") == ()  # and it goes on

    board = await with_board({}, body)
    assert board.lines[-1] == "G0 X0" and "\x04" in board.requests
    assert len(board.ran) < len(JOB)


async def test_a_silent_port_is_given_up_on(autojump_clock):
    host_end, _board_end = trio.testing.memory_stream_pair()
    with pytest.raises(PrinterNotResponding, match="g2core board"):
        async with connect(host_end, "g2core") as client:
            await client.send("G0 X1")


# -- the library's open_printer and the command line, over a pty ---------------------------
class PtyBoard:
    """The fake board on a pty's master side, in a thread with its own trio loop."""

    def __init__(self) -> None:
        self.master, slave = os.openpty()
        tty.setraw(slave)  # no echo of the board's lines back to it before a host opens the port
        self.path = os.ttyname(slave)
        self._slave = slave  # kept open, so the master sees no hang-up between hosts
        self.boards: list[FakeBoard] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=trio.run, args=(self._serve,), daemon=True)

    def __enter__(self) -> "PtyBoard":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(5)
        os.close(self.master)
        os.close(self._slave)

    async def _serve(self) -> None:
        stream = trio.lowlevel.FdStream(os.dup(self.master))
        board = FakeBoard(stream, move_time=0.001, banner=False)
        self.boards.append(board)
        async with trio.open_nursery() as nursery:
            nursery.start_soon(board.run)
            while not self._stop.is_set():
                await trio.sleep(0.01)
            nursery.cancel_scope.cancel()


async def test_open_printer_speaks_g2core():
    with PtyBoard() as pty:
        with trio.fail_after(20):
            async with open_printer(pty.path, protocol="g2core") as printer:
                assert await printer.send("G0 X2") == ()
        assert pty.boards[0].lines == ["G0 X2"]


def test_the_command_line_prints_and_sends_with_protocol_g2core(tmp_path, capsys):
    job = tmp_path / "job.gcode"
    job.write_text("G21 ; millimetres\nG1 X1 F600\n\nG1 X2\n")
    with PtyBoard() as pty:
        assert main(["print", "--protocol", "g2core", "--json", pty.path, str(job)]) == 0
        assert main(["send", "--protocol", "g2core", pty.path, '{"posx":n}']) == 0
        assert pty.boards[0].lines == ["G21", "G1 X1 F600", "G1 X2"]
    out = capsys.readouterr().out.splitlines()
    assert '"commands": 3' in out[0] and out[1] == '{"posx":1.5}'
