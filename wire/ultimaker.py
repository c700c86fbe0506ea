"""Ultimaker serial protocol wire facts (docs/protocols.md section 1), shared by both ends.

Host->printer packets (v2): FF FF seq len payload crc16-big-endian.
Printer->host frames (v3): "\\n" K SS PP CC "\\n", CC = CRC8 over the ASCII of K SS PP.
"""

import re

from fake_marlin.wire.checksums import crc8_smbus, crc16_ccitt_false
from fake_marlin.wire.framing import Framer
from fake_marlin.wire.lines import LINES, MAX_LINE, line_end

HEADER_BYTE = 0xFF
HEADER = b"\xff\xff"
SEQUENCE_MODULUS = 255  # 0..254; 255 would look like a header byte
MAX_PAYLOAD = 96  # MAX_CMD_SIZE
PAYLOAD_MIN_BYTE = 0x20
PAYLOAD_MAX_BYTE = 0x7E
PLANNER_ROOM_MAX = 15  # BLOCK_BUFFER_SIZE 16 holds at most 15 moves
PRINTABLE = re.compile(b"[%c-%c]*" % (PAYLOAD_MIN_BYTE, PAYLOAD_MAX_BYTE))  # a payload's bytes


def payload_error(payload: bytes) -> str | None:
    """Why a payload cannot be sent in a packet, or None if it can."""
    if not 1 <= len(payload) <= MAX_PAYLOAD:
        return f"payload is {len(payload)} bytes; a packet carries 1 to {MAX_PAYLOAD}"
    if PRINTABLE.fullmatch(payload):
        return None
    for index, byte in enumerate(payload):
        if not PAYLOAD_MIN_BYTE <= byte <= PAYLOAD_MAX_BYTE:
            return f"byte 0x{byte:02X} at position {index} is outside printable ASCII"
    return None


def packet_crc(seq: int, payload: bytes) -> int:
    return crc16_ccitt_false(bytes((seq, len(payload))) + payload)


def encode_packet(seq: int, payload: bytes) -> bytes:
    """Encode one host->printer packet; the caller has checked payload_error()."""
    crc = packet_crc(seq, payload)
    return bytes((HEADER_BYTE, HEADER_BYTE, seq, len(payload))) + payload + crc.to_bytes(2, "big")


def frame_body(kind: str, seq: int, room: int) -> str:
    """The 7 characters of a v3 frame between its two line feeds."""
    text = f"{kind}{seq:02X}{room:02X}"
    return f"{text}{crc8_smbus(text.encode('ascii')):02X}"


def next_seq(seq: int, step: int = 1) -> int:
    return (seq + step) % SEQUENCE_MODULUS


def seq_distance(from_seq: int, to_seq: int) -> int:
    """How many increments take from_seq to to_seq, modulo the sequence space."""
    return (to_seq - from_seq) % SEQUENCE_MODULUS


# -- units, for the fault layer (wire/framing.py) -------------------------------------------
def packet_end(buffer: bytes, start: int) -> int | None:
    """Where the packet starting at `start` (at an 0xFF) ends; None if it is not all here.

    A lone 0xFF, or a header whose length no packet has, ends at once as a unit of noise.
    """
    if len(buffer) < start + 4:
        return None if buffer[start:start + 2] in (HEADER[:1], HEADER) else start + 1
    if buffer[start + 1] != HEADER_BYTE:
        return start + 1
    length = buffer[start + 3]
    if not 1 <= length <= MAX_PAYLOAD:
        return start + 4
    end = start + 4 + length + 2
    return end if end <= len(buffer) else None


def text_end(buffer: bytes, start: int) -> int | None:
    """A line's end, or where a packet's header cuts it short: text before a packet is a unit
    of its own (a host's probe line, noise)."""
    end = line_end(buffer, start)
    header = buffer.find(HEADER, start, end if end is not None else len(buffer))
    return header if header > start else end


def to_printer_unit_end(buffer: bytes, start: int) -> int | None:
    if buffer[start] == HEADER_BYTE:
        return packet_end(buffer, start)
    return text_end(buffer, start)


# Packets, and lines between them; the printer's frames are lines.
TO_PRINTER_UNITS = Framer(to_printer_unit_end, MAX_LINE, filler=b"\r\n")
TO_HOST_UNITS = LINES
