"""Parsing one line of G-code the way Marlin's GCodeParser reads it."""

import re
from dataclasses import dataclass, field
from typing import overload

from fake_marlin.wire.gcode import WORD, strip_comment


@dataclass(frozen=True)
class Command:
    text: str  # the normalised command as executed (comment stripped)
    code: str  # "G1", "M105", "T0"; "" for a line without a command word
    params: dict[str, float | None] = field(default_factory=dict)

    def has(self, letter: str) -> bool:
        return letter in self.params

    @overload
    def value(self, letter: str) -> float | None: ...
    @overload
    def value(self, letter: str, default: float) -> float: ...
    @overload
    def value(self, letter: str, default: float | None) -> float | None: ...

    def value(self, letter: str, default: float | None = None) -> float | None:
        """The number after `letter`; `default` when the letter is absent or has none."""
        value = self.params.get(letter)
        return default if value is None else value

    @property
    def string_argument(self) -> str:
        """The free text after the command word (M117, M118, M23 file names)."""
        return self.text[len(self.code):].strip() if self.code else ""


# Marlin's GCodeParser takes the command letter where the line starts (after spaces and a line
# number): a line whose first character is anything else is an unknown command, however much
# G-code follows. (A damaged leading N makes such a line, `\x0e1190 G1 X35 ...`: it must not move.)
_COMMAND_START = re.compile(r"\s*(?:N-?\d+\s*)?(?=[A-Za-z])")
# A command that is a word, not a letter and a number: Klipper's extended commands
# (`FIRMWARE_RESTART`, `SET_HEATER_TEMPERATURE HEATER=extruder`), Prusa's `PRUSA Fir`. Its code
# is the word, upper case; its arguments are its handler's to read (string_argument).
_WORD_COMMAND = re.compile(r"[A-Za-z][A-Za-z_][A-Za-z0-9_]*(?![.\d])")


LONG_MIN, LONG_MAX = -(2**31), 2**31 - 1  # an AVR's long: what strtol() clamps a number to


def whole(value: float) -> int:
    """parser.value_int() of a number: strtol's, clamped to a long (inf and 1e400 are no int)."""
    if value != value:  # NaN
        return 0
    return int(max(LONG_MIN, min(LONG_MAX, value)))


def parse(line: str) -> Command:
    text = strip_comment(line)
    start = _COMMAND_START.match(text)
    if start and (word := _WORD_COMMAND.match(text, start.end())):
        return Command(text, word[0].upper(), {})
    words = WORD.findall(text, start.end()) if start else []
    if not words or words[0][0].upper() not in "GMTD" or (words[0][0].upper() != "T" and not words[0][1]):
        return Command(text, "", {})
    letter, number = words[0]
    code = letter.upper() + _integer_text(number)
    params: dict[str, float | None] = {}
    for param_letter, param_number in words[1:]:
        params[param_letter.upper()] = float(param_number) if param_number else None
    return Command(text, code, params)


# G0/G1 as hosts send them: `G1 X10.4 Y10.0 E0.020 F6000` (Cura puts F first, `G1 F1500 X10.4
# Y10.0 E0.020`), upper case, single spaces, plain numbers, each axis at most once and in this
# order, nothing else on the line. The groups are the numbers, so that the planner reads them
# without reading the line again. Each word starts with the space no word holds, so no match
# depends on backtracking: possessive, the pattern keeps no states to go back to.
_NUMBER = r"(-?\d++(?:\.\d*+)?+)"
_PLAIN_MOVE = re.compile(rf"G[01](?: F{_NUMBER})?+(?: X{_NUMBER})?+(?: Y{_NUMBER})?+"
                         rf"(?: Z{_NUMBER})?+(?: E{_NUMBER})?+(?: F{_NUMBER})?+")

# A plain move's numbers as written, None where the line has none: F (before the axes), X, Y,
# Z, E, F (after them).
PlainMove = tuple[str | None, str | None, str | None, str | None, str | None, str | None]


def plain_move(text: str) -> PlainMove | None:
    """The numbers of text if it is the usual straight move, the most common command by far,
    which Printer.move_at_once() takes and plans from them without parse(); None for any other
    line (a move with its words in another order included: parse() reads that one).
    tests/test_printer_model.py holds the two to parse() and execute()."""
    match = _PLAIN_MOVE.fullmatch(text)
    if match is None or match.lastindex is None:  # no word at all: `G1` alone takes parse()
        return None
    return match.groups()  # type: ignore[return-value]  # six groups, as PlainMove says


def is_plain_move(text: str) -> bool:
    """Whether plain_move() reads text."""
    return plain_move(text) is not None


def _integer_text(number: str) -> str:
    if not number:
        return ""
    try:
        return str(int(float(number)))
    except (ValueError, OverflowError):  # OverflowError: a number of 309 digits and more
        return number
