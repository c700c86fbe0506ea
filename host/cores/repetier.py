"""Streaming numbered commands to Repetier-Firmware, as a sans-IO state machine.

Why nothing runs twice or goes missing: the firmware itself refuses duplicates. It queues a
numbered command only if its number is last + 1 (modulo 2^16), answers a repeat up to 39 lines
behind with `skip`, and anything else (a gap, a damaged command) with `Resend:<last + 1>`.
So the host may always send a command again, under its own number, and never renumbers one.

What each answer says (docs/protocols.md section 2):
- `ok <N>`: line N was queued, and so was every line before it (lines are taken in order).
- `Resend:<n>`: every line before n was queued, none from n on: send again from n. After a
  binary command the firmware then ignores everything until 31 NUL bytes in a row, so a resend
  starts with 32 (RESYNC), as Repetier-Host does.
- `skip <N>` for the oldest line not yet acknowledged: every line before it was queued, so the
  firmware skips N only because it has it: its `ok` was lost.
- `wait`: the firmware is idle with nothing queued: lines still unacknowledged were lost
  (or their oks were): send them again.
A bare `ok` (after M110, Resend or skip) says nothing.

What the printer says arrives unchecked, and a damaged digit can name another line: `ok 141`
for `ok 140`, `Resend:141` for `Resend:140`. So an acknowledgement is a belief, not a fact:
acknowledged lines are kept (HISTORY), and a Resend for one of them means the printer does not
have it after all: the host goes back to it (a rewind). Sending a line the printer has is
harmless (it skips it), so the host errs on the side of sending again.

The firmware repeats its Resend every 200 ms for as long as nothing arrives, so while the host's
answer is on its way (a slow or stalled line) the same request comes again and again. A Resend
for the line the host last went back to, within RESEND_GUARD of it and with no `Error:` line
before it (the printer read something and refused it), is that repeat: the answer is on its way.

The host gives up only on a printer that is silent or refuses everything: after
`max_transmissions` go-backs (Resends answered, timeouts, waits) without any new line being
acknowledged, spanning at least (max_transmissions - 1) timeouts, as long as a silent printer
takes. A go-back resends the whole window, so no single line's count decides.

Flow control is Repetier-Host's: the bytes of unacknowledged lines stay within the firmware's
receive buffer (RECEIVE_CACHE), since the firmware stops reading while its one-command buffer
is full. Timeouts count silence: while the printer works it says `busy:` every 2 s.

Start: `N0 M110` (binary, so `--protocol auto` knows the host), then line 1 is M115, whose
`REPETIER_PROTOCOL:<v>` says whether the printer reads binary V2 (v >= 2). It reads binary V1 at
least, as it answered the binary M110; a damaged or missing version leaves it at V1.
"""

import math
from collections import deque
from dataclasses import dataclass
from enum import Enum, auto

from fake_marlin.host.codecs import marlin
from fake_marlin.host.codecs.repetier import (
    RESYNC,
    WIRE_NUMBER,
    Event,
    Identity,
    Line,
    LineKind,
    LineParser,
    Ok,
    ResendRequest,
    Skip,
    encode_command,
)
from fake_marlin.host.cores.queue import CommandQueue, Ticket, is_long_command
from fake_marlin.host.errors import PrinterHalted, PrinterNotResponding, PrinterReset
from fake_marlin.wire import repetier

RECEIVE_CACHE = 127  # Repetier-Host's receiveCacheSize
UNKNOWN_RESENDS_MEAN_RESET = 3  # the same Resend for a line long gone: the printer restarted
KEEPALIVE_MARGIN = 5.0  # seconds of silence allowed once the printer sends busy: (every 2 s)
IDENTIFY = "M115"
RESEND_GUARD = 0.5  # s: longer than the firmware's 200 ms between repeated Resends
# Acknowledged lines kept, in case a damaged number acknowledged them wrongly. Only lines in
# flight can be, and the printer's 127-byte cache holds a dozen at most: a wrong acknowledgement
# is among the last two windows. A Resend for a line further back is no wrong acknowledgement
# but a printer counting from elsewhere: one that restarted, its `start` lost.
HISTORY = 32
TAKE_AHEAD = 64  # commands taken from the backlog into the send queue


