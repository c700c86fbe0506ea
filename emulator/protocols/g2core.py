"""The board's side of g2core's protocol, as a sans-IO state machine (docs/protocols.md section 7).

Read from g2core's xio.cpp and controller.cpp (synthetos/g2 edge @ c5b1cd72): the host's bytes are
lines; a line that starts with `{` is a control (a JSON request), a first byte of `!`, `~`, `%`,
ENQ, ^D or ^X is a single-character command that needs no line end, and any other line is
data (G-code). Controls are scanned out of the receive buffer ahead of the data queued before
them (xio.cpp:611-626, 773-788) and run at once; a data line is read only when the session says
the board takes one (`reading_gcode`: the planner has PLANNER_HEADROOM buffers free and no
feedhold blocks it). Lines with only CR/LF are never returned (xio.cpp:709-726); a longer line
than the 512-byte buffer is cut at 511 characters and the rest skipped.

A data line's checksum, where it has one (`N<n> ... *<xor of every byte before *>`), is checked
(gcode_parser.cpp:286-315): a mismatch is status 118, a matching one on a line without `N` 120;
the line goes no further, and its answer is the session's (BadLine). Line numbers are never
checked for sequence (see _data_line): a line that comes twice runs twice. The last N word
of a line is its number, wherever it is. The footer's third element is the bytes of
the line just read: a data line's length + 1, a control's with its line ending(s)
(json_parser.cpp:604-617, xio.cpp:759-788, 917-934); every event carries it as `size`.
"""

from collections import deque
from dataclasses import dataclass

from fake_marlin.emulator.protocols.base import CommandReceived, Output
from fake_marlin.wire import g2core
from fake_marlin.wire.checksums import xor8
from fake_marlin.wire.g2core import JsonValue, RelaxedJsonError

RX_BUFFER_SIZE = 512  # xio.h:112: one line at most this, its end included
LINE_ENDS = b"\r\n"


# Events out.
@dataclass(frozen=True, slots=True)
class JsonRequest:
    """A control line, read as g2core's parser reads it: its pairs in order."""

    pairs: dict[str, JsonValue]
    size: int


@dataclass(frozen=True, slots=True)
class BadRequest:
    """A control line the parser refuses (111 syntax, 107 too long, 102 a bad number...)."""

    status: int
    text: str  # the line as it came, for the `err` echo of a syntax error
    size: int


@dataclass(frozen=True, slots=True)
class BadLine:
    """A data line whose checksum (118) or line number (120) does not check out."""

    status: int
    size: int


@dataclass(frozen=True, slots=True)
class SingleCharacter:
    """`!`, `~`, `%`, ENQ, ^D or ^X as a line's first byte: acts at once, ahead of queued data."""

    byte: int


Event = CommandReceived | JsonRequest | BadRequest | BadLine | SingleCharacter


# Events in.
@dataclass(frozen=True, slots=True)
class Response:
    """The answer to one line: `{"r":{body},"f":[1,status,size]}`."""

    body: dict[str, g2core.OutValue]
    status: int
    size: int


@dataclass(frozen=True, slots=True)
class Report:
    """A report of the board's own, a bare object: `{"sr":{...}}`, `{"qr":47}`, `{"er":...}`."""

    name: str
    body: g2core.OutValue


