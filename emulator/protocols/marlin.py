"""The printer side of Marlin's ASCII line protocol, as a sans-IO state machine.

Mirrors Marlin 2.1's GCodeQueue::get_serial_commands(): characters are read into a line buffer
(comments dropped as they arrive, at most MAX_CMD_SIZE), a line numbered N must be last_N + 1 and
carry a correct XOR checksum, and a resend of the last line or the one before is dropped
silently. Lines are read only while the command queue has room, as the firmware stops reading
its RX buffer when the queue is full. Marlin's emergency parser sees M108/M112/M410/M876 as
soon as their line arrives, however full the queue.

The other firmwares that speak a line protocol of this kind (Prusa, Klipper, RepRapFirmware,
Smoothieware, older Marlin) differ in its rules: which checks they make, the words of their
errors, resend requests and `ok`. LineRules holds them, as each firmware's profile says.
"""

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING
from enum import Enum, auto

from fake_marlin.emulator.protocols.base import CommandDone, CommandReceived, Output
from fake_marlin.wire.checksums import xor8
from fake_marlin.wire.gcode import remove_paren_comments

MAX_CMD_SIZE = 96
BUFSIZE = 4
PLANNER_ROOM = 15  # ADVANCED_OK's P where the session states none: an empty planner's room


@dataclass(frozen=True)
class LineRules:
    """One firmware's rules for the line protocol (its profile's [lines] table)."""

    ok: str = "ok"
    line_end: str = "\n"
    queue: int = BUFSIZE  # commands the firmware takes before it stops reading
    # A numbered line must be last_N + 1 (a resend of the last two is dropped silently).
    sequence: bool = True
    # The `*<checksum>` of a numbered line: "required" (Marlin: none is an error), "optional"
    # (checked where it is given), "ignored" (never checked: Klipper).
    checksum: str = "required"
    bad_line: str = "resend"  # what a bad line draws: "resend" (error, resend, ok) or "drop"
    resend: str = "Resend: {line}"
    ok_after_resend: bool = True
    extra_ok_after_resend: bool = False  # a quirk: a second `ok` after the resend request
    # M105's temperatures on its `ok` line (`ok T:...`); False: a line of their own before it.
    answer_on_ok_line: bool = True
    # Klipper: every line it reads gets its `ok`, a blank one (or one all comment) too, in its
    # turn: it is queued as a command with no text.
    ok_for_blank_lines: bool = False
    # The line buffer, its terminator included: a longer line loses the rest (Marlin's
    # MAX_CMD_SIZE; Klipper has no limit, so its profile sets a large one).
    line_size: int = MAX_CMD_SIZE
    # What the emergency parser acts on as it arrives, however full the queue.
    emergency: tuple[str, ...] = ("M108", "M112", "M410", "M876")
    error_line_number: str = "Error:Line Number is not Last Line Number+1, Last Line: {last}"
    error_checksum: str = "Error:checksum mismatch, Last Line: {last}"
    error_no_checksum: str = "Error:No Checksum with line number, Last Line: {last}"
    # Marlin 1.1 refuses a checksum without a line number; "" : accepted (Marlin 2.1).
    error_no_line_number: str = ""
    first_line: int = 1  # the number the first numbered line must have (Smoothieware: 0)
    # A repeat of the last line or the one before is dropped silently (Marlin); False: it is a
    # wrong line number like any other (Smoothieware asks for the next line).
    drop_repeats: bool = True
    flush_on_error: bool = True  # a line error discards the rest of what has arrived (Marlin)
    # Smoothieware: a numbered line whose first M code is M110 sets the counter to its own N
    # and is answered `ok` at once, before any check, and runs nothing; M110 on a line without
    # a number does nothing to the counter.
    m110_takes_line_number: bool = False
    crlf_one_end: bool = False  # `\r\n` ends one line, not a line and a blank one (Smoothieware)
    # Characters the firmware acts on the moment they arrive, wherever they are, and takes out
    # of the line (Smoothieware's `?` status query and ^X halt): the command set's handler
    # under that character answers (Printer.realtime).
    realtime: str = ""
    # Commands whose `ok` goes out before they run, not after (Smoothieware's G1: a full
    # planner then holds the next line, not this one's `ok`).
    ok_before_run: tuple[str, ...] = ()
    # Each line a file being written (M28) takes gets its `ok` (Marlin); False: none, the
    # firmware answers nothing until M29 (RepRapFirmware).
    ok_while_saving: bool = True
    # How what the firmware says is sent: "ascii" (a character it cannot have is `?`), or
    # "utf-8" (RepRapFirmware's `°C`).
    encoding: str = "ascii"
    # M999's resend request has an `ok` of its own before the command's, two in all (Marlin
    # 1.x: flush_and_request_resend() ends with ok_to_send()).
    m999_ok: bool = False
    # A checksum without a line number (error_no_line_number) draws a resend request; False:
    # the error alone, no resend, no `ok`, and what follows is read on (Marlin 1.0's, the
    # Ultimaker 2's).
    no_line_number_resends: bool = True
    # While M28 writes a file every line but M29 must be numbered (Marlin 1.1 and 2.x); False:
    # a line without a number is written as it is (Marlin 1.0's, the Ultimaker 2's).
    numbered_while_saving: bool = True