class Phase(Enum):
    SYNC = auto()  # M110 sent, waiting for its ok
    IDENTIFY = auto()  # M115 on its way: waiting for REPETIER_PROTOCOL
    STREAM = auto()


@dataclass(eq=False)
class _Line:
    number: int
    text: str
    ticket: Ticket | None  # None for the host's own M115
    data: bytes = b""
    binary: bool = False
    transmissions: int = 0


@dataclass
class RepetierStats:
    packets_sent: int = 0
    resends: int = 0
    timeouts: int = 0
    rejects: int = 0  # Resend requests
    unconfirmed: int = 0  # lines whose own ok never came (a skip or a later ok said it)
    binary: int = 0
    ascii: int = 0
    rewinds: int = 0  # Resends for lines already acknowledged: the acknowledgement was wrong


class RepetierCore(CommandQueue):
    def __init__(
        self,
        timeout: float = 2.0,
        long_timeout: float = 300.0,
        max_transmissions: int = 8,
        cache: int = RECEIVE_CACHE,
    ) -> None:
        self.timeout = timeout
        self.long_timeout = long_timeout
        self.max_transmissions = max_transmissions
        self.cache = cache
        self.window = 8  # commands the caller may queue ahead (the client's backlog bound)
        self.stats = RepetierStats()
        self.binary_version = 1
        self.phase = Phase.SYNC
        self._open_queue()
        self._lines: deque[_Line] = deque()  # not yet acknowledged, in order
        self._history: deque[_Line] = deque(maxlen=HISTORY)  # acknowledged, oldest first
        self._next_send = 0  # index into _lines of the next line to (re)transmit
        self._in_flight_bytes = 0  # of the lines before _next_send
        self._resync = False  # NULs owed before the next transmission
        self._resync_alone = False  # ... and owed now, even with nothing to transmit
        self._next_number = 1
        self._sync_sent_at: float | None = None
        self._sync_sends = 0
        self._identify_deadline: float | None = None
        self._last_heard = -math.inf
        self._keepalives = False
        self._want_drained = False
        self._drained = False  # `wait` since the last line went out: all of it has run
        # Giving up: go-backs since a new line was last acknowledged, and since when.
        self._acknowledged_through = 0
        self._rounds = 0
        self._trouble_since: float | None = None
        # Repeated Resends: the one last answered (its number, when), whether an Error: came.
        self._answered: tuple[int | None, float] | None = None
        self._error_seen = False
        self._unknown_asked: int | None = None  # a Resend for a line the host no longer has
        self._unknown_asks = 0  # how often in a row
        self._idle_resends = 0  # Resends in a row for the line after the last one there is
        # Reading the printer (receive_data, next_event).
        self._parser = LineParser()
        self._received_at = -math.inf
        self._answering: Ticket | None = None  # whose output is arriving: the last one queued
        self.greeted = False  # any line at all
        self.room: int | None = None  # Repetier does not say

    @property
    def corrupt_frames(self) -> int:
        return self._parser.garbled

    # -- what the caller asks -----------------------------------------------------------
    def request_drained(self) -> None:
        """Idle only once the printer has also run everything (its `wait`)."""
        self._want_drained = True

    @property
    def idle(self) -> bool:
        return (
            self.phase is Phase.STREAM
            and not self._backlog
            and not self._lines
            and (self._drained or not self._want_drained)
        )

    # -- time and transmission -----------------------------------------------------------
    def poll(self, now: float) -> list[bytes]:
        self._expire(now)
        if self.phase is Phase.SYNC:
            if self._sync_sent_at is None:
                return [self._send_sync(now)]
            return []
        if self.phase is Phase.STREAM:
            self._take_backlog()
        out = []
        while self._next_send < len(self._lines):
            line = self._lines[self._next_send]
            if not line.data:
                line.data, line.binary = encode_command(line.number, line.text, self.binary_version)
            if self._in_flight_bytes and self._in_flight_bytes + len(line.data) > self.cache:
                break
            out.append(self._transmit(line, now))
        if self._resync_alone and self._resync and not out:
            # The printer waits for a line there is not (yet): the NULs end its resync, so it
            # no longer asks, and says `wait` once idle.
            out.append(RESYNC)
            self._resync = False
        self._resync_alone = False
        return out

    def _take_backlog(self) -> None:
        while self._backlog and len(self._lines) < TAKE_AHEAD:
            ticket = self._backlog.popleft()
            self._lines.append(_Line(self._next_number, ticket.text, ticket))
            self._next_number += 1

    def _send_sync(self, now: float) -> bytes:
        if self._sync_sends >= self.max_transmissions:
            raise PrinterNotResponding(
                f"no answer to M110 after {self._sync_sends} tries; is a Repetier printer on the port?"
            )
        self._sync_sends += 1
        self._sync_sent_at = now
        self.stats.packets_sent += 1
        return repetier.encode(repetier.BinaryCommand(n=0, m=110))

    def _transmit(self, line: _Line, now: float) -> bytes:
        self.stats.resends += line.transmissions > 0
        self.stats.packets_sent += 1
        if line.transmissions == 0:
            self.stats.binary += line.binary
            self.stats.ascii += not line.binary
        line.transmissions += 1
        self._next_send += 1
        self._in_flight_bytes += len(line.data)
        self._drained = False
        self._idle_resends = 0
        self._last_heard = max(self._last_heard, now)
        data = line.data
        if self._resync:
            self._resync = False
            data = RESYNC + data
        return data

    def next_deadline(self) -> float | None:
        if self.phase is Phase.SYNC:
            return None if self._sync_sent_at is None else self._sync_sent_at + self.timeout
        if self.phase is Phase.IDENTIFY and not self._lines:
            return self._identify_deadline  # M115 was queued: its answer is due
        if not any(line.transmissions for line in self._lines):
            return None
        return self._last_heard + self._patience()

    def _patience(self) -> float:
        if self._keepalives:
            return max(self.timeout, KEEPALIVE_MARGIN)
        if self._lines and is_long_command(self._lines[0].text):
            return self.long_timeout
        return self.timeout

    def _expire(self, now: float) -> None:
        deadline = self.next_deadline()
        if deadline is None or now < deadline:
            return
        if self.phase is Phase.SYNC:
            self.stats.timeouts += 1
            self._sync_sent_at = None  # M110 may go again: it only sets the counter
        elif self.phase is Phase.IDENTIFY and not self._lines:
            self.phase = Phase.STREAM  # no M115 answer; it read binary M110, so binary V1
        else:
            self.stats.timeouts += 1
            self._go_back(now)
            self._last_heard = now

    def _go_back(self, now: float) -> None:
        """Send every unacknowledged line again; the firmware emptied its receive buffer, and
        after binary it waits for NULs. A go-back with lines out counts towards giving up."""
        if any(line.transmissions for line in self._lines):
            self._rounds += 1
            if self._trouble_since is None:
                self._trouble_since = now
            if (
                self._rounds >= self.max_transmissions
                and now - self._trouble_since >= (self.max_transmissions - 1) * self.timeout
            ):
                head = self._lines[0]
                raise PrinterNotResponding(
                    f"line {head.number} ({head.text!r}) was sent {head.transmissions} times "
                    "without being accepted; is a Repetier printer on the port?"
                )
        self._next_send = 0
        self._in_flight_bytes = 0
        self._resync = True

    # -- what the printer says -----------------------------------------------------------
    def receive_data(self, data: bytes, now: float) -> None:
        self._parser.receive_data(data)
        self._received_at = now

    def next_event(self) -> Line | None:
        """The printer's lines, each handled; those that are no command's output come out.
        Repetier acknowledges a command when it queues it, so what it prints comes after the
        ok: the output of the command queued last."""
        while (event := self._parser.next_event()) is not None:
            self.greeted = True
            self.on_event(event, self._received_at)
            if isinstance(event, Identity):
                event = Line(LineKind.DATA, event.text)
            if not isinstance(event, Line):
                continue
            ticket = self._answering
            if event.kind in (LineKind.DATA, LineKind.REPORT) and ticket is not None:
                ticket.response += (event.text,)
            else:
                return event
        return None

    def on_event(self, event: Event, now: float) -> None:
        if isinstance(event, Line) and event.kind is LineKind.START:
            self._on_start(event.text)
            return
        if not (isinstance(event, Line) and event.kind is LineKind.REPORT):
            # Temperatures the printer sends on its own say nothing about our lines.
            self._last_heard = now
        if isinstance(event, Ok):
            self._on_ok(event.line_number, now)
        elif isinstance(event, ResendRequest):
            self._on_resend(event.line, now)
        elif isinstance(event, Skip):
            head = self._lines[0] if self._lines else None
            if head is not None and head.transmissions and self._wire(head) == event.line_number:
                self._acknowledge(0, confirmed=False, now=now)  # all before it are in: it is too
        elif isinstance(event, Identity):
            if event.binary_version >= 1:  # 0: the version was not readable (or not said)
                self.binary_version = event.binary_version
            if self.phase is Phase.IDENTIFY:
                self.phase = Phase.STREAM
        elif event.kind is LineKind.WAIT:
            if self.phase is Phase.IDENTIFY and not self._lines:
                self.phase = Phase.STREAM  # M115 ran, and its answer came damaged or not at all
            if any(line.transmissions for line in self._lines):
                self._go_back(now)  # idle with lines unacknowledged: they, or their oks, were lost
            elif not self._lines:
                self._drained = True
        elif event.kind is LineKind.BUSY:
            self._keepalives = True
        elif event.kind is LineKind.HALTED or (
            event.kind is LineKind.ERROR and marlin.is_halt_message(event.text)
        ):
            raise PrinterHalted(f"the printer halted: {event.text}")
        elif event.kind is LineKind.ERROR:
            self._error_seen = True  # the printer read something and refused it

    def _on_start(self, text: str) -> None:
        if self.phase is Phase.STREAM:
            raise PrinterReset(f"the printer restarted ({text!r}); commands it had queued may be lost")
        # Still connecting (it was booting): start over.
        self.phase = Phase.SYNC
        self._sync_sent_at = None
        self._lines.clear()
        self._history.clear()
        self._next_send = self._in_flight_bytes = 0
        self._next_number = 1
        self._identify_deadline = None

    def _on_ok(self, number: int | None, now: float) -> None:
        if self.phase is Phase.SYNC:
            if number is None and self._sync_sent_at is not None:
                self.phase = Phase.IDENTIFY
                self._lines.append(_Line(self._next_number, IDENTIFY, None))
                self._next_number += 1
            return
        index = self._sent_index(number)
        if index is not None:
            self._acknowledge(index, confirmed=True, now=now)

    def _on_resend(self, number: int | None, now: float) -> None:
        self.stats.rejects += 1
        fresh = self._fresh(number, now)
        self._error_seen = False
        if self.phase is Phase.SYNC:
            if fresh:
                self._answered = (number, now)
                self._sync_sent_at = None
            return
        index = self._sent_index(number)
        if index is not None:
            if index:
                self._acknowledge(index - 1, confirmed=False, now=now)
        elif (back := self._acknowledged_index(number)) is not None:
            self._rewind(back)
            fresh = True
        else:
            # The line after the last one sent (or, with none out, the next one to go): the
            # printer has everything sent and wants more. Not a line long gone.
            sent = [i for i, line in enumerate(self._lines) if line.transmissions]
            if sent:
                following = self._lines[sent[-1]].number + 1
            else:
                following = self._lines[0].number if self._lines else self._next_number
            after_all = number is not None and (
                following & WIRE_NUMBER == number & WIRE_NUMBER
            )
            if after_all:
                if sent:
                    self._acknowledge(sent[-1], confirmed=False, now=now)  # every line sent is in
            elif number is not None and self.phase is Phase.STREAM:
                self._unknown_resend(number)
        if fresh:
            self._answered = (number, now)
            self._go_back(now)
            self._resync_alone = not self._lines
        if not self._lines and number is not None and (
            number & WIRE_NUMBER == self._next_number & WIRE_NUMBER
        ):
            # It has every line and waits for one there is not: it is idle (it reads, so its
            # one-command buffer is empty). Twice in a row, so a damaged number cannot say it.
            self._idle_resends += 1
            if self._idle_resends >= 2 and self.phase is Phase.STREAM:
                self._drained = True
        else:
            self._idle_resends = 0

    def _unknown_resend(self, number: int) -> None:
        """A Resend for a line the host neither has in flight nor keeps: a damaged number, once;
        asked again and again, a printer that restarted, its `start` lost, and now counts from
        the beginning (it repeats its Resend every 200 ms while the host's lines do not fit)."""
        if self._unknown_asked == number:
            self._unknown_asks += 1
        else:
            self._unknown_asked, self._unknown_asks = number, 1
        if self._unknown_asks >= UNKNOWN_RESENDS_MEAN_RESET:
            raise PrinterReset(
                f"the printer asks for line {number}, which this host sent long ago: it "
                "restarted, and what it had queued is gone"
            )

    def _fresh(self, number: int | None, now: float) -> bool:
        """Whether a Resend asks anew, rather than repeating the one whose answer is on its way
        (the firmware repeats it every 200 ms while nothing arrives)."""
        if self._answered is None:
            return True
        answered, at = self._answered
        if self._rounds >= self.max_transmissions:
            return now - at >= self.timeout  # refused this often: do not flood it as well
        if self._error_seen or number != answered:
            return True
        return now - at >= RESEND_GUARD

    def _sent_index(self, number: int | None) -> int | None:
        if number is None:
            return None
        for index, line in enumerate(self._lines):
            if line.transmissions and self._wire(line) == number & WIRE_NUMBER:
                return index
        return None

    def _acknowledged_index(self, number: int | None) -> int | None:
        """Where in the history the line `number` is, the latest with that wire number."""
        if number is None:
            return None
        for index in range(len(self._history) - 1, -1, -1):
            if self._wire(self._history[index]) == number & WIRE_NUMBER:
                return index
        return None

    def _rewind(self, index: int) -> None:
        """The printer asks for an acknowledged line: the acknowledgement was wrong (a damaged
        number). It and every line after it are unacknowledged again, to be sent again."""
        back = [self._history.pop() for _ in range(len(self._history) - index)]
        self._lines.extendleft(back)  # popped newest first: extendleft restores the order
        self._next_send = self._in_flight_bytes = 0
        self._drained = False
        self.stats.rewinds += 1

    def _acknowledge(self, index: int, confirmed: bool, now: float) -> None:
        """Lines up to the index-th were queued by the printer; only the last one was
        `confirmed` by its own ok."""
        for position in range(index + 1):
            line = self._lines.popleft()
            if self._next_send:
                self._next_send -= 1
                self._in_flight_bytes = max(0, self._in_flight_bytes - len(line.data))
            self._history.append(line)
            if line.number > self._acknowledged_through:
                self._acknowledged_through = line.number
                self._rounds, self._trouble_since, self._answered = 0, None, None
            if line.ticket is None or line.ticket.done:
                continue  # the host's own, or acknowledged before (then rewound)
            own_ok = confirmed and position == index
            line.ticket.done, line.ticket.confirmed = True, own_ok
            self.stats.unconfirmed += not own_ok
            self._completed.append(line.ticket)
            self._answering = line.ticket
        if self.phase is Phase.IDENTIFY and not self._lines and self._identify_deadline is None:
            self._identify_deadline = now + self.timeout

    @staticmethod
    def _wire(line: _Line) -> int:
        return line.number & WIRE_NUMBER
