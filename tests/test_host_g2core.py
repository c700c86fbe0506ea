"""Our host's g2core protocol: the sans-IO core against scripted board bytes, and the client
over in-memory streams (and the command line over a pty) against a small fake board written
here, and against the emulator's board with faults on the line."""

import os
import re
import threading
import tty
from collections import deque

import pytest
import trio
import trio.testing
from hypothesis import given, settings
from hypothesis import strategies as st

from fake_marlin.emulator.protocols.base import CommandReceived
from fake_marlin.emulator.protocols.g2core import BadLine, G2coreProtocol
from fake_marlin.host import CommandFailed, open_printer
from fake_marlin.host.cli import main
from fake_marlin.host.codecs import g2core as codec
from fake_marlin.host.connect import PROTOCOLS, connect
from fake_marlin.host.cores.g2core import (
    DRAIN_POLL,
    LINE_QUERY,
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
from fake_marlin.wire.checksums import xor8

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
    "n": wire.response({"n": 0}, 0, 9),
}
FENCE = [b"*999\n", b"*9999\n"]  # by generation: 0 (on connecting), 1, 2...
FENCE_ANSWER = [wire.response({}, 118, 5), wire.response({}, 118, 6)]
ENQ = b"\x05"
QUERY = f"{LINE_QUERY}\n".encode()


def answer(core: G2coreCore, data: bytes, now: float = 0.0) -> list[codec.Line]:
    """The board says `data`; the lines the caller is shown."""
    core.receive_data(data, now)
    shown = []
    while (line := core.next_event()) is not None:
        shown.append(line)
    return shown


def line(n: int, text: str) -> bytes:
    return codec.encode_line(n, text)


def ok(n: int, length: int = 9, status: int = 0, **extra: object) -> bytes:
    return wire.response({"n": n, **extra}, status, length)


def sr(stat: int) -> bytes:
    return wire.response({"sr": {"stat": stat}}, 0, 10)


def qr(room: int) -> bytes:
    return wire.response({"qr": room}, 0, 10)


def said(n: int, jv: int = 4, stat: int = 5) -> bytes:
    """The answer to LINE_QUERY."""
    return wire.response({"n": n, "jv": jv, "stat": stat}, 0, len(QUERY) + 1)


def connected(window: int = 4, now: float = 0.0, n: int = 0) -> G2coreCore:
    """A core that has set the board up, the bytes checked on the way."""
    core = G2coreCore(window=window)
    answers = dict(SETUP_ANSWERS, n=wire.response({"n": n}, 0, 9))
    for index, ((name, _), sent) in enumerate(zip(SETUP, SETUP_BYTES, strict=True)):
        assert core.poll(now) == ([FENCE[0]] if index == 0 else []) + [sent]
        assert answer(core, answers[name], now) == []
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


def settle(core: G2coreCore, now: float, generation: int, n: int, fence_answered: bool = False,
           **query) -> list[bytes]:
    """The fence of a resolution and the two queries, answered `n`; what goes out after."""
    if not fence_answered:
        answer(core, FENCE_ANSWER[generation % 2], now)
    assert core.poll(now) == [QUERY]
    answer(core, said(n, **query), now)
    assert core.poll(now) == [QUERY]
    answer(core, said(n, **query), now)
    return core.poll(now)


