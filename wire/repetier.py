"""Repetier's binary G-code commands: layout, Fletcher-16, and the text they stand for.

Layout (Repetier-Firmware gcode.cpp computeBinarySize/parseBinary; docs/protocols.md
section 2), all little-endian: u16 bits; V2 only: u16 bits2, then u8 textlen if there is
text; N u16; M and G u8 in V1, u16 in V2; X Y Z E F f32; T u8; S P i32; V2 only: I J R D C H
A B K L O f32; text (16 NUL-padded bytes in V1, textlen bytes in V2); Fletcher-16 sum1, sum2.

Shared by the emulator (decoding) and the host (encoding). Pure: bytes and values only.
"""

import re
import struct
from dataclasses import dataclass

from fake_marlin.wire.framing import Framer
from fake_marlin.wire.gcode import NUMBER, float32, number_text
from fake_marlin.wire.lines import LINES, MAX_LINE, line_end

MARKER = 0x0080  # bit 7: always set, so a binary command's first byte is never ASCII
BIT_N, BIT_M, BIT_G = 0x0001, 0x0002, 0x0004
BIT_T, BIT_S, BIT_P = 0x0200, 0x0400, 0x0800
BIT_V2, BIT_EXT, BIT_INTERNAL, BIT_TEXT = 0x1000, 0x2000, 0x4000, 0x8000
FLOAT_BITS = (("X", 0x0008), ("Y", 0x0010), ("Z", 0x0020), ("E", 0x0040), ("F", 0x0100))
V2_LETTERS = "IJRDCHABKLO"  # bits2 bits 0-10
V1_TEXT = 16
MAX_V2_TEXT = 79  # the firmware counts min(80, textlen + 1) bytes for the length and the text
TEXT_CODES = frozenset({23, 28, 29, 30, 32, 117})  # M codes whose argument is text (file names)
LETTERS = "XYZEFTSP" + V2_LETTERS
_NUMBER = re.compile(NUMBER)


class BadChecksum(ValueError):
    """The command's Fletcher-16 does not match: the firmware asks for a resend."""


def fletcher16(data: bytes | bytearray) -> tuple[int, int]:
    sum1 = sum2 = 0
    for byte in data:
        sum1 = (sum1 + byte) % 255
        sum2 = (sum2 + sum1) % 255
    return sum1, sum2


@dataclass(frozen=True)
class BinaryCommand:
    n: int | None = None
    m: int | None = None
    g: int | None = None
    params: tuple[tuple[str, float], ...] = ()  # letters of LETTERS, in wire order
    text: str | None = None
    v2: bool = False
    internal: bool = False

    def value(self, letter: str) -> float | None:
        return dict(self.params).get(letter)


def command_size(prefix: bytes) -> int | None:
    """The whole command's length in bytes, from its first bytes; None until enough have come
    (two, or five for a V2 command with text)."""
    if len(prefix) < 2:
        return None
    bits = prefix[0] | prefix[1] << 8
    size = 4 + 2 * bool(bits & BIT_N)
    size += 4 * sum(bool(bits & bit) for _, bit in FLOAT_BITS)
    size += bool(bits & BIT_T) + 4 * bool(bits & BIT_S) + 4 * bool(bits & BIT_P)
    if not bits & BIT_V2:
        return size + bool(bits & BIT_M) + bool(bits & BIT_G) + V1_TEXT * bool(bits & BIT_TEXT)
    if len(prefix) < 4 or (bits & BIT_TEXT and len(prefix) < 5):
        return None
    bits2 = prefix[2] | prefix[3] << 8
    size += 2 + 2 * bool(bits & BIT_M) + 2 * bool(bits & BIT_G) + 4 * bin(bits2).count("1")
    if bits & BIT_TEXT:
        size += min(80, prefix[4] + 1)
    return size


def unit_end(buffer: bytes, start: int) -> int | None:
    """Where the command starting at `start` ends, as the firmware reads it (readFromSerial): a
    binary command if its first byte has bit 7 set, its length from command_size; otherwise an
    ASCII line, ended by a LF, CR or NUL. A NUL between commands (the 32 the host sends before a
    resend) is a unit by itself: filler, which the firmware skips."""
    first = buffer[start]
    if first == 0:
        return start + 1
    if first & MARKER:
        size = command_size(buffer[start:start + 5])
        if size is None or start + size > len(buffer):
            return None
        return start + size
    return line_end(buffer, start, b"\n\r\0")


