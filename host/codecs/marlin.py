"""Host side of Marlin's ASCII protocol: encode numbered lines, parse what the printer says.

Sans-IO. What Marlin 2.1 says is listed in docs/protocols.md section 6; hosts that read it
(OctoPrint, printcore) are in docs/hosts.md. Every line the printer sends becomes exactly one
event, whatever its bytes: damaged lines come out as data (or as a line error whose number is
unknown), never as an exception.
"""

import re
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from typing import Generic, TypeVar, cast, overload

from fake_marlin.host.codecs.lines import LineBuffer
from fake_marlin.host.errors import CommandError
from fake_marlin.wire.checksums import xor8

# Marlin keeps at most MAX_CMD_SIZE - 1 = 95 characters of a line. "N<9 digits> " and "*255"
# take 15 of them, so a command of 80 characters fits until line number 10^9.
MAX_COMMAND = 80
MAX_WIRE_LINE = 95

# The probe: a numbered line the printer always refuses and never runs. "M110" anywhere in a
# line makes Marlin skip the line-number check, and its checksum, 256, can never match (Marlin
# compares it with a byte): `Error:checksum mismatch, Last Line: <L>`, `Resend: <L+1>`, `ok`
# give the printer's line counter, read without side effects. No single bit flip makes it
# acceptable: one in the line changes its XOR to a value none of whose one-flip neighbours is
# 256, one in "256" gives none of the values the line's XOR (122) could be, and one that
# changes "M110" leaves N0, which no counter >= 0 is followed by.
# Its command is M105, with the M110 after it: Marlin's emergency parser acts on a line's first
# command the moment it arrives, checksum or not, and a lone "M110" is one bit from "M112"
# (kill). M105 is three bits from the nearest emergency command (M108), and the parser never
# looks past the first command. (The probe sent during recovery from a noisy line killed the
# printer in a test before this.)
# It starts with a line feed. Without it, a probe sent after a line whose end was lost joins
# that line, and Marlin, finding "M110" in the joined line, takes its line number from the
# probe's N0: it would run the line and set its counter to 0 if the first line's checksum were
# the last one. The line feed ends the partial line first (which is then run or refused on its
# own merits); an empty line is ignored. Should both line feeds be lost, the probe's own `*256`
# is the last checksum of the joined line, and it refuses it. (Without it, a campaign at a bit
# error rate of 1e-3 both ways had a printer's counter set to 0 that way, for good.)
PROBE = b"\nN0 M105 M110*256\n"


def xor_checksum(data: bytes) -> int:
    return xor8(data)


def check_command(command: str) -> str:
    """`command` as it can go on a numbered line, or CommandError saying why it cannot."""
    if not command or command != command.strip():
        raise CommandError(f"{command!r}: a command is text without surrounding white space")
    if len(command) > MAX_COMMAND:
        raise CommandError(f"{command!r}: {len(command)} characters; at most {MAX_COMMAND} fit on a line")
    for index, char in enumerate(command):
        if not " " <= char <= "~":
            raise CommandError(f"{command!r}: character {index} is not printable ASCII")
    # `;` starts a comment and `\` escapes in Marlin's reader, and the last `*` starts the
    # checksum: each would make the printer check a different line than the host summed.
    for char, meaning in ((";", "a comment"), ("\\", "an escape"), ("*", "the checksum")):
        if char in command:
            raise CommandError(f"{command!r}: {char!r} starts {meaning} on a Marlin line")
    if "M110" in command.upper():
        raise CommandError(f"{command!r}: M110 sets the line number, which the host keeps itself")
    return command


def encode_line(number: int, command: str) -> bytes:
    """`N<number> <command>*<checksum>` and a line feed; the caller has checked the command."""
    body = f"N{number} {command}".encode("ascii")
    line = body + b"*%d" % xor_checksum(body)
    if len(line) > MAX_WIRE_LINE:
        raise CommandError(f"{command!r} does not fit on line {number}")
    return line + b"\n"