# -- the core against scripted bytes -------------------------------------------------------
def test_a_line_is_spelt_to_be_checked_and_the_emulators_board_reads_it_so():
    assert line(1, "G21") == b"N0G21N1;*126\n"
    assert line(12, "M104 S200") == b"N0M104 S200N12;*49\n"
    assert line(4, "/G1 X1") == b"N0 /G1 X1N4;*15\n"  # a space before what starts with no letter
    assert line(4, "G28 X") == b"N0G28 X N4;*42\n"  # and after what ends in a letter
    board = G2coreProtocol()
    board.receive_data(line(12, "M104 S200") + line(14, "G1 X5.5 F300") + b"*999\n")
    assert list(iter(board.next_event, None)) == [
        CommandReceived("M104 S200;", 12, len(line(12, "M104 S200"))),
        CommandReceived("G1 X5.5 F300;", 14, len(line(14, "G1 X5.5 F300"))),
        BadLine(wire.CHECKSUM_MISMATCH, 5)]
    # A line cut short on the way runs into the fence, and is refused with it.
    board.receive_data(line(16, "G1 X9")[:7] + b"*999\n")
    assert board.next_event() == BadLine(wire.CHECKSUM_MISMATCH, 12)
    # ...or, if a line end from elsewhere closes it first, runs as line 0, which the host sees.
    board.receive_data(line(16, "G1 X9")[:7] + b"\r\n")
    assert board.next_event() == CommandReceived("G1 X9"[:5], 0, 8)
    # A damaged `*`: the checksum digits are a comment, not the number's.
    board.receive_data(line(17, "G1 X9").replace(b"*", b"+"))
    assert board.next_event() == CommandReceived(f"G1 X9;+{line(17, 'G1 X9')[-3:-1].decode()}",
                                                  17, len(line(17, "G1 X9")))


def test_the_emulators_board_takes_the_last_n_word_outside_comments_as_the_number():
    """gcode_parser.cpp: N is a word like the others (SET_NON_MODAL), the last one counts."""
    board = G2coreProtocol()
    board.receive_data(b"N12 G1 X5\nG1 X10 N7\nN0G1 X5 (N9) N11\nN0G1 X5;N13\nN G1\n")
    assert list(iter(board.next_event, None)) == [
        CommandReceived("G1 X5", 12, 10), CommandReceived("G1 X10", 7, 10),
        CommandReceived("G1 X5 (N9)", 11, 17), CommandReceived("G1 X5;N13", 0, 12),
        CommandReceived("N G1", None, 5)]


def test_a_refusal_said_twice_is_one_refusal():
    core = connected()
    core.submit("M999")
    sent = core.poll(0)
    refusal = wire.response({}, 132, len(sent[0]))  # refused at parse: no n
    answer(core, refusal + refusal)  # (repeated on the way back)
    assert core.poll(0) == [FENCE[1]]
    assert settle(core, 0.1, 1, n=0) == sent  # not run: tried again, not given up
    with pytest.raises(CommandFailed, match="status 132"):
        answer(core, refusal, 0.2)


def test_a_small_job_goes_out_one_line_at_a_time_and_ends_when_the_board_has_run_it():
    core = connected()
    tickets = [core.submit(text) for text in ("G21", "G0 X1", "M3 S1000")]
    assert core.poll(0) == [line(1, "G21")]
    assert core.poll(0) == [] and core.in_flight == 1
    answer(core, ok(1, 7))
    assert core.poll(0) == [line(2, "G0 X1")]
    answer(core, ok(2, 9))
    assert core.poll(0) == [line(3, "M3 S1000")]
    answer(core, ok(3, 12))
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
    assert core.stats.fences == 1  # the one written on connecting


def test_the_job_is_numbered_on_from_the_boards_line_number():
    core = connected(n=37)  # a host before this one left it there
    core.submit("G0 X1")
    assert core.poll(0) == [line(38, "G0 X1")]


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


def test_the_caller_may_queue_a_window_ahead_of_the_one_line_in_flight():
    core = connected(window=6)
    assert core.window == 6
    for n in range(10):
        core.submit(f"G1 X{n}")
    assert core.poll(0) == [line(1, "G1 X0")]
    assert core.poll(0) == []
    answer(core, ok(1))
    assert core.poll(0) == [line(2, "G1 X1")]
    assert core.in_flight == 1 and core.backlog == 8


def test_reports_interleaved_with_responses_acknowledge_nothing():
    core = connected()
    for n in range(3):
        core.submit(f"G1 X{n}")
    assert len(core.poll(0)) == 1
    shown = answer(core, b'{"sr":{"line":0,"posx":0.5,"stat":5}}\n{"qr":44}\n'
                         b'{"prb":{"e":1, "z":-3.210}}\n{"er":{"fb":101.03,"st":29,"msg":"x"}}\n')
    assert [line.kind for line in shown] == [codec.LineKind.REPORT] * 3 + [codec.LineKind.EXCEPTION]
    assert core.poll(0) == [] and core.take_completed() == []
    assert core.room == 44 and core.machine_state == 5
    answer(core, b'{"sr":{"posx":1}}\n' + ok(1) + b'{"qr":45}\n')
    assert core.poll(0) == [line(2, "G1 X1")]
    assert [t.text for t in core.take_completed()] == ["G1 X0"]


