"""Printrhub's CommStack frames (the ESP8266 <-> MK20 link of the Printrbot Simple 2016).

A packet is an 8-byte header and up to 255 data bytes, COBS-encoded as one block (the `cobs`
package is PacketSerial's algorithm) and ended by a 0x00 (docs/protocols.md section 3). The header
is the firmware's unpacked C struct, little-endian: taskID u8, commType u8, contentLength u8,
one padding byte (sent as 00, ignored), dataCheckSum u16 (the data's byte sum) and checkSum u16
(taskID + commType + contentLength + dataCheckSum), both mod 65536.

Shared by the emulator and the host. Pure: bytes in, packets out.
"""

import struct
from dataclasses import dataclass
from enum import IntEnum

from cobs import cobs  # type: ignore[import-untyped]  # the package has no type hints

from fake_marlin.wire.framing import Framer

HEADER = struct.Struct("<BBBxHH")
BUFFER_SIZE = 256  # COMM_STACK_BUFFER_SIZE: the MK20 reads at most this much of a frame
MAX_DATA = 245  # what fits: 8 header bytes, the data, and COBS overhead in 255 bytes
CHUNK_SIZE = 128  # file data per FileSaveData, as the ESP sends it
MARKER = b"\x00"


class CommType(IntEnum):
    REQUEST = 1
    RESPONSE_SUCCESS = 2
    RESPONSE_FAILED = 3


class Task(IntEnum):
    UNKNOWN = 0
    GET_INDEX_FILE = 1
    GET_PROJECT_WITH_ID = 2
    PRINT_PROJECT_WITH_ID = 3
    GET_TIME_AND_DATE = 4
    GET_PROJECT_ITEM_WITH_ID = 5
    GET_JOB_WITH_ID = 6
    FILE_OPEN_FOR_WRITE = 7
    FILE_SAVE_DATA = 8
    FILE_CLOSE = 9
    PRINTER_COMMAND = 10
    FLUSH_BUFFER = 11
    START_WIFI = 12
    STOP_WIFI = 13
    UPDATE_MK20_FIRMWARE = 14
    UPDATE_ESP_FIRMWARE = 15
    RUN_PRINTER_GCODE = 16
    ERROR = 17
    SAVE_PROJECT_WITH_ID = 18
    FILE_SET_SIZE = 19
    SYSTEM_INFO = 20
    SCAN_WIFI = 21
    DOWNLOAD_FILE = 22
    DOWNLOAD_ERROR = 23
    START_FIRMWARE_UPDATE = 24
    PING = 25
    SHOW_FIRMWARE_UPDATE_NOTIFICATION = 26
    FIRMWARE_UPDATE_ERROR = 27
    DEBUG_LOG = 28
    RESTART_ESP = 29
    FIRMWARE_UPDATE_COMPLETE = 30
    DOWNLOAD_FILE_TO_SD_CARD = 31
    SHOW_FIRMWARE_UPDATE_IN_PROGRESS = 32
    GET_SYSTEM_INFO = 33
    SHOW_WIFI_INFO = 34
    SET_PASSWORD = 35
    SAVE_MATERIALS = 36
    CANCEL_DOWNLOAD = 37


@dataclass(frozen=True)
class Packet:
    task: int  # a Task value, or any other byte a sender chose
    comm_type: int
    data: bytes = b""


@dataclass(frozen=True)
class BadHeader:
    """The header's checksum is wrong (or there is no whole header): dropped unanswered."""

    frame: bytes


@dataclass(frozen=True)
class BadData:
    """The header is sound, the data's checksum is not: the MK20 answers ResponseFailed."""

    task: int
    comm_type: int


@dataclass(frozen=True)
class Undecodable:
    """Not COBS, or empty (a stray 0x00): the MK20 answers ResponseFailed for the last task."""

    frame: bytes


Decoded = Packet | BadHeader | BadData | Undecodable


def data_checksum(data: bytes) -> int:
    return sum(data) & 0xFFFF


def header_checksum(task: int, comm_type: int, length: int, data_sum: int) -> int:
    return (task + comm_type + length + data_sum) & 0xFFFF