def encode_sync(command: str) -> bytes:
    """The host's own M110 line, after a line feed for the reason PROBE has one."""
    return b"\n" + encode_line(0, command)


# -- what the printer says ----------------------------------------------------------------
@dataclass(frozen=True)
class Ok:
    """`ok`: a command finished (or, after Resend, the printer is ready again)."""

    text: str = ""  # what M105 says on the ok line itself; ADVANCED_OK's fields taken out
    line_number: int | None = None  # ADVANCED_OK: ` N<line>`
    planner_free: int | None = None  # ADVANCED_OK: ` P<n>`
    queue_free: int | None = None  # ADVANCED_OK: ` B<n>`


@dataclass(frozen=True)
class ResendRequest:
    """`Resend: <n>` or `rs <n>`: send again from line n. None if the number was unreadable."""

    line: int | None
    text: str


class LineErrorKind(Enum):
    LINE_NUMBER = "line number"
    CHECKSUM = "checksum"
    NO_CHECKSUM = "no checksum"
    OTHER = "other"  # another firmware's wording of a line error


@dataclass(frozen=True)
class LineError:
    """An `Error:` about the line itself; Resend and ok follow. `last_line`: the printer's
    counter, the last line number it accepted (None if unreadable)."""

    kind: LineErrorKind
    last_line: int | None
    text: str


class LineKind(Enum):
    DATA = "data"  # anything else: a command's response (M114, M115, file lists), or noise
    ECHO = "echo"
    BUSY = "busy"  # `echo:busy: processing`, `busy: paused for user`: alive, still working
    WAIT = "wait"  # the command queue is empty (Marlin's NO_TIMEOUTS)
    START = "start"  # the firmware booted: `start`, or its reset reason
    REPORT = "report"  # temperatures or position the printer reports on its own (M155, M154,
    # and M109/M190 while they wait, with ` W:`): never a command's response
    ACTION = "action"  # `//action:...` for the host
    ERROR = "Error"  # an Error: line that is no line error and no halt
    HALTED = "halted"  # kill(): `Error:Printer halted. kill() called!` or a kill reason
    LOCKED = "locked"  # PASSWORD_FEATURE: `echo:Printer locked! (Unlock with M511 or LCD)`


@dataclass(frozen=True)
class Line:
    kind: LineKind
    text: str  # the whole line, as the printer said it


Event = Ok | ResendRequest | LineError | Line

_OK = re.compile(r"ok(?:\s+(.*))?")
_ADVANCED_OK = re.compile(r"(?:N(-?\d+))?\s*(?:P(\d+)\s+B(\d+))?\s*")
_RESEND = re.compile(r"(?:resend|rs)\b:?\s*(?:N:?\s*)?(\d+)?", re.IGNORECASE)
_LAST_LINE = re.compile(r"last\s*line:?\s*(-?\d+)", re.IGNORECASE)
_BUSY = re.compile(r"(?:echo:)?\s*busy:", re.IGNORECASE)
_TEMPERATURE = re.compile(r"\s*(?:T\d*|B|C):\s*-?\d")
_POSITION_REPORT = re.compile(r"X:\S+ Y:\S+ Z:\S+ E:\S+")  # M154's; M114 adds " Count ..."
_RESET_REASON = re.compile(  # Marlin 2.1 says it alone, 1.1 after `echo:`, Repetier after `Info:`
    r"(?:(?:echo|Info):)?\s*"
    r"(?:PowerUp|External Reset|Brown out Reset|Watchdog Reset|Software Reset)\s*$"
)
# OctoPrint's words for a line error, and Marlin's three.
_LINE_ERRORS = (
    ("line number is not last line number+1", LineErrorKind.LINE_NUMBER),
    ("checksum mismatch", LineErrorKind.CHECKSUM),
    ("no checksum", LineErrorKind.NO_CHECKSUM),
    ("checksum", LineErrorKind.OTHER),
    ("line number", LineErrorKind.OTHER),
    ("linenumber", LineErrorKind.OTHER),
    ("format error", LineErrorKind.OTHER),
    ("expected line", LineErrorKind.OTHER),
    ("last line", LineErrorKind.OTHER),
)
# What Marlin prints when kill() stops it, and the reasons it prints just before.
_HALT_WORDS = (
    "printer halted", "kill() called", "system stopped", "thermal runaway",
    "maxtemp", "mintemp", "heating failed",
)


