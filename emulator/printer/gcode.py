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


def parse(line: str) -> Command:
    text = strip_comment(line)
    start = _COMMAND_START.match(text)
    words = WORD.findall(text, start.end()) if start else []
    if not words or words[0][0].upper() not in "GMT" or (words[0][0].upper() != "T" and not words[0][1]):
        return Command(text, "", {})
    letter, number = words[0]
    code = letter.upper() + _integer_text(number)
    params: dict[str, float | None] = {}
    for param_letter, param_number in words[1:]:
        params[param_letter.upper()] = float(param_number) if param_number else None
    return Command(text, code, params)


# G0/G1 as hosts send them: `G1 X10.4 Y10.0 E0.020 F6000`, upper case, single spaces, plain
# numbers, nothing else on the line.
# Each word starts with the space no word holds, so no match depends on backtracking: the
# possessive and atomic forms match the same lines, in half the time.
_PLAIN_MOVE = re.compile(r"G[01](?> [XYZEF]-?\d++(?:\.\d*+)?+)++")


def is_plain_move(text: str) -> bool:
    """Whether text is the usual straight move, the most common command by far, which
    Printer.move_at_once() takes and plans from its words without parse().
    tests/test_printer_model.py holds the two to parse() and execute()."""
    return _PLAIN_MOVE.fullmatch(text) is not None


def _integer_text(number: str) -> str:
    if not number:
        return ""
    try:
        return str(int(float(number)))
    except (ValueError, OverflowError):  # OverflowError: a number of 309 digits and more
        return number
