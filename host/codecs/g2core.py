"""Host side of g2core's JSON protocol: what a job's commands look like on the wire, and what
each line the board says is (the envelope itself is fake_marlin.wire.g2core's).

Sans-IO. A command is either G-code, sent as `N0<gcode>N<k>;*<checksum>` (encode_line: the
host's line number, and the XOR of every byte before the `*`, which g2core checks: a mismatch
is refused with 118 and never runs), or a JSON request `{...}` sent as it is. A fence (`*999`,
`*9999`) is a line g2core always refuses (no XOR is 999) and that never runs: the board answers
it in its turn with the G-code lines, so its answer says the board has read every line sent
before it; and a line cut short on the way (no line end) runs into it and is refused with it.

Every line the board sends becomes exactly one event, whatever its bytes: a response (`r` with
its footer), the power-up banner (a response to no line: its footer counts 1 byte), a report of
the board's own (a bare object: `sr`, `qr`, `er`, `prb`), or noise (anything that is no JSON
object). Nothing here raises on what the board says.
"""

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum

from fake_marlin.host.codecs.lines import LineBuffer
from fake_marlin.host.errors import CommandError
from fake_marlin.wire import g2core as wire
from fake_marlin.wire.checksums import xor8

# A G-code line is read into a 512-byte buffer (RX_BUFFER_SIZE) and one longer is cut; the RX
# ring holds 1024. cncjs refuses commands of 254 characters or more: so do we, and keep 14 of
# them for "N0 ", " N<10 digits>", ";*<3 digits>" and the line feed on a G-code line.
MAX_CONTROL = 253
MAX_COMMAND = MAX_CONTROL - 21
SYSTEM_READY = "SYSTEM READY"
# What the banner's body holds besides its msg (report.cpp:87-101; msg goes at jv < 2).
BANNER_NAMES = frozenset({"fv", "fb", "fbs", "fbc", "hp", "hv", "id"})
# Fences, two lengths: a host tells the answer of its newest fence from a late one of the fences
# before (docs in fake_marlin.host.cores.g2core). strtol() reads 999 or 9999, and no XOR of
# bytes is above 255: refused with 118 whatever line ran into it, and it never runs.
FENCES = ("*999", "*9999")
ENQUIRY = bytes([wire.ENQ])  # answered {"ack":true} at once, whatever is queued
# The host's own settings, which a caller's request may read but not change: without JSON mode
# (ej) and a response for every line (jv >= 1) the host cannot follow the board.
HOST_SETTINGS = frozenset({"ej", "jv"})
_TEXT_MODE_FIRST = "$?"  # text-mode commands: in JSON mode the board answers them with nothing


def check_command(command: str) -> str:
    """`command` as it can go on the wire, or CommandError saying why it cannot."""
    if not command or command != command.strip():
        raise CommandError(f"{command!r}: a command is text without surrounding white space")
    for index, char in enumerate(command):
        if not " " <= char <= "~":
            raise CommandError(f"{command!r}: character {index} is not printable ASCII")
    first = command[0]
    if first == "{":
        return _check_request(command)
    if len(command) > MAX_COMMAND:
        raise CommandError(f"{command!r}: {len(command)} characters; at most {MAX_COMMAND} fit on a line")
    if ord(first) in wire.SINGLE_CHARACTERS:
        raise CommandError(f"{command!r}: {first!r} is one of g2core's single-character commands "
                           "(the client's feedhold(), resume() and cancel() send them)")
    if first in _TEXT_MODE_FIRST:
        raise CommandError(f"{command!r}: a text-mode command, which g2core in JSON mode answers "
                           'with nothing; ask in JSON instead (e.g. {"xvm":n})')
    if first in "Nn" and command[1:2].isdigit():
        raise CommandError(f"{command!r}: the host numbers the lines itself")
    if "*" in command:
        raise CommandError(f"{command!r}: '*' starts a checksum on a g2core line")
    for char in ";%":
        if char in command:
            raise CommandError(f"{command!r}: {char!r} ends the G-code on a g2core line (the host "
                               "puts the line's number at its end)")
    if command.rfind("(") > command.rfind(")"):
        raise CommandError(f"{command!r}: a comment left open would hide the line's number")
    if command.upper().replace(" ", "").startswith("M100.1"):
        raise CommandError(f"{command!r}: M100.1 prints a response of its own, which the host "
                           "cannot tell from the line's; send the JSON request itself")
    return command


def _check_request(command: str) -> str:
    if len(command) > MAX_CONTROL:
        raise CommandError(f"{command!r}: {len(command)} characters; at most {MAX_CONTROL} fit on a line")
    try:
        pairs = wire.parse_request(command)
    except wire.RelaxedJsonError as error:
        raise CommandError(f"{command!r}: g2core would refuse it: {error}") from None
    for name, value in pairs.items():
        if name in HOST_SETTINGS and not isinstance(value, wire.Null):
            raise CommandError(f"{command!r}: the host keeps {name} itself (it reads it, "
                               "but setting it would leave the host unable to follow the board)")
    return command


def is_request(command: str) -> bool:
    """A JSON request (sent bare, answered ahead of any G-code queued before it), not G-code."""
    return command.startswith("{")


