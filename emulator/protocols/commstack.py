"""The MK20's side of CommStack, as a sans-IO state machine (Printrhub's mk20 CommStack.cpp).

Frames are read one at a time, as CommStack::process() reads them: `readBytesUntil(0, buffer,
256)` on the Teensy 3.1 core, which keeps the last byte of the buffer for a NUL, so a read ends
at a 0x00 (taken from the line), after 255 bytes (the next byte, even a 0x00, is left for the
next read: a 255-byte frame is followed by an empty one), or when no byte has come for the
stream's timeout, 1 s (told by `time_passed`: the bytes so far are a frame). Each frame is copied
into the current header before its checksum is checked, so the task of any frame that decodes,
sound or not, is the one a ResponseFailed is sent under next. A request whose data checksum is
wrong is answered at once with an empty ResponseFailed for its task; a frame whose header
checksum is wrong is dropped without a word; a frame that is no COBS at all (or empty, as a
stray 0x00 makes it) is answered with a ResponseFailed for that current header's task. Only
requests are answered; responses from the other side are passed on and never answered.
"""

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from cobs import cobs  # type: ignore[import-untyped]  # the package has no type hints

from fake_marlin.wire.commstack import (
    BUFFER_SIZE,
    BadData,
    BadHeader,
    CommType,
    Packet,
    decode_frame,
    encode_packet,
)

READ_LIMIT = BUFFER_SIZE - 1  # Teensy's Stream::readBytesUntil(t, buf, n) reads n - 1 at most
READ_TIMEOUT = 1.0  # Stream's default timeout, which the MK20 never changes: s between bytes


# Events out.
@dataclass(frozen=True)
class RequestReceived:
    task: int
    data: bytes


@dataclass(frozen=True)
class ResponseReceived:
    packet: Packet


@dataclass(frozen=True)
class FrameRejected:
    """A damaged frame: `answered` if the firmware said ResponseFailed for it."""

    reason: str
    answered: bool


Event = RequestReceived | ResponseReceived | FrameRejected


# Events in.
@dataclass(frozen=True)
class Response:
    task: int
    success: bool = True
    data: bytes = b""


class FrameReader:
    """Serial3.readBytesUntil(0, _receiveBuffer, COMM_STACK_BUFFER_SIZE), one call per frame."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._timed_out = False

    @property
    def reading(self) -> bool:
        """Bytes of a frame have come, and its end has not: the read waits for more."""
        return bool(self._buffer)

    def receive_data(self, data: bytes) -> None:
        self._buffer += data
        self._timed_out = False

    def end_frame(self) -> None:
        """The read gives up waiting (READ_TIMEOUT without a byte): it ends with what it has."""
        self._timed_out = bool(self._buffer)

    def next_frame(self) -> bytes | None:
        end = self._buffer.find(0, 0, READ_LIMIT)
        if end >= 0:
            frame = bytes(self._buffer[:end])
            del self._buffer[:end + 1]
        elif len(self._buffer) >= READ_LIMIT or self._timed_out:
            frame = bytes(self._buffer[:READ_LIMIT])
            del self._buffer[:READ_LIMIT]  # the byte after a full buffer is the next read's
            self._timed_out = False
        else:
            return None
        return frame


class CommStackProtocol:
    def __init__(self) -> None:
        self._frames = FrameReader()
        self._last_task = 0  # _currentHeader.taskID: what an undecodable frame is answered as
        self._output = bytearray()
        self._last_byte = -math.inf  # when a byte last came
        self._heard = False  # bytes came since the last time_passed()

    @property
    def reading(self) -> bool:
        """A frame has begun and not ended: it ends READ_TIMEOUT after the last byte."""
        return self._frames.reading

    def receive_data(self, data: bytes) -> None:
        self._frames.receive_data(data)
        self._heard = True

    def time_passed(self, now: float) -> None:
        if self._heard:
            self._last_byte, self._heard = now, False
        elif self.reading and now >= self._last_byte + READ_TIMEOUT:
            self._frames.end_frame()  # next_event() gives the frame as it is

    def next_deadline(self) -> float | None:
        return self._last_byte + READ_TIMEOUT if self.reading else None

    def next_event(self) -> Event | None:
        frame = self._frames.next_frame()
        if frame is None:
            return None
        decoded = decode_frame(frame)
        if isinstance(decoded, Packet):
            self._last_task = decoded.task
            if decoded.comm_type == CommType.REQUEST:
                return RequestReceived(decoded.task, decoded.data)
            return ResponseReceived(decoded)
        if isinstance(decoded, BadHeader):
            # packetReceived() copies the header in before it checks it: whatever the first
            # byte now says is the task the next ResponseFailed goes out under.
            self._last_task = _first_byte(frame, self._last_task)
            return FrameRejected("header checksum", answered=False)
        if isinstance(decoded, BadData):
            self._last_task = decoded.task
            self._fail(decoded.task)
            return FrameRejected("data checksum", answered=True)
        self._fail(self._last_task)
        return FrameRejected("not a COBS frame", answered=True)

    def _fail(self, task: int) -> None:
        self._output += encode_packet(Packet(task, CommType.RESPONSE_FAILED))

    def send(self, event: Response) -> bytes:
        if not isinstance(event, Response):
            raise TypeError(f"cannot send {event!r}")
        comm_type = CommType.RESPONSE_SUCCESS if event.success else CommType.RESPONSE_FAILED
        self._output += encode_packet(Packet(event.task, comm_type, event.data))
        return self.data_to_send()

    def data_to_send(self) -> bytes:
        data = bytes(self._output)
        self._output.clear()
        return data


def _first_byte(frame: bytes, default: int) -> int:
    """The first byte of a COBS frame once decoded (`default` if it decodes to nothing)."""
    try:
        raw: bytes = cobs.decode(frame)
    except cobs.DecodeError:
        return default
    return raw[0] if raw else default


if TYPE_CHECKING:  # mypy holds the machine to the shared interface
    from fake_marlin.emulator.protocols.base import TimedMachine

    _: type[TimedMachine[Event, Response]] = CommStackProtocol