def parse_line(text: str) -> Event:
    """One line from the printer (without its line end) as an event."""
    match = _OK.fullmatch(text)
    if match:
        return _parse_ok(match[1] or "")
    match = _RESEND.match(text)
    if match:
        return ResendRequest(int(match[1]) if match[1] else None, text)
    lowered = text.lower()
    if lowered.startswith("error:"):
        return _parse_error(text, lowered)
    if text == "start" or _RESET_REASON.match(text):
        return Line(LineKind.START, text)
    if text == "wait":
        return Line(LineKind.WAIT, text)
    if _BUSY.match(text):
        return Line(LineKind.BUSY, text)
    if lowered.startswith("echo:printer locked"):
        return Line(LineKind.LOCKED, text)
    if lowered.startswith("echo:"):
        return Line(LineKind.ECHO, text)
    if text.startswith("//action:"):
        return Line(LineKind.ACTION, text)
    if lowered.startswith("fatal:"):
        return Line(LineKind.HALTED, text)
    if _TEMPERATURE.match(text) or _POSITION_REPORT.fullmatch(text):
        return Line(LineKind.REPORT, text)
    return Line(LineKind.DATA, text)


def _parse_ok(rest: str) -> Ok:
    advanced = _ADVANCED_OK.fullmatch(rest)
    if rest and advanced and (advanced[1] or advanced[2]):
        return Ok(
            "",
            int(advanced[1]) if advanced[1] else None,
            int(advanced[2]) if advanced[2] else None,
            int(advanced[3]) if advanced[3] else None,
        )
    return Ok(rest.strip())


def is_halt_message(text: str) -> bool:
    """An Error: text saying kill() stopped the firmware (any Marlin, UltimakerMarlin too)."""
    lowered = text.lower()
    return any(word in lowered for word in _HALT_WORDS)


def _parse_error(text: str, lowered: str) -> Event:
    if is_halt_message(text):
        return Line(LineKind.HALTED, text)
    for words, kind in _LINE_ERRORS:
        if words in lowered:
            last = _LAST_LINE.search(text)
            return LineError(kind, int(last[1]) if last else None, text)
    return Line(LineKind.ERROR, text)


def is_garbled(raw: bytes) -> bool:
    """Bytes Marlin never sends (it speaks printable ASCII): the line was damaged on the way."""
    return any(not (0x20 <= byte <= 0x7E or byte == 0x09) for byte in raw)


_EventT = TypeVar("_EventT")


class LineParser(Generic[_EventT]):
    """Splits what arrives into lines and parses each; counts the lines that came damaged.
    Its events are what `parse` makes of a line: Marlin's (Event) unless told otherwise."""

    @overload
    def __init__(self: "LineParser[Event]") -> None: ...
    @overload
    def __init__(self, parse: Callable[[str], _EventT]) -> None: ...

    def __init__(self, parse: Callable[[str], object] = parse_line) -> None:
        self._lines = LineBuffer()
        # Repetier's replies are lines too, with words of their own. The overloads tie the
        # parser's event type to `parse` (parse_line's Event when it is left out).
        self._parse = cast("Callable[[str], _EventT]", parse)
        self.garbled = 0

    def receive_data(self, data: bytes) -> None:
        self._lines.receive_data(data)

    def next_event(self) -> _EventT | None:
        while (raw := self._lines.next_line()) is not None:
            raw = raw.rstrip(b"\r")
            if not raw.strip():
                continue
            if is_garbled(raw):
                self.garbled += 1
            return self._parse(raw.decode("ascii", "replace").strip())
        return None
