"""Host side of Ultimaker's protocol: encode v2 packets, parse v3 frames and lines, and the
protocol lab's variants of both (wire/ultimaker_variants.py)."""

import re
from dataclasses import dataclass
from enum import Enum

from fake_marlin.host.codecs.lines import LineBuffer
from fake_marlin.host.errors import CommandError
from fake_marlin.wire import ultimaker as wire
from fake_marlin.wire import ultimaker_variants as lab
from fake_marlin.wire.ultimaker_variants import PLAIN, PacketFormat, Variants

# `a` is the ack variant's; a host without it reads it to say why it cannot go on.
_FRAME = re.compile(r"([oraq])([0-9A-F]{2})([0-9A-F]{2})([0-9A-F]{2})")


def encode_command(seq: int, command: str, packet: PacketFormat = lab.V3_PACKET) -> bytes:
    return packet.encode(seq, check_command(command))


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
class Received:
    """`a` (the ack variant): the packet `seq` is in the printer's queue, not yet executed."""

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


Event = Ack | Reject | Received | RoomInfo | CorruptFrame | Line


class FrameParser:
    def __init__(self, variants: Variants = PLAIN) -> None:
        self._lines = LineBuffer()
        self.variants = variants

    def receive_data(self, data: bytes) -> None:
        self._lines.receive_data(data)

    def next_event(self) -> Event | None:
        while (raw := self._lines.next_line()) is not None:
            text = raw.decode("ascii", "replace").strip("\r")
            if text:
                return parse_line(text, self.variants)
        return None


_COMPACT = tuple((prefix, LineKind(name)) for name, prefix in lab.COMPACT_PREFIXES.items())
_COMPACT_LOG = lab.COMPACT_PREFIXES["LOG"]


def parse_line(text: str, variants: Variants = PLAIN) -> Event:
    """One line from the printer. A host with compact-oob reads both forms of out-of-band
    line (and unescapes `d:` data); one without reads a compact variant announcement too, so
    that either can say what the printer speaks."""
    match = _FRAME.fullmatch(text)
    if match:
        kind, seq, room, crc = match.groups()
        if wire.frame_body(kind, int(seq, 16), int(room, 16)) != text:
            return CorruptFrame(text)
        if kind == "o":
            return Ack(int(seq, 16), int(room, 16))
        if kind == "r":
            return Reject(int(seq, 16), int(room, 16))
        if kind == "a":
            return Received(int(seq, 16), int(room, 16))
        return RoomInfo(int(room, 16))
    if variants.compact_oob:
        if text.startswith(lab.DATA_ESCAPE):
            return Line(LineKind.RESPONSE, text[len(lab.DATA_ESCAPE):])
        for prefix, kind in _COMPACT:
            if text.startswith(prefix):
                return Line(kind, text[len(prefix):].strip())
    elif text.startswith(_COMPACT_LOG + lab.ANNOUNCEMENT):
        return Line(LineKind.LOG, text[len(_COMPACT_LOG):])
    for prefix, kind in _PREFIXES:
        if text.startswith(prefix):
            return Line(kind, text[len(prefix):].strip())
    return Line(LineKind.RESPONSE, text)
