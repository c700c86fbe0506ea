"""The printer side of Repetier's protocol, binary and ASCII mixed, as a sans-IO state machine.

Mirrors Repetier-Firmware's GCode::readFromSerial and checkAndPushCommand (docs/protocols.md
section 2): a command whose first byte has bit 7 set is binary (its length follows from its
first bytes, its Fletcher-16 is checked), any other is an ASCII line; NUL bytes are ignored
between commands. A numbered command must be last + 1; it is acknowledged `ok <N>` as soon as
it is queued, before it runs. A repeat, at most 39 lines behind the last one, draws
`skip <N>`; a gap (any line ahead), or a damaged command, draws an empty line,
`Resend:<last + 1>`, `ok`, and the firmware empties its receive buffer. After a binary
command the firmware then reads nothing until it has seen 31 NUL bytes in a row, so that it
restarts on a command boundary.

Time is told (time_passed, next_deadline): no byte read for 200 ms while a command is half
read or a resend is awaited draws a Resend; a second of that quiet with nothing queued draws
`wait`. As in the firmware, the quiet counts from the last byte read, not the last byte that
arrived: bytes wait unread while the command buffer is full.
"""

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from fake_marlin.emulator.protocols.base import CommandDone, CommandReceived, Output
from fake_marlin.emulator.protocols.marlin import strtol, xor_checksum
from fake_marlin.wire import repetier
from fake_marlin.wire.gcode import strip_comment

MAX_CMD_SIZE = 96
GCODE_BUFFER_SIZE = 1  # Repetier.h: one parsed command waits; the rest stays in the RX buffer
RESYNC_NULS = 30  # waitingForResend after a binary error: it counts down to -1 on 31 NULs
ASCII_SKIPS = 14  # lines skipped silently in ASCII mode before a gap is an error again
REPEAT_DISTANCE = 40  # a line up to 39 behind the last one is a repeat: skipped, not an error
STALL_TIMEOUT = 0.2  # seconds without a byte before a half-read command is given up
WAIT_INTERVAL = 1.0  # seconds of quiet, with nothing queued, between `wait` lines
_U32 = 0xFFFFFFFF


# Events out (and CommandReceived: protocols.base; `last_was_binary` says how it came).
@dataclass(frozen=True)
class CommandRejected:
    """Damaged or out of sequence: the printer asked for line `resend` again."""

    reason: str
    resend: int


@dataclass(frozen=True)
class EmergencyStop:
    """M112: the firmware stops at once, when the command is read, not when it would run."""

    text: str


Event = CommandReceived | CommandRejected | EmergencyStop


# Events in: CommandDone (which says nothing: the `ok` came when it was queued) and Output,
# protocols.base.