def encode_line(number: int, command: str) -> bytes:
    """`N0<command>N<number>;*<checksum>` and a line feed; the caller has checked the command.

    Spelt so that what g2core's checks cannot see does least harm. g2core takes the last N word
    of a line as its number, and a line with a `*` must start with `N`: so the line starts with
    N0 (0 is no line number: a response never shows it) and ends with its number. A line whose
    end was lost on the way and that a line end from elsewhere closed runs unchecked (no `*`),
    and so does a line cut in two by a byte damaged into a line end: either runs as line 0, which
    the host sees, where it would otherwise run as the line, cut short. A `;` (node-g2core-api's
    way) ends the G-code for the parser: should the `*` be damaged, the line runs unchecked, but
    with its checksum digits as a comment, not in its number. No space before the number (a
    space is one bit from `(`, which would make it a comment) unless the command ends in a
    letter."""
    head = "N0" if command[:1].isalpha() else "N0 "
    tail = " N" if command[-1:].isalpha() else "N"
    body = f"{head}{command}{tail}{number};".encode("ascii")
    return body + b"*%d\n" % xor8(body)


def encode_request(request: str) -> bytes:
    return request.encode("ascii") + b"\n"


def encode_fence(generation: int) -> bytes:
    return FENCES[generation % len(FENCES)].encode("ascii") + b"\n"


def fence_size(generation: int) -> int:
    """The footer's length in a fence's answer: its bytes and the line end."""
    return len(FENCES[generation % len(FENCES)]) + 1


# -- what the board says -------------------------------------------------------------------
@dataclass(frozen=True)
class Response:
    """`{"r":{...},"f":[1,status,length]}`: the board's answer to one line it read."""

    body: Mapping[str, object] = field(hash=False)
    status: int
    length: int  # the footer's third element: the bytes of the line it answers
    text: str


@dataclass(frozen=True)
class Boot:
    """The power-up banner (`"msg":"SYSTEM READY"`, or a footer counting 1 byte and the
    banner's names): the board has just started, or a host has just connected to it; no line's
    answer."""

    body: Mapping[str, object] = field(hash=False)
    status: int
    text: str


@dataclass(frozen=True)
class Report:
    """A bare object without a footer: a report of the board's own (`sr`, `qr`, `er`, `prb`...),
    never an answer to a line. `name`: its first key."""

    name: str
    body: Mapping[str, object] = field(hash=False)
    text: str


@dataclass(frozen=True)
class Noise:
    """A line that is no JSON object: a text-mode prompt, or damage. `damaged`: bytes or a shape
    the board never sends (non-printable bytes, or a `{` line that does not parse)."""

    text: str
    damaged: bool


Event = Response | Boot | Report | Noise


def is_fence_answer(response: Response) -> bool:
    """A refusal without a line number, of a fence's length (of either generation)."""
    return (response.status != wire.OK and "n" not in response.body
            and response.length in {len(fence) + 1 for fence in FENCES})


class LineKind(Enum):
    """What a line the caller is shown is."""

    REPORT = "report"  # sr, qr, prb and other reports of the board's own
    EXCEPTION = "exception"  # er: an exception report (alarm, shutdown, panic, job kill...)
    BOOT = "boot"  # the power-up banner
    RESPONSE = "response"  # a response the host was waiting for from nobody
    NOISE = "noise"  # no JSON: a text-mode prompt, or damage


@dataclass(frozen=True)
class Line:
    """A line of the board's that is no answer to one of the caller's commands."""

    kind: LineKind
    text: str  # the line as the board said it
    body: Mapping[str, object] = field(default_factory=dict, hash=False)  # its JSON, parsed


def parse_line(raw: bytes) -> Event:
    """One line from the board (without its line end) as an event; never raises."""
    text = raw.decode("ascii", "replace")
    try:
        reply = wire.parse_reply(raw)
    except RecursionError:  # nested deeper than json's C decoder goes: no board says that
        reply = None
    if reply is None:
        return Noise(text, _garbled(raw) or raw.lstrip().startswith(b"{"))
    footer = reply.footer
    if footer is None:
        name = next(iter(reply.body), "")
        return Report(name, reply.body, text)
    status = int(footer.status)  # (a bool is an int to json too)
    # The banner's footer counts 1 byte, which no line's can; but a digit of a footer lost or
    # flipped on the way can say 1 too, so its body must look like a banner's as well.
    if reply.body.get("msg") == SYSTEM_READY or (
            int(footer.length) == 1 and len(reply.body.keys() & BANNER_NAMES) >= 2):
        return Boot(reply.body, status, text)
    return Response(reply.body, status, int(footer.length), text)


def _garbled(raw: bytes) -> bool:
    return any(not (0x20 <= byte <= 0x7E or byte == 0x09) for byte in raw)


class ReplyReader:
    """Splits what arrives into lines (bounded: noise cannot grow memory) and parses each."""

    def __init__(self) -> None:
        self._lines = LineBuffer()

    def receive_data(self, data: bytes) -> None:
        self._lines.receive_data(data)

    def next_event(self) -> Event | None:
        while (raw := self._lines.next_line()) is not None:
            raw = raw.rstrip(b"\r")
            if raw.strip():
                return parse_line(raw)
        return None


def compact(body: Mapping[str, object]) -> str:
    """A body as JSON text, for a command's response data."""
    return json.dumps(body, separators=(",", ":"))