def encode_packet(packet: Packet) -> bytes:
    """The packet as it goes on the wire: COBS block and 0x00. ValueError if its data is too
    long for the firmware's buffers."""
    if len(packet.data) > MAX_DATA:
        raise ValueError(f"{len(packet.data)} data bytes; a CommStack packet carries at most {MAX_DATA}")
    data_sum = data_checksum(packet.data)
    length = len(packet.data)
    header = HEADER.pack(
        packet.task, packet.comm_type, length, data_sum,
        header_checksum(packet.task, packet.comm_type, length, data_sum),
    )
    return _cobs_encode(header + packet.data) + MARKER


def _cobs_encode(data: bytes) -> bytes:
    encoded: bytes = cobs.encode(data)
    return encoded


def _cobs_decode(frame: bytes) -> bytes:
    """cobs.DecodeError if `frame` is no COBS block."""
    decoded: bytes = cobs.decode(frame)
    return decoded


def _unpack_header(raw: bytes) -> tuple[int, int, int, int, int]:
    """taskID, commType, contentLength, dataCheckSum and checkSum from the start of `raw`."""
    fields: tuple[int, int, int, int, int] = HEADER.unpack_from(raw)
    return fields


def decode_frame(frame: bytes) -> Decoded:
    """One frame (the bytes between two 0x00) as the MK20's CommStack::packetReceived sees it."""
    try:
        raw = _cobs_decode(frame)
    except cobs.DecodeError:
        return Undecodable(frame)
    if not raw:
        return Undecodable(frame)
    if len(raw) < HEADER.size:
        return BadHeader(frame)
    task, comm_type, length, data_sum, checksum = _unpack_header(raw)
    if header_checksum(task, comm_type, length, data_sum) != checksum:
        return BadHeader(frame)
    data = raw[HEADER.size:HEADER.size + length]
    if len(data) != length or data_checksum(data) != data_sum:
        return BadData(task, comm_type)
    return Packet(task, comm_type, data)


def starts_with_header(data: bytes) -> bool | None:
    """Whether `data` begins with a COBS block whose first 8 bytes are a header that checks
    out; None while too few bytes have come to say."""
    raw = bytearray()
    at = 0
    while len(raw) < HEADER.size:
        if at >= len(data):
            return None
        code = data[at]
        if code == 0:
            return False  # the frame ended before its header did
        block = data[at + 1:at + code]
        if 0 in block:
            return False
        raw += block
        if len(raw) >= HEADER.size:
            break
        if len(block) < code - 1:
            return None
        at += code
        if code < 0xFF:
            raw.append(0)
    task, comm_type, length, data_sum, checksum = _unpack_header(bytes(raw[:HEADER.size]))
    return header_checksum(task, comm_type, length, data_sum) == checksum


def frame_end(buffer: bytes | bytearray, start: int, limit: int = BUFFER_SIZE) -> int | None:
    """Just past the 0x00 that ends the frame starting at `start`, or `limit` bytes on if no
    0x00 comes within `limit` + 1 bytes (readBytesUntil stops there; the rest is read as the
    next frame); None while neither has come."""
    marker = buffer.find(0, start, start + limit + 1)
    if marker >= 0:
        return marker + 1
    return start + limit if len(buffer) - start > limit else None


class FrameSplitter:
    """Cuts the byte stream at each 0x00. Like the MK20's readBytesUntil, a frame that runs
    past BUFFER_SIZE bytes is cut there, and its rest read as the next frame."""

    def __init__(self, limit: int = BUFFER_SIZE) -> None:
        self._limit = limit
        self._buffer = bytearray()

    def receive_data(self, data: bytes) -> None:
        self._buffer += data

    def next_frame(self) -> bytes | None:
        end = frame_end(self._buffer, 0, self._limit)
        if end is None:
            if len(self._buffer) < self._limit:
                return None
            # Exactly `limit` bytes and no 0x00: cut now, as readBytesUntil does, without
            # waiting to see whether the next byte is the marker (frame_end, whose answer must
            # not depend on how the stream was cut, waits for it).
            end = self._limit
        frame = bytes(self._buffer[:end])
        del self._buffer[:end]
        return frame[:-1] if frame.endswith(MARKER) else frame


# A frame is a unit both ways: the ESP's requests and the MK20's answers (wire/framing.py).
FRAMES = Framer(frame_end, BUFFER_SIZE + 1)
TO_PRINTER_UNITS = TO_HOST_UNITS = FRAMES
