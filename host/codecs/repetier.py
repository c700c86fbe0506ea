"""Host side of Repetier's protocol: encode numbered commands (binary where they fit), parse
what the printer says. Sans-IO; every line becomes exactly one event, damaged or not.

What Repetier-Firmware says (docs/protocols.md section 2): `ok <N>` when a command is queued,
an empty line + `Resend:<n>` + `ok` for a command it wants again, `skip <N>` + `ok` for one
it has already, `wait` when idle, `busy:processing` / `busy:heating` while it works.
"""

import re
from dataclasses import dataclass

from fake_marlin.host.codecs import marlin
from fake_marlin.wire import repetier

RESYNC = b"\0" * 32  # before a resend after binary: the firmware waits for 31 NULs in a row
WIRE_NUMBER = 0xFFFF  # binary N is 16 bits, and the firmware compares numbers modulo 2^16

check_command = marlin.check_command
# The words both firmwares say are Marlin's events: `ok` (Repetier's carries the number the
# line was queued under), `Resend:`, and the lines.
Line = marlin.Line
LineKind = marlin.LineKind
Ok = marlin.Ok
ResendRequest = marlin.ResendRequest


@dataclass(frozen=True)
class Skip:
    line_number: int


@dataclass(frozen=True)
class Identity:
    """M115's first line: `REPETIER_PROTOCOL:<n>` says which binary versions it reads."""

    binary_version: int  # 0 if the line does not say, or says it damaged (no digits)
    text: str


Event = Ok | ResendRequest | Skip | Identity | Line

_OK = re.compile(r"ok(?:\s+(\d+))?\s*")
_SKIP = re.compile(r"skip\s+(\d+)\s*")
_PROTOCOL = re.compile(r"\bREPETIER_PROTOCOL:(\d+)")


def parse_line(text: str) -> Event:
    if (match := _OK.fullmatch(text)) is not None:
        return Ok(line_number=int(match[1]) if match[1] else None)
    if (match := _SKIP.fullmatch(text)) is not None:
        return Skip(int(match[1]))
    if text.startswith("FIRMWARE_NAME:"):
        match = _PROTOCOL.search(text)
        return Identity(int(match[1]) if match else 0, text)
    event = marlin.parse_line(text)
    if isinstance(event, marlin.LineError):
        return Line(LineKind.ERROR, text)  # the Resend that follows says what to do
    if isinstance(event, marlin.Ok):
        return Line(LineKind.DATA, text)  # `ok` with words Repetier does not say
    return event


class LineParser(marlin.LineParser[Event]):
    """Marlin's line splitting (the empty line before a Resend skipped, damaged lines
    counted), with Repetier's words."""

    def __init__(self) -> None:
        super().__init__(parse_line)


def encode_command(number: int, command: str, binary_version: int) -> tuple[bytes, bool]:
    """The command as line `number`, and whether it went binary: binary when the printer reads
    binary and the command has a binary form (V2 only if the printer reads V2), else ASCII."""
    wire_number = number & WIRE_NUMBER
    if binary_version >= 1:
        binary = repetier.from_gcode(command, wire_number, v2=binary_version >= 2)
        if binary is not None:
            return repetier.encode(binary), True
    return marlin.encode_line(wire_number, command), False