class InputState(Enum):
    NORMAL = auto()
    EOL_COMMENT = auto()  # after `;` or an overlong line: skip to the end of the line
    PAREN_COMMENT = auto()  # inside `( )`: kept for the checksum, but a `;` here is no comment


# A module constant: an Enum member looked up on its class is a descriptor call in 3.11, and
# the usual read asks for this one on every line.
_NORMAL = InputState.NORMAL


class LineError(Enum):
    LINE_NUMBER = "line_number"
    CHECKSUM = "checksum"
    NO_CHECKSUM = "no_checksum"
    NO_LINE_NUMBER = "no_line_number"


# Events out (and CommandReceived, protocols.base).
@dataclass(frozen=True)
class LineRejected:
    error: LineError
    resend: int


@dataclass(frozen=True)
class EmergencyCommand:
    text: str  # "M108", "M112", "M410" or "M876 S<n>"


@dataclass(frozen=True)
class RealtimeCommand:
    text: str  # one of LineRules.realtime: "?", "\x18"


Event = CommandReceived | LineRejected | EmergencyCommand | RealtimeCommand


# Events in: CommandDone and Output (protocols.base).


_LEADING_INT = re.compile(r"\s*([-+]?\d+)")
_LINE_END = re.compile(rb"[\r\n]")
_SPECIAL = re.compile(rb"[;\\(\x08]")  # what process_stream_char() treats other than text
# What a host sends nearly always, `N<n> <command>*<checksum>\n`, in ASCII, with no other line
# end and nothing in it that process_stream_char() treats other than text (_SPECIAL, NUL).
_PLAIN_LINE = re.compile(rb"N(\d+)([^*\r\n;\\(\x08\x00\x80-\xff]*)\*(\d+)\n")
_EMERGENCY_FORMS = {"M108": r"M108(?!\d)", "M112": r"M112(?!\d)", "M410": r"M410(?!\d)",
                    "M876": r"M876\s*S\d+"}


def _emergency_pattern(codes: tuple[str, ...]) -> re.Pattern[str] | None:
    forms = [_EMERGENCY_FORMS[code] for code in codes if code in _EMERGENCY_FORMS]
    if not forms:
        return None
    return re.compile(r"(?:N-?\d+\s*)?(" + "|".join(forms) + ")")


def strtol(text: str) -> int:
    """C's strtol(text, NULL, 10): the leading integer, 0 if there is none."""
    match = _LEADING_INT.match(text)
    return int(match[1]) if match else 0


def xor_checksum(text: str) -> int:
    return xor8(text.encode("latin-1", "replace"))


def _first_m_is_m110(line: str) -> bool:
    """Whether the first M of `line` is M110 (Smoothieware's Gcode::get_int('M'))."""
    at = line.find("M")
    return at >= 0 and strtol(line[at + 1:]) == 110


def strip_line_number(line: str) -> str:
    """What GCodeParser::parse sees: the command without `N<n>` before it or `*<cs>` after it."""
    if line.startswith("N"):
        line = re.sub(r"^N-?\d*\s*", "", line)
    return line.split("*", 1)[0].strip()


