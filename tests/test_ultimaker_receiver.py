"""The printer's receiver, against the behaviour of UltimakerMarlin's SerialProtocol."""

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from fake_marlin.emulator.protocols.base import CommandDone, CommandReceived
from fake_marlin.emulator.protocols.ultimaker import (
    OutOfBand,
    OutOfBandKind,
    PacketRejected,
    RejectReason,
    RoomChanged,
    UltimakerProtocol,
)
from fake_marlin.wire.ultimaker import encode_packet, frame_body


def feed(protocol: UltimakerProtocol, data: bytes) -> list:
    protocol.receive_data(data)
    events = []
    while (event := protocol.next_event()) is not None:
        events.append(event)
    return events


def test_commands_come_out_in_order_with_their_sequence_numbers():
    protocol = UltimakerProtocol()
    events = feed(protocol, encode_packet(0, b"G28") + encode_packet(1, b"G1 X10 F3000"))
    assert events == [CommandReceived("G28", 0), CommandReceived("G1 X10 F3000", 1)]
    assert protocol.expected_seq == 2


def test_ok_frame_follows_the_response_data_and_carries_the_room():
    protocol = UltimakerProtocol()
    feed(protocol, encode_packet(0, b"M105"))
    out = protocol.send(CommandDone(0, room=15, response=("T:21.00 /0.00 B:21.00 /0.00 @:0 B@:0",)))
    assert out == b"T:21.00 /0.00 B:21.00 /0.00 @:0 B@:0\n\no000FF8\n"


@pytest.mark.parametrize(
    "packet, reason, message",
    [
        (
            encode_packet(3, b"G28"),
            RejectReason.UNEXPECTED_SEQUENCE,
            "Sequence number is unexpected (received, expected): 3,0",
        ),
        (
            bytes.fromhex("ffff0000"),
            RejectReason.BAD_LENGTH,
            "Payload size is too big for packet with sequence number: 0",
        ),
        (
            bytes.fromhex("ffff0061") + b"x" * 97,
            RejectReason.BAD_LENGTH,
            "Payload size is too big for packet with sequence number: 0",
        ),
        (
            bytes.fromhex("ffff000347327f0000"),
            RejectReason.ILLEGAL_BYTE,
            "Payload byte not in acceptable (ASCII) range at position #2",
        ),
        (
            encode_packet(0, b"G28")[:-1] + b"\x00",
            RejectReason.CHECKSUM_MISMATCH,
            "Checksum mismatch for packet with sequence number: 0",
        ),
    ],
)
def test_each_bad_packet_gets_the_firmware_text_then_r_with_the_expected_number(packet, reason, message):
    protocol = UltimakerProtocol()
    protocol.send(RoomChanged(12))
    events = feed(protocol, packet)
    assert events == [PacketRejected(reason, message, 0)]
    assert protocol.data_to_send() == f"\nProtoError:{message}\n\n{frame_body('r', 0, 12)}\n".encode()


def test_a_full_command_queue_rejects_without_advancing():
    protocol = UltimakerProtocol(queue_size=2)
    events = feed(protocol, encode_packet(0, b"G1 X1"))
    events += feed(protocol, encode_packet(1, b"G1 X2"))
    events += feed(protocol, encode_packet(2, b"G1 X3"))
    assert [type(e) for e in events] == [CommandReceived, CommandReceived, PacketRejected]
    assert events[2].reason is RejectReason.QUEUE_FULL
    assert b"(buffer full), packet with sequence number: 2" in protocol.data_to_send()
    protocol.send(CommandDone(0, room=15))
    assert feed(protocol, encode_packet(2, b"G1 X3")) == [CommandReceived("G1 X3", 2)]


def test_an_error_flushes_the_rest_of_the_receive_buffer():
    protocol = UltimakerProtocol()
    corrupt = encode_packet(0, b"G28")[:-1] + b"\x00"
    events = feed(protocol, corrupt + encode_packet(0, b"G28") + encode_packet(1, b"M105"))
    assert [type(e) for e in events] == [PacketRejected]
    # What arrives after the flush is read normally.
    assert feed(protocol, encode_packet(0, b"G28")) == [CommandReceived("G28", 0)]


def test_a_retransmitted_packet_is_never_handed_out_twice():
    protocol = UltimakerProtocol()
    assert feed(protocol, encode_packet(0, b"G1 X5")) == [CommandReceived("G1 X5", 0)]
    events = feed(protocol, encode_packet(0, b"G1 X5"))
    assert [e.reason for e in events] == [RejectReason.UNEXPECTED_SEQUENCE]
    assert protocol.data_to_send().endswith(f"\n{frame_body('r', 1, 15)}\n".encode())


def test_ff_where_a_field_is_expected_restarts_framing():
    protocol = UltimakerProtocol()
    truncated = encode_packet(0, b"G1 X100")[:6]  # header, seq, length, two payload bytes
    assert feed(protocol, truncated + encode_packet(0, b"M105")) == [CommandReceived("M105", 0)]


@pytest.mark.parametrize("extra", [1, 2, 5])
def test_header_bytes_beyond_two_are_ignored(extra):
    """readCommand syncs on any run of 0xFF: a packet cut to its first byte (or noise ending in
    0xFF) in front of the resend must not make the resend's header look like noise."""
    protocol = UltimakerProtocol()
    assert feed(protocol, b"\xff" * extra + encode_packet(0, b"M105")) == [CommandReceived("M105", 0)]