class G2coreProtocol:
    def __init__(self) -> None:
        self._buffer = bytearray()
        self._controls: deque[Event] = deque()  # scanned ahead: run before any queued data
        self._data: deque[tuple[bytes, int]] = deque()  # data lines and their sizes, in order
        self._skipping = False  # past the 511th character of a line: the rest is dropped
        self.reading_gcode = True  # the session's: whether the board reads a data line now
        self._out = bytearray()
        # The data line read last, as it came (N words, checksum and all): what a connection
        # that switches to Marlin's protocol on it hands over.
        self.last_line = b""

    def receive_data(self, data: bytes) -> None:
        self._buffer += data
        self._scan()

    def _scan(self) -> None:
        buffer = self._buffer
        while buffer:
            first = buffer[0]
            if first in LINE_ENDS:
                del buffer[0]
                self._skipping = False
                continue
            if self._skipping:
                end = find_end(buffer)
                if end is None:
                    buffer.clear()
                    return
                del buffer[:end]
                continue
            if first in g2core.SINGLE_CHARACTERS:
                del buffer[0]
                if bytes(buffer[:1]) in (b"\r", b"\n"):  # a line end after it is eaten with it
                    del buffer[0]
                self._controls.append(SingleCharacter(first))
                continue
            end = find_end(buffer)
            if end is None:
                if len(buffer) >= RX_BUFFER_SIZE - 1:  # cut at 511; the rest is skipped
                    self._take_line(bytes(buffer[:RX_BUFFER_SIZE - 1]), RX_BUFFER_SIZE - 1)
                    del buffer[:RX_BUFFER_SIZE - 1]
                    self._skipping = True
                return
            line = bytes(buffer[:end])
            ending = end + 1
            # A control's copy holds its line ending, CR LF both where both came.
            if buffer[end:end + 1] == b"\r" and buffer[end + 1:end + 2] == b"\n":
                ending += 1
            del buffer[:ending]
            self._take_line(line, ending)

    def _take_line(self, line: bytes, with_end: int) -> None:
        if line[:1] == b"{":
            self._controls.append(self._control(line, with_end + 1))  # (cs.linelen + 1)
        else:
            self._data.append((line, len(line) + 1))

    @staticmethod
    def _control(line: bytes, size: int) -> JsonRequest | BadRequest:
        text = line.decode("latin-1")
        try:
            return JsonRequest(g2core.parse_request(text), size)
        except RelaxedJsonError as error:
            return BadRequest(error.status, text, size)

    def next_event(self) -> Event | None:
        if self._controls:
            return self._controls.popleft()
        if self._data and self.reading_gcode:
            line, size = self._data.popleft()
            self.last_line = line
            return _data_line(line, size)
        return None

    def discard_data(self) -> int:
        """A queue flush or job kill: the data lines received before it are thrown away
        (xio_flush_to_command); how many."""
        count = len(self._data)
        self._data.clear()
        return count

    def take_unread(self) -> bytes:
        """The data lines received and not yet read, and the start of the next: what a
        connection that switches to another protocol (Marlin's) reads next."""
        data = b"".join(line + b"\n" for line, _ in self._data) + bytes(self._buffer)
        self._data.clear()
        self._buffer.clear()
        return data

    @property
    def waiting_lines(self) -> int:
        """Data lines received and not yet read."""
        return len(self._data)

    def send(self, event: Response | Report | Output) -> bytes:
        if isinstance(event, Response):
            data = g2core.response(event.body, event.status, event.size)
        elif isinstance(event, Report):
            data = g2core.report(event.name, event.body)
        else:
            data = event.text.encode("ascii", "replace") + b"\n"
        if self._out:
            data, self._out = bytes(self._out) + data, bytearray()
        return data

    def data_to_send(self) -> bytes:
        data, self._out = bytes(self._out), bytearray()
        return data


def find_end(data: bytes | bytearray, start: int = 0) -> int | None:
    """Where the first line end (CR or LF) from `start` is; None while none has come."""
    ends = [at for at in (data.find(b"\n", start), data.find(b"\r", start)) if at >= 0]
    return min(ends) if ends else None


def _data_line(line: bytes, size: int) -> CommandReceived | BadLine:
    """A data line as the G-code parser first takes it: its checksum checked, where it has one
    (gcode_parser.cpp:286-315, _verify_checksum). The controller has skipped leading spaces and
    tabs (controller.cpp:248-250). The XOR covers every byte before the first `*`; what follows
    it is read as strtol() reads it (leading digits; none is 0) and the line ends at the `*`. A
    mismatch is 118; a match on a line not starting with `N` is 120. There is no line-number
    check: cm_check_linenum() runs only with gf.checksum set, and _parse_gcode_block() clears
    gf (its memset) after _verify_checksum() set it, so a line's N is never compared with the
    last one (gcode_parser.cpp:661 and 949-951; master the same).

    N is a word like the others to the parser (gcode_parser.cpp:868, SET_NON_MODAL): anywhere in
    the block outside a comment, and the last one is the line's number (`number`). The N words
    are taken out of `text`, which is the G-code for the rest of the board."""
    text = line.decode("latin-1").lstrip(" \t")
    star = text.find("*")
    if star >= 0:
        if _strtol(text[star + 1:]) != xor8(text[:star].encode("latin-1")):
            return BadLine(g2core.CHECKSUM_MISMATCH, size)
        if not text.startswith("N"):
            return BadLine(g2core.MISSING_LINE_NUMBER, size)
        text = text[:star]
    text, number = _take_line_numbers(text)
    return CommandReceived(text.strip(), number, size)


def _take_line_numbers(text: str) -> tuple[str, int | None]:
    """`text` without its N words (outside comments: `( ... )`, and what follows `;` or `%`),
    and the value of the last one (None: none)."""
    out: list[str] = []
    number: int | None = None
    at, comment = 0, False
    while at < len(text):
        char = text[at]
        if comment:
            comment = char != ")"
        elif char == "(":
            comment = True
        elif char in ";%":
            out.append(text[at:])
            break
        elif char in "Nn":
            digits_at = at + 1
            while digits_at < len(text) and text[digits_at] in " \t":
                digits_at += 1
            end = digits_at
            while end < len(text) and "0" <= text[end] <= "9":  # (not isdigit: latin-1 has ²)
                end += 1
            if end > digits_at:
                number = int(text[digits_at:end])
                at = end
                continue
        out.append(char)
        at += 1
    return "".join(out), number


def _strtol(text: str) -> int:
    """C's strtol(text, NULL, 10): white space, a sign, the digits that follow; 0 if none."""
    text = text.lstrip(" \t\n\v\f\r")
    sign = -1 if text[:1] == "-" else 1
    if text[:1] in ("+", "-"):
        text = text[1:]
    digits = ""
    for char in text:
        if not "0" <= char <= "9":
            break
        digits += char
    return sign * int(digits) if digits else 0