# No binary command is longer than a line may be (command_size's most is under 200 bytes).
TO_PRINTER_UNITS = Framer(unit_end, MAX_LINE, filler=b"\r\n\0")
TO_HOST_UNITS = LINES  # the printer's replies are lines


def decode(frame: bytes) -> BinaryCommand:
    """A whole command (command_size bytes) as its fields; BadChecksum if it is damaged."""
    body = frame[:-2]
    if fletcher16(body) != (frame[-2], frame[-1]):
        raise BadChecksum(f"Fletcher-16 mismatch in {frame.hex()}")
    reader = _Reader(body)
    bits = reader.unsigned(2)
    v2 = bool(bits & BIT_V2)
    bits2, text_length = 0, V1_TEXT
    if v2:
        bits2 = reader.unsigned(2)
        if bits & BIT_TEXT:
            text_length = reader.unsigned(1)
    n = reader.unsigned(2) if bits & BIT_N else None
    code_size = 2 if v2 else 1
    m = reader.unsigned(code_size) if bits & BIT_M else None
    g = reader.unsigned(code_size) if bits & BIT_G else None
    params = [(letter, reader.f32()) for letter, bit in FLOAT_BITS if bits & bit]
    if bits & BIT_T:
        params.append(("T", reader.unsigned(1)))
    for letter, bit in (("S", BIT_S), ("P", BIT_P)):
        if bits & bit:
            params.append((letter, reader.signed32()))
    for index in range(16):
        if bits2 & (1 << index):
            value = reader.f32()
            if index < len(V2_LETTERS):  # later bits are reserved: skipped, as the size says
                params.append((V2_LETTERS[index], value))
    text = None
    if bits & BIT_TEXT:
        # A C string: it ends at the first NUL, or where the firmware writes one.
        raw = reader.rest()[: min(text_length, MAX_V2_TEXT) if v2 else V1_TEXT]
        text = raw.split(b"\0", 1)[0].decode("latin-1")
    return BinaryCommand(n, m, g, tuple(params), text, v2, bool(bits & BIT_INTERNAL))


def encode(command: BinaryCommand) -> bytes:
    """The command's bytes, checksum included. ValueError if a field does not fit its type."""
    params = dict(command.params)
    unknown = set(params) - set(LETTERS)
    if unknown:
        raise ValueError(f"no binary field for {''.join(sorted(unknown))}")
    v2_letters = [letter for letter in V2_LETTERS if letter in params]
    text = None if command.text is None else command.text.encode("latin-1")
    v2 = command.v2 or bool(v2_letters)
    bits = MARKER | BIT_V2 * v2 | BIT_INTERNAL * command.internal
    bits |= BIT_N * (command.n is not None) | BIT_M * (command.m is not None)
    bits |= BIT_G * (command.g is not None) | BIT_TEXT * (text is not None)
    bits |= sum(bit for letter, bit in FLOAT_BITS if letter in params)
    bits |= BIT_T * ("T" in params) | BIT_S * ("S" in params) | BIT_P * ("P" in params)
    out = bytearray(struct.pack("<H", bits))
    if v2:
        out += struct.pack("<H", sum(1 << V2_LETTERS.index(letter) for letter in v2_letters))
        if text is not None:
            if len(text) > MAX_V2_TEXT:
                raise ValueError(f"text of {len(text)} bytes; V2 carries at most {MAX_V2_TEXT}")
            out.append(len(text))
    code = "<H" if v2 else "<B"
    for value, fmt in ((command.n, "<H"), (command.m, code), (command.g, code)):
        if value is not None:
            out += _pack(fmt, value)
    for letter, _ in FLOAT_BITS:
        if letter in params:
            out += _pack("<f", params[letter])
    for letter, fmt in (("T", "<B"), ("S", "<i"), ("P", "<i")):
        if letter in params:
            out += _pack(fmt, params[letter])
    for letter in v2_letters:
        out += _pack("<f", params[letter])
    if text is not None:
        if not v2:
            if len(text) > V1_TEXT:
                raise ValueError(f"text of {len(text)} bytes; V1 carries at most {V1_TEXT}")
            text = text.ljust(V1_TEXT, b"\0")
        out += text
    return bytes(out) + bytes(fletcher16(out))


