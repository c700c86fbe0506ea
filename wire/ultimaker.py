"""Ultimaker serial protocol wire facts (docs/protocols.md section 1), shared by both ends.

Host->printer packets (v2): FF FF seq len payload crc16-big-endian.
Printer->host frames (v3): "\\n" K SS PP CC "\\n", CC = CRC8 over the ASCII of K SS PP.
"""

from fake_marlin.wire.checksums import crc8_smbus, crc16_ccitt_false

HEADER_BYTE = 0xFF
SEQUENCE_MODULUS = 255  # 0..254; 255 would look like a header byte
MAX_PAYLOAD = 96  # MAX_CMD_SIZE
PAYLOAD_MIN_BYTE = 0x20
PAYLOAD_MAX_BYTE = 0x7E
PLANNER_ROOM_MAX = 15  # BLOCK_BUFFER_SIZE 16 holds at most 15 moves


def payload_error(payload: bytes) -> str | None:
    """Why a payload cannot be sent in a packet, or None if it can."""
    if not 1 <= len(payload) <= MAX_PAYLOAD:
        return f"payload is {len(payload)} bytes; a packet carries 1 to {MAX_PAYLOAD}"
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