def test_a_status_of_100_or_more_twice_is_an_error_naming_the_line_status_and_message():
    core = connected()
    core.submit("G0 X1")
    core.submit("M999")
    core.poll(0)
    answer(core, ok(1))
    assert core.poll(0) == [line(2, "M999")]
    # Read and refused, so not on the board: sent again at once, under another number (the
    # board's is 2 now), in case a flip past the XOR made it a code the board lacks.
    answer(core, ok(2, 7, status=132))
    assert core.poll(0) == [line(3, "M999")]
    with pytest.raises(CommandFailed) as raised:
        answer(core, ok(3, 7, status=132, msg="M code unsupported"))
    assert raised.value.status == 132
    assert str(raised.value) == "the board refused line 3 ('M999'): status 132 (M code unsupported)"
    assert isinstance(raised.value, RemoteError)


def test_the_boards_own_words_are_added_to_the_message():
    core = connected()
    core.submit("G1 X900")
    core.poll(0)
    answer(core, ok(1, status=220, msg="Soft limit exceeded - X max"))
    core.poll(0)
    with pytest.raises(CommandFailed, match=r"status 220 \(a status g2core does not list\): Soft limit"):
        answer(core, ok(2, status=220, msg="Soft limit exceeded - X max"))


def test_a_status_no_g_code_line_gets_is_a_zero_damaged_on_the_way():
    core = connected()
    ticket = core.submit("G1 X1")
    core.poll(0)
    answer(core, ok(1, status=1))  # a flipped 0
    assert ticket.done and ticket.confirmed and core.stats.damaged_statuses == 1


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
    assert core.poll(0) == [FENCE[0], SETUP_BYTES[0]]


def test_a_footer_damaged_to_say_1_is_no_banner():
    assert isinstance(codec.parse_line(b'{"r":{"n":12},"f":[1,0,1]}'), codec.Response)
    assert isinstance(codec.parse_line(b'{"r":{"fb":101.03},"f":[1,0,1]}'), codec.Response)
    damaged = b'{"r":{"fv":0.99,"fb":101.03,"fbs":"101.03","msg":"SYSTEM REA\\u0004Y"},"f":[1,0,1]}'
    assert isinstance(codec.parse_line(damaged), codec.Boot)


def test_the_banner_arriving_mid_connect_starts_the_settings_again():
    core = G2coreCore()
    assert core.poll(0) == [FENCE[0], b'{"ej":1}\n']
    answer(core, SETUP_ANSWERS["ej"])
    assert core.poll(0) == [b'{"jv":4}\n']
    answer(core, BANNER, 0.1)  # not jv's answer, however it looks
    assert core.poll(0.1) == [b'{"ej":1}\n']  # the board reset ej, sv, qv before it
    answer(core, SETUP_ANSWERS["jv"], 0.1)  # jv's late answer is passed over
    assert core.poll(0.1) == []
    for (asked, _), sent in zip(SETUP, SETUP_BYTES[1:]):
        answer(core, SETUP_ANSWERS[asked], 0.1)
        assert core.poll(0.1) == [sent]
    answer(core, SETUP_ANSWERS["n"], 0.1)
    assert core.phase is Phase.READY


def test_the_banner_while_a_line_is_in_flight_is_no_answer_and_a_restart_once_jv_says_so():
    core = connected()
    ticket = core.submit("G0 X1")
    core.poll(4.0)
    answer(core, BANNER, 4.0)
    assert core.poll(4.0) == [FENCE[1], QUERY]  # asked at once: a restarted board holds nothing
    answer(core, said(0, jv=2), 4.0)
    assert core.poll(4.0) == [QUERY]
    with pytest.raises(PrinterReset, match=r"restarted: its jv is 2, .*its banner \(\{"):
        answer(core, said(0, jv=2), 4.0)
    assert not ticket.done


