"""The wire vectors of docs/protocols.md section 1, byte for byte."""

import pytest

from fake_marlin.emulator.protocols.base import CommandReceived
from fake_marlin.emulator.protocols.ultimaker import RoomChanged, UltimakerProtocol
from fake_marlin.host.codecs.ultimaker import Ack, RoomInfo, parse_line
from fake_marlin.wire.checksums import crc8_smbus, crc16_ccitt_false
from fake_marlin.wire.ultimaker import encode_packet, frame_body


def test_check_values_of_both_crcs():
    assert crc16_ccitt_false(b"123456789") == 0x29B1
    assert crc8_smbus(b"123456789") == 0xF4


@pytest.mark.parametrize(
    "seq, payload, wire_hex",
    [
        (0, b"G28", "ffff0003473238c641"),
        (1, b"M105", "ffff01044d313035045a"),
    ],
)
def test_packet_vectors(seq, payload, wire_hex):
    assert encode_packet(seq, payload).hex() == wire_hex
    printer = UltimakerProtocol()
    printer.expected_seq = seq
    printer.receive_data(bytes.fromhex(wire_hex))
    assert printer.next_event() == CommandReceived(payload.decode(), seq)
    assert printer.data_to_send() == b""


@pytest.mark.parametrize(
    "kind, seq, room, wire_text",
    [
        ("o", 0x05, 0x10, "\no051068\n"),
        ("o", 0x00, 0x0F, "\no000FF8\n"),
        ("q", 0x00, 0x0F, "\nq000F98\n"),
    ],
)
def test_frame_vectors(kind, seq, room, wire_text):
    assert f"\n{frame_body(kind, seq, room)}\n" == wire_text
    parsed = parse_line(wire_text.strip())
    assert parsed == (Ack(seq, room) if kind == "o" else RoomInfo(room))


def test_boot_q_frame_is_the_reference_one():
    assert UltimakerProtocol().send(RoomChanged(15)) == b"\nq000F98\n"
