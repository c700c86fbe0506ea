"""What counts as the command on a G-code line. Host and printer must agree on this exactly:
it is what the host sends and what the printer's journal records."""

import math
import re
import struct
from decimal import Decimal

_PAREN_COMMENT = re.compile(r"\([^)]*\)")


def strip_comment(line: str) -> str:
    """The command without `;` and `( )` comments or surrounding white space."""
    if ";" not in line and "(" not in line:
        return line.strip()  # the usual line: no regex to run
    return remove_paren_comments(line.split(";", 1)[0]).strip()


def remove_paren_comments(text: str) -> str:
    return _PAREN_COMMENT.sub("", text)


# -- the same command, however it is written ------------------------------------------------
TEXT_ARGUMENT_CODES = frozenset({"M23", "M28", "M29", "M30", "M32", "M117", "M118"})
NUMBER = r"[-+]?(?:\d+(?:\.\d*)?|\.\d+)"  # a G-code number: no exponents, no underscores
# (\d+\.?\d* matched the same, but let a failing match try every split of a run of digits
# between \d+ and \d*: exponential, minutes for a 93-character line; found by fuzzing.)
WORD = re.compile(rf"([A-Za-z])\s*({NUMBER})?")  # a letter and its value, if it has one
_WORDS = re.compile(rf"(?:\s*[A-Za-z]\s*(?:{NUMBER})?)+\s*")
_TEXT_COMMAND = re.compile(r"([A-Za-z])(\d+)\s*(.*)", re.DOTALL)  # M117 and the like: word, text


def float32(value: float) -> float:
    """`value` as a float32 holds it (OverflowError if it cannot)."""
    rounded: float = struct.unpack("<f", struct.pack("<f", value))[0]
    return rounded


def number_text(value: float) -> str:
    """The shortest plain decimal that is the same float32 (an int as itself)."""
    if isinstance(value, int) or not math.isfinite(value):
        return str(value)
    text = repr(value)
    for digits in range(1, 10):
        candidate = f"{value:.{digits}g}"
        try:
            if float32(float(candidate)) == value:
                text = candidate
                break
        except OverflowError:  # rounded past the largest float32 (FLT_MAX): more digits
            continue
    plain = format(Decimal(text), "f")
    return plain.rstrip("0").rstrip(".") if "." in plain else plain


def canonical(command: str) -> str:
    """One spelling for a command however a host or a wire format wrote it: parameters in
    alphabetical order, numbers as the float32 the firmware keeps (`X10.0`, `X10`, `X10.000001`
    are one command), a command word (G, M, T) without leading zeros. A text argument (an M117
    message, a file name) is kept as the firmware reads it; other lines that are not plain words
    stay as they are."""
    text = strip_comment(command)
    if (match := _TEXT_COMMAND.fullmatch(text)) and (
        (head := f"{match[1]}{int(match[2])}").upper() in TEXT_ARGUMENT_CODES
    ):
        # The firmwares take the text from the first character after the number and the
        # spaces that follow it (Marlin's string_arg; Repetier's parseAscii, and its binary
        # text field holds just that).
        return f"{head} {match[3]}" if match[3] else head
    if not _WORDS.fullmatch(text):
        return text
    words = WORD.findall(text)
    letter, number = words[0]
    if letter.upper() in "GMT" and number and number.isdigit():
        head = f"{letter}{int(number)}"
    elif letter.upper() in "GMT" and number[:1].isdigit() and (
            f"{letter}{int(number.split('.')[0])}".upper() in TEXT_ARGUMENT_CODES):
        # `M 117.5 X1`: a text command's number apart from its letter and not a whole one.
        # Written together (`M117.5 X1`) it would read as M117 and the text `.5 X1`; as it is,
        # it reads the same again (found by fuzzing: canonical() of canonical() differed).
        return text
    else:
        head = letter + number
    params = sorted(words[1:], key=lambda word: word[0])
    return " ".join([head] + [letter + _number(value) for letter, value in params])


def _number(text: str) -> str:
    if not text:
        return ""
    try:
        value = float32(float(text))
    except OverflowError:
        return text
    return number_text(value) if math.isfinite(value) else text  # past any float: as written