def test_a_late_greeting_of_a_marlin_compatible_build_is_no_restart():
    """Such a build greets a USB host 2 s after the port opens; the host may have begun."""
    core = connected()
    ticket = core.submit("G0 X1")
    core.poll(0.6)
    answer(core, BANNER, 2.0)
    assert core.poll(2.0) == [FENCE[1], QUERY]
    answer(core, said(0), 2.0)
    assert core.poll(2.0) == [QUERY]
    answer(core, said(0), 2.0)  # jv 4: the host's settings are there
    assert not ticket.done and core.poll(2.0) == []
    answer(core, ok(1), 2.1)
    assert ticket.done
    core.submit("G0 X2")
    core.poll(2.2)
    answer(core, BANNER, 2.3)  # another: a restart this time
    assert core.poll(2.3) == [FENCE[0], QUERY]
    answer(core, said(1, jv=2), 2.3)
    core.poll(2.3)
    with pytest.raises(PrinterReset):
        answer(core, said(1, jv=2), 2.3)


def test_a_banner_between_lines_is_asked_about_too():
    core = connected()
    core.submit("G0 X1")
    core.poll(0)
    answer(core, ok(1))
    answer(core, BANNER, 5.0)
    assert core.poll(5.0) == [QUERY]
    answer(core, said(0, jv=2, stat=1), 5.0)
    assert core.poll(5.0) == [QUERY]
    with pytest.raises(PrinterReset):
        answer(core, said(0, jv=2, stat=1), 5.0)


def test_garbage_and_non_json_lines_are_shown_and_passed_over():
    core = connected()
    ticket = core.submit("G0 X1")
    core.poll(0)
    shown = answer(core, b"g2core[mm] ok> \n\xff\xfe{\"r\n{\"r\":{\"n\":1},\"f\":[1,0\n[1,2]\n\r\n")
    assert [line.kind for line in shown] == [codec.LineKind.NOISE] * 4
    assert core.corrupt_frames == 2  # the bytes no board sends, and the broken `{` line
    assert not ticket.done and core.poll(0) == []
    answer(core, ok(1))
    assert ticket.done


def test_a_lost_answer_is_found_out_the_line_ran_and_it_is_done_unconfirmed():
    core = connected()
    ticket = core.submit("G1 X1")
    assert core.poll(0) == [line(1, "G1 X1")]
    assert core.next_deadline() == 2.0
    assert core.poll(2.0) == [FENCE[1]]  # silence: the fence, then (answered) the question
    assert settle(core, 2.1, 1, n=1) == []
    assert ticket.done and not ticket.confirmed
    assert core.stats.unconfirmed == 1 and core.stats.resends == 0 and core.stats.resolutions == 1
    core.submit("G1 X2")
    assert core.poll(2.2) == [line(2, "G1 X2")]


def test_a_lost_line_is_found_out_it_never_ran_and_it_is_sent_again_as_it_was():
    core = connected(n=0)
    ticket = core.submit("G0 X1")
    assert core.poll(0) == [line(1, "G0 X1")]
    assert core.poll(2.0) == [FENCE[1]]
    assert settle(core, 2.1, 1, n=0) == [line(1, "G0 X1")]
    assert not ticket.done and core.stats.resends == 1
    answer(core, ok(1), 2.2)
    assert ticket.done and ticket.confirmed


def test_a_refused_line_is_found_out_and_sent_again():
    core = connected()
    core.submit("G1 X1")
    sent = core.poll(0)
    answer(core, wire.response({}, 118, len(sent[0])))  # a byte flipped on the way
    assert core.poll(0) == [FENCE[1]]  # at once: no need to wait for silence
    assert settle(core, 0.1, 1, n=0) == sent


def test_the_fences_answer_may_not_be_an_earlier_fences():
    core = connected()
    core.submit("G1 X1")
    core.poll(0)
    assert core.poll(2.0) == [FENCE[1]]
    answer(core, FENCE_ANSWER[0], 2.1)  # the fence of connecting, late: not this one
    assert core.poll(2.1) == []
    answer(core, FENCE_ANSWER[1], 2.2)
    assert core.poll(2.2) == [QUERY]