def _pack(fmt: str, value: float) -> bytes:
    try:
        return struct.pack(fmt, int(value) if fmt[-1] in "BHi" else value)
    except (struct.error, OverflowError):
        raise ValueError(f"{value} does not fit a {fmt} field") from None


class _Reader:
    def __init__(self, data: bytes) -> None:
        self._data = data
        self._at = 0

    def _take(self, count: int) -> bytes:
        chunk = self._data[self._at:self._at + count]
        self._at += count
        return chunk.ljust(count, b"\0")

    def unsigned(self, size: int) -> int:
        return int.from_bytes(self._take(size), "little")

    def signed32(self) -> int:
        value: int = struct.unpack("<i", self._take(4))[0]
        return value

    def f32(self) -> float:
        value: float = struct.unpack("<f", self._take(4))[0]
        return value

    def rest(self) -> bytes:
        return self._data[self._at:]


# -- the G-code text a command stands for ---------------------------------------------------
def to_gcode(command: BinaryCommand) -> str:
    """The command as a G-code line (no line number), fields in the firmware's order."""
    words = []
    if command.m is not None:
        words.append(f"M{command.m}")
    if command.g is not None:
        words.append(f"G{command.g}")
    params = list(command.params)
    if command.m is None and command.g is None and params and params[0][0] != "T":
        tool = [p for p in params if p[0] == "T"]
        params = tool + [p for p in params if p[0] != "T"]  # a tool change reads `T1 ...`
    words += [f"{letter}{number_text(value)}" for letter, value in params]
    if command.text is not None:
        words.append(command.text)
    return " ".join(words)


def from_gcode(text: str, n: int | None = None, v2: bool = False) -> BinaryCommand | None:
    """The binary command for a G-code line (comment already stripped), or None if it has none
    that the printer would read back as the same command: a letter without a field or value,
    a value its field cannot hold (S200.5 in an integer field), text that does not fit. Such
    lines go as ASCII. Floats are rounded to float32, which is what firmware keeps of them."""
    words = text.split()
    if not words:
        return None
    head = words[0]
    letter, digits = head[:1], head[1:]
    if letter not in ("G", "M", "T") or not digits.isdigit():
        return None
    code = int(digits)
    if code > (0xFFFF if v2 else 0xFF) or (letter == "T" and code > 0xFF):
        return None
    fields: dict[str, int | None] = {"m": None, "g": None}
    params: list[tuple[str, float]] = []
    rest = words[1:]
    if letter == "T":
        params.append(("T", code))
    else:
        fields[letter.lower()] = code
    command_text = None
    if letter == "M" and code in TEXT_CODES:
        argument = text.split(None, 1)[1] if len(words) > 1 else ""
        if not _fits_text(argument, v2, spaces=code == 117):
            return None
        command_text, rest = argument, []
    seen = {letter} if letter == "T" else set()
    for word in rest:
        param = _param(word, v2)
        if param is None or param[0] in seen:
            return None
        seen.add(param[0])
        params.append(param)
    order = {letter: index for index, letter in enumerate("XYZEFTSP" + V2_LETTERS)}
    params.sort(key=lambda item: order[item[0]])
    needs_v2 = (
        any(p[0] in V2_LETTERS for p in params)
        or (code > 0xFF and letter != "T")
        or (command_text is not None and len(command_text) > V1_TEXT)
    )
    return BinaryCommand(n, fields["m"], fields["g"], tuple(params), command_text, v2=needs_v2)


def _param(word: str, v2: bool) -> tuple[str, float] | None:
    letter, number = word[:1], word[1:]
    if letter not in LETTERS or (letter in V2_LETTERS and not v2) or not number:
        return None
    if not _NUMBER.fullmatch(number):
        return None
    value = float(number)
    if letter in "TSP":
        low, high = (0, 0xFF) if letter == "T" else (-(2**31), 2**31 - 1)
        if value != int(value) or not low <= value <= high:
            return None
        return letter, int(value)
    try:
        # Rounded to float32, as the firmware rounds what it parses from ASCII, too.
        return letter, float32(value)
    except OverflowError:
        return None


def _fits_text(argument: str, v2: bool, spaces: bool) -> bool:
    """Text the firmware reads back whole: ASCII, no NUL or `*`, a file name without spaces."""
    if not argument or not argument.isascii() or "\0" in argument or "*" in argument:
        return False
    if not spaces and " " in argument:
        return False
    return len(argument) <= (MAX_V2_TEXT if v2 else V1_TEXT)