class MarlinProtocol:
    def __init__(self, advanced_ok: bool = False, queue_size: int | None = None,
                 rules: LineRules = LineRules()) -> None:
        self.advanced_ok = advanced_ok
        self.rules = rules
        self.queue_size = rules.queue if queue_size is None else queue_size
        self.last_n = rules.first_line - 1
        self._skip_lf = False  # the line before ended in `\r` (crlf_one_end)
        self._realtime_events: list[RealtimeCommand] = []
        self.saving_to_sd = False  # while M28 writes a file, every line must be numbered
        self._queued = 0
        self._input = bytearray()
        self._line = bytearray()
        self._state = InputState.NORMAL
        self._escaped = False
        self._output = bytearray()
        self._emergency_line = bytearray()
        self._emergencies: list[EmergencyCommand] = []
        self._read: CommandReceived | None = None  # a line receive_data() read whole

    @property
    def rules(self) -> LineRules:
        return self._rules

    @rules.setter
    def rules(self, rules: LineRules) -> None:
        """The firmware's rules; a quirk switched on changes them between lines."""
        self._rules = rules
        self._ok = (rules.ok + rules.line_end).encode("ascii", "replace")
        self._emergency = _emergency_pattern(rules.emergency)
        self._realtime = (re.compile(b"[" + re.escape(rules.realtime.encode("latin-1")) + b"]")
                          if rules.realtime else None)

    # -- receiving ---------------------------------------------------------------------
    def receive_data(self, data: bytes) -> None:
        if self._realtime is not None and self._realtime.search(data):
            data = self._take_realtime(data)
        # The usual read, a whole plain line without an M (so no emergency command) and nothing
        # unread before it, is read at once: no buffering, no scan.
        if (self._read is None and not self._input and not self._emergency_line
                and not self._skip_lf
                and (line := self._whole_plain_line(data)) is not None):
            self._read = line
            return
        self._input += data
        self._scan_for_emergencies(data)

    def _take_realtime(self, data: bytes) -> bytes:
        """The realtime characters out of `data`, each an event, as the serial driver's
        interrupt takes them before the line buffer sees them."""
        pattern = self._realtime
        assert pattern is not None
        for match in pattern.finditer(data):
            self._realtime_events.append(RealtimeCommand(match[0].decode("latin-1")))
        return pattern.sub(b"", data)

    def _scan_for_emergencies(self, data: bytes) -> None:
        """The emergency parser sees every byte as it arrives, whole lines of them at a time."""
        if self._emergency is None:
            return
        if b"M" not in data and b"M" not in self._emergency_line:
            # No line here can be an emergency command (the usual G1): keep the unfinished tail.
            last_end = max(data.rfind(b"\n"), data.rfind(b"\r"))
            if last_end >= 0:
                self._emergency_line.clear()
            self._emergency_take(data[last_end + 1:])
        else:
            self._scan_lines_for_emergencies(data)

    def _scan_lines_for_emergencies(self, data: bytes) -> None:
        start = 0
        for end in _LINE_END.finditer(data):
            self._emergency_take(data[start:end.start()])
            if b"M" in self._emergency_line:  # every emergency command is an M code
                line = self._emergency_line.decode("ascii", "replace").strip()
                match = self._emergency.match(line) if self._emergency else None
                if match:
                    self._emergencies.append(EmergencyCommand(re.sub(r"\s+", " ", match[1])))
            self._emergency_line.clear()
            start = end.end()
        self._emergency_take(data[start:])

    def _emergency_take(self, chunk: bytes) -> None:
        room = MAX_CMD_SIZE - len(self._emergency_line)
        if room > 0:
            self._emergency_line += chunk[:room]

    @property
    def unread(self) -> bool:
        """Bytes that arrived and are not read yet (the queue was full)."""
        return bool(self._input)

    @property
    def queue_free(self) -> int:
        return self.queue_size - self._queued

    def next_event(self) -> Event | None:
        if self._realtime_events:
            return self._realtime_events.pop(0)
        if self._emergencies:
            return self._emergencies.pop(0)
        if (line := self._read) is not None:
            self._read = None
            return line
        data = self._input
        if not data:
            return None
        position = 0
        try:
            while position < len(data) and self._queued < self.queue_size:
                if self._skip_lf:  # `\r\n` is one line end: this `\n` ends nothing
                    self._skip_lf = False
                    if data[position] == 0x0A:
                        position += 1
                        continue
                end = _LINE_END.search(data, position)
                stop = len(data) if end is None else end.start()
                self._stream_chars(data, position, stop)
                if end is None:
                    position = stop
                    return None
                position = stop + 1
                self._skip_lf = self.rules.crlf_one_end and data[stop] == 0x0D
                event = self._line_done()
                if (isinstance(event, LineRejected) and self.rules.flush_on_error
                        and (event.error is not LineError.NO_LINE_NUMBER
                             or self.rules.no_line_number_resends)):
                    position = len(data)  # the firmware reads its RX buffer empty
                if event is not None:
                    return event
            return None
        finally:
            del data[:position]

    def _whole_plain_line(self, data: bytes) -> CommandReceived | None:
        """The usual read, one whole _PLAIN_LINE without an M, numbered last_N + 1 with a
        correct checksum, into an empty line buffer with room in the queue: read in one match
        as _line_done() reads it; None for anything else, which next_event() reads by the rules.
        Without an M it is no emergency command (all are M codes), and no M110, which sets the
        line number rather than following it."""
        if (b"M" in data or len(data) > self.rules.line_size  # longer than the line buffer holds
                or self._line or self._state is not _NORMAL or self._escaped
                or self._queued >= self.queue_size):
            return None
        match = _PLAIN_LINE.fullmatch(data)
        if match is None or (line_number := int(match[1])) != self.last_n + 1:
            return None
        if int(match[3]) != xor8(data[:match.start(3) - 1]):
            return None
        text = match[2].decode("ascii").strip()
        if not text:
            return None
        self.last_n = line_number
        self._queued += 1
        return CommandReceived(text, line_number)

    def _stream_chars(self, data: bytearray, start: int, stop: int) -> None:
        """process_stream_char() over data[start:stop], a stretch without line ends: plain text
        in one piece, and character by character only where a comment, an escape or a
        backspace needs it."""
        if start == stop or self._state is InputState.EOL_COMMENT:
            return
        if self._state is InputState.NORMAL and not self._escaped and (
            _SPECIAL.search(data, start, stop) is None
        ):
            room = self.rules.line_size - 1 - len(self._line)
            self._line += data[start:min(stop, start + room)]
            if stop - start >= room:
                self._state = InputState.EOL_COMMENT  # the buffer is full: the rest is lost
            return
        for position in range(start, stop):
            self._stream_char(data[position])

    def _stream_char(self, byte: int) -> None:
        """process_stream_char(): `;` comments and escapes, as the firmware strips them.

        `( )` comments stay in the line until it is complete: hosts compute the checksum over
        the line as they send it, comment included (stock Marlin keeps them in the buffer too).
        """
        if self._state is InputState.EOL_COMMENT:
            return
        if self._state is InputState.PAREN_COMMENT:
            if byte == ord(")"):
                self._state = InputState.NORMAL
        elif self._escaped:
            self._escaped = False
        elif byte == ord("\\"):
            self._escaped = True
            return
        elif byte == ord(";"):
            self._state = InputState.EOL_COMMENT
            return
        elif byte == ord("("):
            self._state = InputState.PAREN_COMMENT
        if byte == 0x08:  # backspace, for people typing in a terminal
            if self._line:
                self._line.pop()
            return
        self._line.append(byte)
        if len(self._line) >= self.rules.line_size - 1:
            self._state = InputState.EOL_COMMENT

    def _line_done(self) -> CommandReceived | LineRejected | None:
        # The firmware's line buffer is a C string: a NUL ends it there.
        raw = self._line.split(b"\x00", 1)[0].decode("ascii", "replace")
        self._line.clear()
        self._state = InputState.NORMAL
        self._escaped = False
        command = raw.lstrip(" ")
        rules = self.rules
        if not command:
            return self._blank_line(None)
        line_number = None
        if rules.m110_takes_line_number and command.startswith("N") and _first_m_is_m110(command):
            self.last_n = strtol(command[1:])  # GcodeDispatch: `ok`, before any check
            self._output += self._ok
            return None
        if command.startswith("N"):
            is_m110 = "M110" in command and not rules.m110_takes_line_number
            number_at = command.find("N", 4) if is_m110 else -1
            number = strtol(command[number_at + 1:] if number_at >= 0 else command[1:])
            if rules.sequence and number != self.last_n + 1 and not is_m110:
                if rules.drop_repeats and self.last_n - 1 <= number <= self.last_n:
                    return None  # a resend crossed our Resend request: already have it
                return self._line_error(LineError.LINE_NUMBER)
            star = command.rfind("*")
            if rules.checksum != "ignored":
                if star < 0 and rules.checksum == "required":
                    return self._line_error(LineError.NO_CHECKSUM)
                if star >= 0 and strtol(command[star + 1:]) != xor_checksum(command[:star]):
                    return self._line_error(LineError.CHECKSUM)
            self.last_n = line_number = number
        elif (self.saving_to_sd and rules.checksum == "required"  # (Marlin's M28 upload)
              and rules.numbered_while_saving
              and not re.match(r"M29(?!\d)", command)):
            return self._line_error(LineError.NO_CHECKSUM)
        elif rules.error_no_line_number and "*" in command:
            return self._line_error(LineError.NO_LINE_NUMBER)
        text = strip_line_number(remove_paren_comments(command))
        if not text:
            return self._blank_line(line_number)
        self._queued += 1
        return CommandReceived(text, line_number)

    def _blank_line(self, line_number: int | None) -> CommandReceived | None:
        """A line with no command: nothing (Marlin), or a command of no text that gets its
        `ok` in its turn (ok_for_blank_lines)."""
        if not self.rules.ok_for_blank_lines:
            return None
        self._queued += 1
        return CommandReceived("", line_number)

    def _line_error(self, error: LineError) -> LineRejected:
        # Error, Resend and ok go out back to back: printcore mistakes them for two
        # permissions to send if they arrive in separate reads.
        rules = self.rules
        resend = self.last_n + 1
        if error is LineError.NO_LINE_NUMBER and not rules.no_line_number_resends:
            self._output += (rules.error_no_line_number.format(last=self.last_n, line=resend)
                             + rules.line_end).encode("ascii", "replace")
            return LineRejected(error, resend)
        if rules.bad_line == "resend":
            words = getattr(rules, f"error_{error.value}")
            lines = [words.format(last=self.last_n, line=resend), rules.resend.format(line=resend)]
            if rules.ok_after_resend:
                lines.append(rules.ok)
                if rules.extra_ok_after_resend:
                    lines.append(rules.ok)
            self._output += "".join(line + rules.line_end for line in lines if line).encode(
                "ascii", "replace")
        return LineRejected(error, resend)

    def hand_over(self) -> bytes:
        """The bytes not read yet, for the protocol that takes the line (M28 B1). A line half
        read is dropped: the firmware's line buffer becomes the binary receiver's."""
        data = bytes(self._input)
        self._input.clear()
        self._line.clear()
        self._state = InputState.NORMAL
        self._escaped = False
        return data

    # -- sending -----------------------------------------------------------------------
    def send(self, event: CommandDone | Output) -> bytes:
        if isinstance(event, CommandDone):
            self._queued = max(0, self._queued - 1)
            end = self.rules.line_end
            if event.quiet:
                pass
            elif event.ok_suffix and self.rules.answer_on_ok_line:
                self._output += f"{self.rules.ok} {event.ok_suffix}{end}".encode(
                    self.rules.encoding, "replace")
            elif event.ok_suffix:
                self._output += f"{event.ok_suffix}{end}{self.rules.ok}{end}".encode(
                    self.rules.encoding, "replace")
            elif self.advanced_ok:
                number = f" N{event.number}" if event.number is not None else ""
                room = PLANNER_ROOM if event.room is None else event.room
                # The slot this command held is free again by the time `ok` goes out.
                self._output += f"{self.rules.ok}{number} P{room} B{self.queue_free}{end}".encode()
            elif not self._output:
                return self._ok  # the usual answer, with nothing waiting to go before it
            else:
                self._output += self._ok
        elif isinstance(event, Output):
            self._output += f"{event.text}{self.rules.line_end}".encode(self.rules.encoding,
                                                                        "replace")
        else:
            raise TypeError(f"cannot send {event!r}")
        return self.data_to_send()

    def data_to_send(self) -> bytes:
        if not self._output:
            return b""
        data = bytes(self._output)
        self._output.clear()
        return data


if TYPE_CHECKING:  # mypy holds the machine to the shared interface
    from fake_marlin.emulator.protocols.base import ProtocolMachine

    _: type[ProtocolMachine[Event, CommandDone | Output]] = MarlinProtocol