def test_while_the_fence_waits_the_board_is_asked_if_it_is_there_and_the_line_answers_itself():
    """A board busy with a long command reads nothing, the fence neither: ENQ (no line end, so
    harmless after a line cut short) shows it is there; nothing is sent twice."""
    core = connected()
    ticket = core.submit("G4 P30")
    core.poll(0)
    assert core.poll(2.0) == [FENCE[1]]
    assert core.poll(4.0) == [ENQ, FENCE[1]]  # (another fence: one may be lost)
    answer(core, b'{"ack":true}\n', 4.0)
    assert core.poll(6.0) == [ENQ]
    answer(core, b'{"ack":true}\n', 6.0)
    assert core.poll(8.0) == [ENQ, FENCE[1]]
    answer(core, ok(1), 9)
    assert ticket.done and ticket.confirmed and core.stats.resends == 0
    answer(core, FENCE_ANSWER[1] * 3, 9)  # passed over: the line is done
    assert core.poll(9) == [] and core.stats.enquiries == 3


def test_a_board_that_says_nothing_at_all_while_the_fence_waits_is_given_up_on():
    core = G2coreCore(timeout=1.0, max_transmissions=3)
    for index, (name, _) in enumerate(SETUP):
        core.poll(0)
        answer(core, SETUP_ANSWERS[name])
    core.submit("G1 X1")
    core.poll(0)
    assert core.poll(1.0) == [FENCE[1]]
    core.poll(2.0)
    core.poll(3.0)
    with pytest.raises(PrinterNotResponding, match="said nothing"):
        core.poll(4.0)


def test_a_late_repeated_answer_is_not_taken_for_the_next_lines():
    core = connected()
    first, second = core.submit("G1 X1"), core.submit("G1 X2")
    core.poll(0)
    answer(core, ok(1))
    assert core.poll(0) == [line(2, "G1 X2")]
    answer(core, ok(1))  # the line repeated the answer
    assert not second.done and core.stats.mismatches == 1 and core.poll(0) == []
    answer(core, ok(2))
    assert first.done and second.done


def test_a_response_without_n_or_naming_another_line_is_found_out():
    core = connected()
    ticket = core.submit("G1 X1")
    core.poll(0)
    answer(core, wire.response({}, 0, 9))  # (a garbage line's, say)
    assert core.poll(0) == [FENCE[1]]
    answer(core, ok(1), 0.1)  # its own, behind it
    assert ticket.done and ticket.confirmed
    core.submit("G1 X2")
    assert core.poll(0.1) == [line(2, "G1 X2")]
    answer(core, ok(7), 0.2)  # a digit damaged
    assert core.poll(0.2) == [FENCE[0]]  # the next resolution's fences are the other length
    assert settle(core, 0.3, 2, n=2) == []


def test_answers_that_disagree_are_asked_again_until_two_agree():
    core = connected()
    ticket = core.submit("G1 X1")
    core.poll(0)
    core.poll(2.0)
    answer(core, FENCE_ANSWER[1], 2.1)
    for n in (1, 0, 1):  # a digit damaged in one of them
        assert core.poll(2.1) == [QUERY]
        answer(core, said(n), 2.1)
    assert not ticket.done and core.poll(2.1) == [QUERY]
    answer(core, said(1), 2.1)
    assert ticket.done


def test_a_board_that_lost_the_hosts_settings_restarted():
    core = connected()
    core.submit("G1 X1")
    core.poll(4.0)
    core.poll(6.0)
    with pytest.raises(PrinterReset, match="jv is 2.*its banner has not reached the host"):
        settle(core, 6.0, 1, n=0, jv=2)  # its banner was lost


def test_a_halt_said_twice_while_a_line_is_in_flight_is_a_halt():
    core = connected()
    core.submit("G1 X1")
    core.poll(0)
    answer(core, b'{"er":{"fb":101.03,"st":203,"msg":"Limit hit"}}\n')
    answer(core, b'{"sr":{"stat":2}}\n')
    assert core.poll(0) == [FENCE[1], QUERY]  # asked at once: a halted board runs nothing
    answer(core, said(0, stat=2))
    assert core.poll(0) == [QUERY]
    with pytest.raises(PrinterHalted, match="ALARM"):
        answer(core, said(0, stat=2))


