"""Marlin's binary file transfer (BINARY_FILE_TRANSFER, `M28 B1`): the packet wire facts
(docs/protocols.md section 5, docs/binary-transfer.md), shared by the printer side
(emulator/protocols/marlin_binary.py), hosts and the fault layer.

Host->printer packets: `AD B5` sync meta size(LE16) header-checksum(LE16), then, if size > 0,
the payload and a footer checksum (LE16). meta is protocol << 4 | type. The printer answers in
text lines (`ok<sync>`, `rs<sync>`, `PFT:success`, ...).
"""

from dataclasses import dataclass
from enum import IntEnum

from fake_marlin.wire.framing import Framer
from fake_marlin.wire.lines import MAX_LINE

TOKEN = b"\xad\xb5"  # the LE16 0xB5AD of binary_stream.h
HEADER_SIZE = 8  # token, sync, meta, size, header checksum
FOOTER_SIZE = 2
PROTOCOL_VERSION = "0.1.0"  # BinaryStream's and SDFileTransferProtocol's VERSION_*
MAX_SIZE = 0xFFFF


class Protocol(IntEnum):
    CONTROL = 0
    FILE_TRANSFER = 1


class Control(IntEnum):
    SYNC = 1
    CLOSE = 2  # back to ASCII


class FileRequest(IntEnum):
    QUERY = 0
    OPEN = 1
    CLOSE = 2
    WRITE = 3
    ABORT = 4


def checksum(data: bytes | bytearray, start: int = 0) -> int:
    """binary_stream.h's "fletchers 16" over `data`, carried on from `start`.

    Per byte b: low = (low + b) % 255, then high = (high + low) % 255; the value is
    high << 8 | low. Summed in closed form (low gains the bytes' sum, high gains n times the old
    low and each byte weighted by how many steps it is counted in), which is the same value
    modulo 255 and much faster in Python than a step per byte.
    """
    low, high = start & 0xFF, start >> 8
    count = len(data)
    high = (high + count * low + sum(map(int.__mul__, range(count, 0, -1), data))) % 255
    low = (low + sum(data)) % 255
    return high << 8 | low


@dataclass(frozen=True)
class Header:
    sync: int
    protocol: int
    type: int
    size: int

    @property
    def packet_size(self) -> int:
        return HEADER_SIZE + (self.size + FOOTER_SIZE if self.size else 0)


@dataclass(frozen=True)
class Packet:
    sync: int
    protocol: int
    type: int
    payload: bytes = b""


def header_fields(header: Header) -> bytes:
    """sync, meta and size: the four bytes the header checksum covers."""
    return bytes((header.sync, header.protocol << 4 | header.type)) + header.size.to_bytes(2, "little")


def encode(packet: Packet) -> bytes:
    """One packet as a host sends it."""
    if not (0 <= packet.sync <= 0xFF and 0 <= packet.protocol <= 0xF and 0 <= packet.type <= 0xF):
        raise ValueError(f"no packet has sync {packet.sync}, protocol {packet.protocol}, "
                         f"type {packet.type}")
    if len(packet.payload) > MAX_SIZE:
        raise ValueError(f"a payload of {len(packet.payload)} bytes does not fit a packet")
    fields = header_fields(Header(packet.sync, packet.protocol, packet.type, len(packet.payload)))
    header = fields + checksum(fields).to_bytes(2, "little")
    if not packet.payload:
        return TOKEN + header
    footer = checksum(packet.payload, checksum(header))
    return TOKEN + header + packet.payload + footer.to_bytes(2, "little")


def parse_header(data: bytes | bytearray) -> Header | None:
    """The six bytes after the token as a header; None if its checksum is wrong."""
    if len(data) != HEADER_SIZE - len(TOKEN):
        raise ValueError(f"a header has {HEADER_SIZE - len(TOKEN)} bytes after its token")
    if checksum(data[:4]) != int.from_bytes(data[4:6], "little"):
        return None
    return Header(data[0], data[1] >> 4, data[1] & 0xF, int.from_bytes(data[2:4], "little"))


class PacketError(ValueError):
    """Bytes that are no whole, intact packet."""


def decode(data: bytes) -> Packet:
    """Exactly one packet (for hosts and tests; the printer reads a stream, byte by byte)."""
    if not data.startswith(TOKEN) or len(data) < HEADER_SIZE:
        raise PacketError("a packet starts with AD B5 and an 8-byte header")
    header = parse_header(data[2:HEADER_SIZE])
    if header is None:
        raise PacketError("header checksum mismatch")
    if len(data) != header.packet_size:
        raise PacketError(f"the header says {header.packet_size} bytes, not {len(data)}")
    payload = data[HEADER_SIZE:HEADER_SIZE + header.size]
    if header.size and checksum(payload, checksum(data[2:HEADER_SIZE])) != int.from_bytes(
        data[-FOOTER_SIZE:], "little"
    ):
        raise PacketError("payload checksum mismatch")
    return Packet(header.sync, header.protocol, header.type, payload)


def open_payload(name: str, compression: bool = False, dummy: bool = False) -> bytes:
    """A file OPEN's payload: dummy, compression, the file name and its NUL."""
    return bytes((int(dummy), int(compression))) + name.encode("utf-8") + b"\0"


# -- units, for the fault layer (wire/framing.py) -------------------------------------------
def unit_end(buffer: bytes, start: int) -> int | None:
    """Marlin's units toward the printer: text lines, and in binary mode packets.

    A packet whose header checksum is right ends where its size says; one whose header is
    wrong ends after the header, as the firmware looks for the next token from there. Other
    bytes (a line, or noise) end at the first line end or just before the next token.
    """
    if buffer.startswith(TOKEN, start):
        if len(buffer) < start + HEADER_SIZE:
            return None
        header = parse_header(buffer[start + 2:start + HEADER_SIZE])
        if header is None:
            return start + HEADER_SIZE
        end = start + min(header.packet_size, MAX_LINE)  # longer is noise to the firmware
        return end if end <= len(buffer) else None
    stop = min(len(buffer), start + MAX_LINE)
    newline = buffer.find(b"\n", start, stop)
    token = buffer.find(TOKEN, start + 1, stop if newline < 0 else newline)
    if token >= 0:
        return token
    if newline >= 0:
        return newline + 1
    return start + MAX_LINE if len(buffer) - start >= MAX_LINE else None


TO_PRINTER_UNITS = Framer(unit_end, MAX_LINE, filler=b"\r\n")
