"""The host's Ultimaker codec: packets out, frames and lines in."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fake_marlin.emulator.protocols.base import CommandReceived
from fake_marlin.emulator.protocols.ultimaker import UltimakerProtocol
from fake_marlin.host.codecs.lines import MAX_LINE
from fake_marlin.host.codecs.ultimaker import (
    Ack,
    CorruptFrame,
    FrameParser,
    Line,
    LineKind,
    Reject,
    RoomInfo,
    check_command,
    encode_command,
)
from fake_marlin.host.errors import CommandError
from fake_marlin.wire.ultimaker import frame_body

printable = st.text(alphabet=st.characters(min_codepoint=0x20, max_codepoint=0x7E), min_size=1, max_size=96)


def parse_all(data: bytes) -> list:
    parser = FrameParser()
    parser.receive_data(data)
    events = []
    while (event := parser.next_event()) is not None:
        events.append(event)
    return events


@given(printable, st.integers(0, 254))
def test_every_sendable_command_reaches_the_printer_intact(command, seq):
    printer = UltimakerProtocol()
    printer.expected_seq = seq
    printer.receive_data(encode_command(seq, command))
    assert printer.next_event() == CommandReceived(command, seq)


@given(st.sampled_from("orq"), st.integers(0, 254), st.integers(0, 15))
def test_frames_round_trip(kind, seq, room):
    expected = {"o": Ack(seq, room), "r": Reject(seq, room), "q": RoomInfo(room)}[kind]
    assert parse_all(f"\n{frame_body(kind, seq, room)}\n".encode()) == [expected]


def test_a_frame_with_a_bad_crc_is_reported_corrupt_not_acted_on():
    good = frame_body("o", 7, 15)
    bad = good[:-1] + ("0" if good[-1] != "0" else "1")
    assert parse_all(f"\n{bad}\n".encode()) == [CorruptFrame(bad)]


def test_lines_are_classified_and_both_proto_error_spellings_accepted():
    data = (
        b"LOG:Marlin started\n\nq000F98\nT:21.00 /0.00\n\no000FF8\n"
        b"\nProtoError:Checksum mismatch\nProtoErr: old spelling\n\nError:Heater\nWARNING: hot\n"
    )
    assert parse_all(data) == [
        Line(LineKind.LOG, "Marlin started"),
        RoomInfo(15),
        Line(LineKind.RESPONSE, "T:21.00 /0.00"),
        Ack(0, 15),
        Line(LineKind.PROTO_ERROR, "Checksum mismatch"),
        Line(LineKind.PROTO_ERROR, "old spelling"),
        Line(LineKind.ERROR, "Heater"),
        Line(LineKind.WARNING, "hot"),
    ]


def test_frames_split_across_reads_are_reassembled():
    parser = FrameParser()
    events = []
    for byte in b"ok\n\no000FF8\n":
        parser.receive_data(bytes([byte]))
        while (event := parser.next_event()) is not None:
            events.append(event)
    assert events == [Line(LineKind.RESPONSE, "ok"), Ack(0, 15)]


def test_an_endless_line_does_not_grow_memory_without_bound():
    parser = FrameParser()
    parser.receive_data(b"x" * (3 * MAX_LINE))
    events = []
    while (event := parser.next_event()) is not None:
        events.append(event)
    assert len(events) == 2 and all(len(e.text) == MAX_LINE for e in events)


def test_a_line_too_long_is_cut_even_when_its_end_comes_in_the_same_read():
    parser = FrameParser()
    parser.receive_data(b"x" * (MAX_LINE + 10) + b"\n")
    events = []
    while (event := parser.next_event()) is not None:
        events.append(event)
    assert [len(e.text) for e in events] == [MAX_LINE, 10]


@pytest.mark.parametrize("command", ["", "G1 X" + "1" * 100, "M117 Grüße", "M117 tab\there"])
def test_unsendable_commands_are_the_callers_error(command):
    with pytest.raises(CommandError):
        check_command(command)


@settings(max_examples=300)
@given(st.binary(max_size=2000))
def test_arbitrary_bytes_never_crash_the_frame_parser(data):
    for event in parse_all(data):
        assert isinstance(event, (Ack, Reject, RoomInfo, CorruptFrame, Line))