def test_a_halt_said_once_is_a_digit_damaged():
    core = connected()
    ticket = core.submit("G1 X1")
    core.poll(0)
    answer(core, b'{"sr":{"stat":2}}\n')  # 3, with one bit flipped
    assert core.poll(0) == [FENCE[1], QUERY]
    answer(core, said(0, stat=3))
    assert core.poll(0) == [QUERY]
    answer(core, said(0, stat=3))
    assert core.poll(0) == []  # and the fence's answer settles the rest
    answer(core, ok(1))
    assert ticket.done


def test_a_callers_json_request_goes_alone_and_its_answer_is_the_response():
    core = connected()
    core.submit("G1 X1")
    request = core.submit('{"posx":n}')
    core.submit("G1 X2")
    assert core.poll(0) == [line(1, "G1 X1")]
    answer(core, ok(1))
    assert core.poll(0) == [b'{"posx":n}\n']
    assert core.poll(0) == []
    answer(core, wire.response({"posx": 1}, 0, 12))
    assert request.response == ('{"posx":1}',)
    assert core.poll(0) == [line(2, "G1 X2")]


def test_a_callers_request_the_board_refuses_is_an_error():
    core = connected()
    core.submit('{"foo":n}')
    core.poll(0)
    with pytest.raises(CommandFailed, match=r'\{"foo":n\}: status 100 \(Unrecognized command'):
        answer(core, wire.response({"foo": None}, 100, 11))


def test_lines_held_by_a_feedhold_wait_for_resume():
    core = connected()
    first, second = core.submit("G1 X100 F10"), core.submit("G1 X0")
    core.poll(0)
    answer(core, ok(1, 13))
    assert core.poll(0) == [line(2, "G1 X0")]
    core.feedhold()
    assert core.poll(0.5) == [b"!"]
    answer(core, b'{"sr":{"stat":6}}\n', 0.6)
    assert core.poll(2.0) == [FENCE[1]]
    for t in (4.0, 6.0, 8.0):
        assert core.poll(t)[0] == ENQ
        answer(core, b'{"ack":true}\n', t)
    core.resume()
    assert core.poll(9) == [b"~"]
    answer(core, ok(2), 9.5)
    assert second.done and core.idle and core.stats.resends == 0


def test_an_unanswered_setup_is_asked_again_then_given_up():
    core = G2coreCore(timeout=1.0, max_transmissions=3)
    assert core.poll(0) == [FENCE[0], b'{"ej":1}\n']
    assert core.poll(1.0) == [b'{"ej":1}\n']
    assert core.poll(2.0) == [b'{"ej":1}\n']
    with pytest.raises(PrinterNotResponding, match="is a g2core board on the port"):
        core.poll(3.0)
    assert core.stats.resends == 2


def test_a_request_met_by_damaged_answers_is_not_given_up():
    core = G2coreCore(timeout=1.0, max_transmissions=3)
    core.poll(0)
    for t in (1.0, 2.0, 3.0, 4.0):
        answer(core, b'{"r":{"e\xea":1},"f":[1,0,10]}\n', t - 0.5)  # noise: the board is there
        assert core.poll(t) == [b'{"ej":1}\n']


def test_an_alarm_said_twice_while_draining_is_a_halt():
    core = connected()
    core.submit("G1 X1")
    core.poll(0)
    answer(core, ok(1))
    core.request_drained()
    core.poll(0)
    answer(core, sr(2))
    assert core.poll(0) == [b'{"sr":n}\n']
    with pytest.raises(PrinterHalted, match="ALARM"):
        answer(core, sr(2))


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