def test_ff_inside_the_crc_is_data_not_a_header():
    seq, payload = next(
        (s, p)
        for s in range(255)
        for p in (b"G1 X%d" % n for n in range(300))
        if 0xFF in encode_packet(s, p)[-2:]
    )
    protocol = UltimakerProtocol()
    protocol.expected_seq = seq
    assert feed(protocol, encode_packet(seq, payload)) == [CommandReceived(payload.decode(), seq)]


def test_sequence_numbers_wrap_after_254():
    protocol = UltimakerProtocol(queue_size=1000)
    seqs = [event.number for n in range(300) for event in feed(protocol, encode_packet(n % 255, b"M105"))]
    assert seqs == [n % 255 for n in range(300)]


def test_q_only_when_the_room_last_reported_was_zero():
    protocol = UltimakerProtocol()
    assert protocol.send(RoomChanged(15)) == b"\nq000F98\n"  # boot
    assert protocol.send(RoomChanged(14)) == b""
    protocol.receive_data(encode_packet(0, b"G1 X1"))
    protocol.next_event()
    protocol.send(CommandDone(0, room=0))
    assert protocol.send(RoomChanged(0)) == b""
    assert protocol.send(RoomChanged(1)) == f"\n{frame_body('q', 0, 1)}\n".encode()
    assert protocol.send(RoomChanged(2)) == b""


def test_out_of_band_lines():
    protocol = UltimakerProtocol()
    assert protocol.send(OutOfBand(OutOfBandKind.LOG, "Marlin started")) == b"LOG:Marlin started\n"
    assert protocol.send(OutOfBand(OutOfBandKind.ERROR, "Heater failed")) == b"\nError:Heater failed\n"


@settings(max_examples=300)
@given(st.lists(st.binary(max_size=64), max_size=20))
def test_arbitrary_bytes_never_crash_and_output_stays_framed(chunks):
    protocol = UltimakerProtocol()
    for chunk in chunks:
        for event in feed(protocol, chunk):
            assert isinstance(event, (CommandReceived, PacketRejected))
            if isinstance(event, CommandReceived):
                protocol.send(CommandDone(event.number, room=15))
    for line in protocol.data_to_send().split(b"\n"):
        assert line == b"" or line.startswith(b"ProtoError:") or line[:1] in b"or"


@settings(max_examples=300)
@given(garbage=st.binary(max_size=200), payload=st.binary(min_size=1, max_size=96).map(
    lambda b: bytes(0x20 + x % 95 for x in b)))
def test_a_valid_packet_after_garbage_is_accepted_by_the_time_it_is_resent(garbage, payload):
    protocol = UltimakerProtocol(queue_size=10_000)
    feed(protocol, garbage)
    seq = protocol.expected_seq
    received = feed(protocol, encode_packet(seq, payload)) + feed(protocol, encode_packet(seq, payload))
    assert CommandReceived(payload.decode(), seq) in received


class ByteByByte(UltimakerProtocol):
    """The receiver as the firmware runs it: readCommand() for every byte."""

    def _whole_packet(self, start):
        return None


@settings(max_examples=300)
@given(st.lists(st.tuples(
    st.integers(-1, 1),  # the sequence number: one before, as expected, one after
    st.binary(max_size=100) | st.text("G1 XYEF0123456789.", min_size=0, max_size=100).map(str.encode),
    st.sampled_from([None, None, None, "crc", "length", "cut", "cut crc", "header", "ff",
                     "garbage"]),
    st.booleans(),  # the printer finishes the commands it has before this packet arrives
), max_size=25), st.integers(1, 8))
# A packet cut before its last CRC byte: the next packet's first byte completes it.
@example([(0, b"G1 X1", "cut crc", False), (0, b"G1 X2", None, False)], 8)
def test_reading_a_whole_packet_at_once_is_reading_it_byte_by_byte(packets, queue_size):
    fast, slow = UltimakerProtocol(queue_size), ByteByByte(queue_size)
    for seq_offset, payload, damage, finish in packets:
        wire = bytearray(encode_packet((fast.expected_seq + seq_offset) % 255, payload[:96] or b"M"))
        if damage == "crc":
            wire[-1] ^= 0x01
        elif damage == "length":
            wire[3] = 0 if wire[3] > 50 else 97
        elif damage == "cut":
            wire = wire[:len(wire) // 2]
        elif damage == "cut crc":  # what comes next is read as the CRC's second byte
            wire = wire[:-1]
        elif damage == "header":
            wire[1] = 0x00
        elif damage == "ff":
            wire[4] = 0xFF
        elif damage == "garbage":
            wire[:0] = b"\x00\xff"
        received = feed(fast, bytes(wire))
        assert received == feed(slow, bytes(wire))
        assert fast.expected_seq == slow.expected_seq
        for protocol in (fast, slow):
            for event in received if finish else ():
                if isinstance(event, CommandReceived):
                    protocol.send(CommandDone(event.number, room=15))
        assert fast.data_to_send() == slow.data_to_send()
