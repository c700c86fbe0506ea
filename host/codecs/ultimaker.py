"""Host side of Ultimaker's protocol: encode v2 packets, parse v3 frames and lines."""

import re
from dataclasses import dataclass
from enum import Enum

from fake_marlin.host.codecs.lines import LineBuffer
from fake_marlin.host.errors import CommandError
from fake_marlin.wire import ultimaker as wire

_FRAME = re.compile(r"([orq])([0-9A-F]{2})([0-9A-F]{2})([0-9A-F]{2})")


def encode_command(seq: int, command: str) -> bytes:
    payload = check_command(command)
    return wire.encode_packet(seq, payload)


def check_command(command: str) -> bytes:
    """The payload for `command`, or CommandError saying why it cannot be sent."""
    try:
        payload = command.encode("ascii")
    except UnicodeEncodeError:
        raise CommandError(f"{command!r} is not plain ASCII") from None
    problem = wire.payload_error(payload)
    if problem:
        raise CommandError(f"{command!r}: {problem}")
    return payload


@dataclass(frozen=True)
class Ack:
    """`o`: the packet `seq` was executed."""

    seq: int
    room: int


@dataclass(frozen=True)
class Reject:
    """`r`: resend from `seq`, the printer's next expected sequence number."""

    seq: int
    room: int


@dataclass(frozen=True)
class RoomInfo:
    """`q`: the planner has room again."""

    room: int


@dataclass(frozen=True)
class CorruptFrame:
    """A frame whose CRC8 does not match; ignored, the timeout recovers it."""

    text: str


class LineKind(Enum):
    RESPONSE = "response"
    PROTO_ERROR = "ProtoError"
    ERROR = "Error"
    WARNING = "WARNING"
    LOG = "LOG"


_PREFIXES = (
    ("ProtoError:", LineKind.PROTO_ERROR),
    ("ProtoErr:", LineKind.PROTO_ERROR),
    ("Error:", LineKind.ERROR),
    ("WARNING:", LineKind.WARNING),
    ("LOG:", LineKind.LOG),
)


@dataclass(frozen=True)
class Line:
    kind: LineKind
    text: str  # without the prefix for out-of-band lines


Event = Ack | Reject | RoomInfo | CorruptFrame | Line


class FrameParser:
    def __init__(self) -> None:
        self._lines = LineBuffer()

    def receive_data(self, data: bytes) -> None:
        self._lines.receive_data(data)

    def next_event(self) -> Event | None:
        while (raw := self._lines.next_line()) is not None:
            text = raw.decode("ascii", "replace").strip("\r")
            if text:
                return parse_line(text)
        return None


def parse_line(text: str) -> Event:
    match = _FRAME.fullmatch(text)
    if match:
        kind, seq, room, crc = match.groups()
        if wire.frame_body(kind, int(seq, 16), int(room, 16)) != text:
            return CorruptFrame(text)
        if kind == "o":
            return Ack(int(seq, 16), int(room, 16))
        if kind == "r":
            return Reject(int(seq, 16), int(room, 16))
        return RoomInfo(int(room, 16))
    for prefix, kind in _PREFIXES:
        if text.startswith(prefix):
            return Line(kind, text[len(prefix):].strip())
    return Line(LineKind.RESPONSE, text)