def test_cancel_drops_the_line_in_flight_unanswered_by_the_mark():
    core = connected()
    tickets = [core.submit(f"G1 X{n}") for n in range(3)]
    core.poll(0)
    core.cancel()
    assert core.poll(0.1) == [b"\x04", b'{"sr":n}\n']
    answer(core, sr(4), 0.1)
    assert [t.confirmed for t in tickets] == [False] * 3 and core.stats.cancelled == 3


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
    buffer, G-code read only while its planner has 4 of 48 buffers free, one response per line
    (118 for a bad checksum), moves that take `move_time` each, and filtered status reports of
    `stat` as it changes."""

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
        self.n = 0  # the last line number run
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
            if (at == 0 or self.rx[at - 1] == ord("\n")) and self.rx[at] in b"!~\x04\x05":
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
        if text == "\x05":
            await self._send(b'{"ack":true}\n')
            return
        if text == "\x04":  # (what came before it is dropped already)
            self.planner.clear()
            await self._send(wire.report("er", {"fb": wire.Number(self.fb, 2), "st": 207,
                                                          "msg": "Kill job - Job killed by ^d"}))
            await self._state(4)
            return
        values = {"fb": wire.Number(self.fb, 2), "fv": wire.Number(0.99, 2),
                  "qr": self.PLANNER - len(self.planner), "sr": {"stat": self.stat},
                  "posx": wire.Number(1.5, 3), "n": self.n, "jv": 4, "stat": self.stat}
        body, status = {}, 0
        for name, value in wire.parse_request(text).items():
            if name in ("ej", "jv", "qv", "sv") and value is not wire.NULL:
                body[name] = value
            elif name in values:
                body[name] = values[name]
            else:
                body, status = {**body, name: None}, 100
                break
        await self._send(wire.response(body, status, len(line) + 2))

    async def _gcode(self, line: str) -> None:
        size = len(line) + 1
        body, star, given = line.partition("*")
        if star and (int(given) != xor8(body.encode()) or not body.startswith("N")):
            await self._send(wire.response({}, 118, size))
            return
        text = body.split(";")[0]
        numbers = re.findall(r"N(\d+)", text)  # g2core's line number: the last N word
        number, text = int(numbers[-1]), re.sub(r"N\d+", "", text).strip()
        self.lines.append(text)
        status = self.statuses.get(text, 0)
        if status == 0:
            self.n = number
        if status == 0 and text.startswith(("G0", "G1")):
            self.planner.append(text)
            self._moved.set()
            await self._state(5)
        await self._send(wire.response({"n": number}, status, size))

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
    assert board.most_in_rx == 1  # one line at a time


async def test_the_window_option_is_what_the_caller_may_queue_not_lines_in_flight(autojump_clock):
    async def body(client, board):
        await client.print_commands(JOB)
        assert client._core.window == 6

    board = await with_board({"move_time": 0.01}, body, options=ClientOptions(window=6))
    assert board.most_in_rx == 1 and board.lines == JOB


async def test_send_returns_a_requests_answer_and_waits_for_a_move(autojump_clock):
    async def body(client, board):
        assert await client.send("G0 X1") == ()
        assert board.ran == ["G0 X1"] and board.stat == 3
        assert await client.send('{"posx":n}') == ('{"posx":1.5}',)

    await with_board({"banner": False}, body)


async def test_a_line_refused_twice_ends_the_session_with_the_error(autojump_clock):
    async def body(client, board):
        await client.print_commands(["G21", "M104 S200", "G1 X1"])

    with pytest.raises(CommandFailed, match=r"line 3 \('M104 S200'\): status 132 \(M code unsupported\)"):
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


def test_a_setting_that_reads_back_otherwise_is_set_again():
    """{jv:4} damaged to {jv:5} on the way: the board says jv 5, and the host sets it again
    (else it would take the board's jv 5 later for a restart)."""
    core = G2coreCore()
    assert core.poll(0.0) == [FENCE[0], SETUP_BYTES[0]]
    answer(core, SETUP_ANSWERS["ej"])
    assert core.poll(0.0) == [SETUP_BYTES[1]]
    answer(core, wire.response({"jv": 5}, 0, 9))
    assert core.poll(0.0) == [SETUP_BYTES[1]]  # {"jv":4} again
    answer(core, SETUP_ANSWERS["jv"])
    assert core.poll(0.0) == [SETUP_BYTES[2]]