class RepetierProtocol:
    def __init__(self, queue_size: int = GCODE_BUFFER_SIZE) -> None:
        self.queue_size = queue_size
        self.last_line = 0  # lastLineNumber: unsigned 32 bits, as `N-1 M110` makes it 2^32-1
        self.act_line = 0  # the line number last read, which the `ok` of any line repeats
        self.waiting_for_resend = -1
        self.last_was_binary = False  # wasLastCommandReceivedAsBinary: how the last command came
        self._binary = False
        self._binary_size: int | None = None
        self._comment = False
        self._format_errors = 0
        self._queued = 0
        self._input = bytearray()
        self._command = bytearray()
        self._output = bytearray()
        # Bytes the firmware has taken from its input (a flush drops the rest unread): its
        # timeOfLastDataPacket is the moment it last read one, where its timers count from.
        self.bytes_read = 0
        self._bytes_told = -1  # bytes_read at the last time_passed(): the first one is the boot
        self._last_read = -math.inf

    # -- receiving ---------------------------------------------------------------------
    def receive_data(self, data: bytes) -> None:
        self._input += data

    @property
    def queue_free(self) -> int:
        return self.queue_size - self._queued

    @property
    def reading(self) -> bool:
        """Whether the firmware reads its input now (it stops while its buffer is full)."""
        return self._queued < self.queue_size

    @property
    def has_input(self) -> bool:
        return bool(self._input)

    @property
    def expects_more(self) -> bool:
        """A command is half read, or a resend is awaited: silence now is an error."""
        return bool(self._command) or self.waiting_for_resend >= 0

    def next_event(self) -> Event | None:
        position = 0
        try:
            while position < len(self._input) and self.reading:
                byte = self._input[position]
                position += 1
                self.bytes_read += 1
                event = self._take(byte)
                if isinstance(event, CommandRejected):
                    position = len(self._input)  # HAL::serialFlush()
                if event is not None:
                    return event
            return None
        finally:
            del self._input[:position]

    def _take(self, byte: int) -> Event | None:
        self._command.append(byte)
        if len(self._command) == 1 and not self._comment:
            if self.waiting_for_resend >= 0 and self.last_was_binary:
                # Resynchronising after a binary error: only a run of NULs ends it.
                self.waiting_for_resend = self.waiting_for_resend - 1 if byte == 0 else RESYNC_NULS
                self._command.clear()
                return None
            if byte == 0:
                self._command.clear()
                return None
            self._binary = bool(byte & 0x80)
            self._binary_size = None
        event = self._take_binary() if self._binary else self._take_ascii(byte)
        if event is None and len(self._command) >= MAX_CMD_SIZE:
            return self._request_resend("command too long")
        return event

    def _take_binary(self) -> Event | None:
        if len(self._command) in (2, 4, 5):
            self._binary_size = repetier.command_size(bytes(self._command))
        if self._binary_size is None or len(self._command) < self._binary_size:
            return None
        frame = bytes(self._command)
        self._command.clear()
        try:
            command = repetier.decode(frame)
        except repetier.BadChecksum:
            return self._request_resend("Wrong checksum", error=True)
        if command.n is not None:
            self.act_line = command.n
        return self._check_and_push(repetier.to_gcode(command), command.n, command.m)

    def _take_ascii(self, byte: int) -> Event | None:
        if byte in (0, 0x0A, 0x0D):
            raw = bytes(self._command[:-1]).decode("latin-1")
            self._command.clear()
            self._comment = False
            if not raw:
                return None
            return self._ascii_line(raw)
        if byte == ord(";"):
            self._comment = True
        if self._comment:
            self._command.pop()  # a comment is not kept: it never fills the buffer
        return None

    def _ascii_line(self, raw: str) -> Event | None:
        """GCode::parseAscii: N is the first `N` anywhere, the checksum follows the first `*`."""
        n = None
        at = raw.find("N")
        if at >= 0:
            n = strtol(raw[at + 1:]) & _U32
            self.act_line = n
        star = raw.find("*")
        if star >= 0:
            if xor_checksum(raw[:star]) != strtol(raw[star + 1:]) & 0xFF:
                return self._request_resend("Wrong checksum", error=True)
        elif self.last_was_binary:
            # A damaged binary command can look like an ASCII line: after binary, only a
            # checked line is believed.
            return self._request_resend(
                "Checksum required when switching back to ASCII protocol.", error=True
            )
        text = strip_comment(raw[:star] if star >= 0 else raw)
        if n is not None and text.startswith("N"):
            text = text[1:].lstrip("+-0123456789").lstrip(" ")
        if not any(letter in text for letter in "GMT"):
            self._format_errors += 1
            if self._format_errors < 3:
                return self._request_resend("Format error", error=True)
        else:
            self._format_errors = 0
        m_at = text.find("M")
        m_code = strtol(text[m_at + 1:]) & 0xFFFF if m_at >= 0 else None
        return self._check_and_push(text, n, m_code)

    def _check_and_push(self, text: str, n: int | None, m_code: int | None) -> Event | None:
        if m_code == 110:
            self.last_line = self.act_line
            self._say("ok")
            self.waiting_for_resend = -1
            return None
        if m_code == 112:
            return EmergencyStop(text)  # before any check: a stop is never refused
        if n is not None:
            if (self.last_line + 1) & 0xFFFF != n & 0xFFFF:
                # static_cast<uint16_t>(lastLineNumber - actLineNumber) < 40: only a line at
                # or up to 39 behind the last one is a repeat; one ahead is a gap. Compared
                # modulo 2^16, as a binary N has 16 bits and the counter 32.
                if (self.last_line - n) & 0xFFFF < REPEAT_DISTANCE:
                    self._say(f"skip {n}", "ok")  # seen already: a repeated resend
                elif self.waiting_for_resend < 0:
                    return self._request_resend(
                        f"expected line {self.last_line + 1} got {n}", error=True
                    )
                else:
                    self.waiting_for_resend -= 1
                    self._say(f"skip {n}", "ok")
                return None
            self.last_line = n
        self._queued += 1
        self._say(f"ok {self.act_line}")
        self.last_was_binary = self._binary
        self.waiting_for_resend = -1
        return CommandReceived(text, n)

    def _request_resend(self, reason: str, error: bool = False) -> CommandRejected:
        """`error`: the firmware says why first (its debug level shows errors by default)."""
        if error:
            self._say(f"Error:{reason}")
        self._command.clear()
        self._comment = False
        self.waiting_for_resend = RESYNC_NULS if self._binary else ASCII_SKIPS
        resend = (self.last_line + 1) & _U32
        self._say("", f"Resend:{resend}", "ok")
        return CommandRejected(reason, resend)

    # -- time ----------------------------------------------------------------------------
    def time_passed(self, now: float) -> None:
        """Bytes read since the last call were read now (the first call: the firmware booted).
        No byte read for STALL_TIMEOUT while expects_more: ask for the line again; quiet for
        WAIT_INTERVAL with nothing queued: `wait`, which unblocks a host that lost an ok."""
        if self.bytes_read != self._bytes_told:
            self._last_read, self._bytes_told = now, self.bytes_read
        deadline = self.next_deadline()
        if deadline is None or now < deadline:
            return
        if self.expects_more:
            self._request_resend("no data")
        else:
            self._say("wait")
        self._last_read = now  # the quiet counts again from here

    def next_deadline(self) -> float | None:
        """Only while the firmware reads and has read everything that came."""
        if not self.reading or self.has_input:
            return None
        if self.expects_more:
            return self._last_read + STALL_TIMEOUT
        if self._queued == 0:
            return self._last_read + WAIT_INTERVAL
        return None

    # -- sending -----------------------------------------------------------------------
    def send(self, event: CommandDone | Output) -> bytes:
        if isinstance(event, CommandDone):
            self._queued = max(0, self._queued - 1)
        elif isinstance(event, Output):
            self._say(event.text)
        else:
            raise TypeError(f"cannot send {event!r}")
        return self.data_to_send()

    def _say(self, *lines: str) -> None:
        for line in lines:
            self._output += line.encode("latin-1", "replace") + b"\r\n"

    def data_to_send(self) -> bytes:
        data = bytes(self._output)
        self._output.clear()
        return data


if TYPE_CHECKING:  # mypy holds the machine to the shared interface
    from fake_marlin.emulator.protocols.base import TimedMachine

    _: type[TimedMachine[Event, CommandDone | Output]] = RepetierProtocol
