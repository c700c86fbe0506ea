"""Streaming numbered commands to Repetier-Firmware, as a sans-IO state machine.

Why nothing runs twice or goes missing: the firmware itself refuses duplicates. It queues a
numbered command only if its number is last + 1 (modulo 2^16), answers a repeat less than 40
lines back with `skip`, and anything else (a gap, a damaged command) with `Resend:<last + 1>`.
So the host may always send a command again, under its own number, and never renumbers one.

What each answer proves:
- `ok <N>`: line N was queued, and so was every line before it (lines are taken in order).
- `Resend:<n>`: every line before n was queued, none from n on: send again from n. After a
  binary command the firmware then ignores everything until 31 NUL bytes in a row, so a resend
  starts with 32 (RESYNC), as Repetier-Host does.
- `skip <N>` for the oldest line not yet acknowledged: every line before it was queued, so the
  firmware skips N only because it has it: its `ok` was lost.
- `wait`: the firmware is idle with nothing queued: lines still unacknowledged were lost
  (or their oks were): send them again.
A bare `ok` (after M110, Resend or skip) proves nothing.

Flow control is Repetier-Host's: the bytes of unacknowledged lines stay within the firmware's
receive buffer (RECEIVE_CACHE), since the firmware stops reading while its one-command buffer
is full. Timeouts count silence: while the printer works it says `busy:` every 2 s.

Start: `N0 M110` (binary, so `--protocol auto` knows the host), then line 1 is M115, whose
`REPETIER_PROTOCOL:<v>` says whether the printer reads binary V2 (v >= 2) or binary at all.
"""

import math
from collections import deque
from dataclasses import dataclass
from enum import Enum, auto

from fake_marlin.host.codecs import marlin
from fake_marlin.host.codecs.repetier import (
    RESYNC,
    WIRE_NUMBER,
    Identity,
    Line,
    LineKind,
    Ok,
    Resend,
    Skip,
    encode_command,
)
from fake_marlin.host.cores.queue import CommandQueue, Ticket, is_long_command
from fake_marlin.host.errors import PrinterHalted, PrinterNotResponding, PrinterReset
from fake_marlin.wire import repetier

RECEIVE_CACHE = 127  # Repetier-Host's receiveCacheSize
KEEPALIVE_MARGIN = 5.0  # seconds of silence allowed once the printer sends busy: (every 2 s)
IDENTIFY = "M115"


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


class RepetierSender(CommandQueue):
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
        self._next_send = 0  # index into _lines of the next line to (re)transmit
        self._resync = False  # a resend after binary: NULs first
        self._in_flight_bytes = 0
        self._next_number = 1
        self._sync_sent_at: float | None = None
        self._sync_sends = 0
        self._last_heard = -math.inf
        self._keepalives = False
        self._want_drained = False
        self._drained = False  # `wait` since the last line went out: all of it has run

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
        return out

    def _take_backlog(self) -> None:
        while self._backlog and len(self._lines) < 64:
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
        if line.transmissions >= self.max_transmissions:
            raise PrinterNotResponding(
                f"line {line.number} ({line.text!r}) was sent {line.transmissions} times "
                "without being accepted; is a Repetier printer on the port?"
            )
        self.stats.resends += line.transmissions > 0
        self.stats.packets_sent += 1
        if line.transmissions == 0:
            self.stats.binary += line.binary
            self.stats.ascii += not line.binary
        line.transmissions += 1
        self._next_send += 1
        self._in_flight_bytes += len(line.data)
        self._drained = False
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
            return self._last_heard + self.timeout  # M115 was queued: its answer is due
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
            self._go_back()
            self._last_heard = now

    def _go_back(self) -> None:
        """Send every unacknowledged line again; the firmware emptied its receive buffer, and
        after binary it waits for NULs."""
        self._next_send = 0
        self._in_flight_bytes = 0
        self._resync = True

    # -- what the printer says -----------------------------------------------------------
    def on_event(self, event, now: float) -> None:
        if isinstance(event, Line) and event.kind is LineKind.START:
            self._on_start(event.text)
            return
        if not (isinstance(event, Line) and event.kind is LineKind.REPORT):
            # Temperatures the printer sends on its own say nothing about our lines.
            self._last_heard = now
        if isinstance(event, Ok):
            self._on_ok(event.line_number)
        elif isinstance(event, Resend):
            self._on_resend(event.line_number)
        elif isinstance(event, Skip):
            head = self._lines[0] if self._lines else None
            if head is not None and head.transmissions and self._wire(head) == event.line_number:
                self._acknowledge(0, confirmed=False)  # all before it are in: it is too
        elif isinstance(event, Identity):
            self.binary_version = event.binary_version
            if self.phase is Phase.IDENTIFY:
                self.phase = Phase.STREAM
        elif event.kind is LineKind.WAIT:
            if any(line.transmissions for line in self._lines):
                self._go_back()  # idle with lines unacknowledged: they, or their oks, were lost
            elif not self._lines:
                self._drained = True
        elif event.kind is LineKind.BUSY:
            self._keepalives = True
        elif event.kind is LineKind.HALTED or (
            event.kind is LineKind.ERROR and marlin.is_halt_message(event.text)
        ):
            raise PrinterHalted(f"the printer halted: {event.text}")

    def _on_start(self, text: str) -> None:
        if self.phase is Phase.STREAM:
            raise PrinterReset(f"the printer restarted ({text!r}); commands it had queued may be lost")
        # Still connecting (it was booting): start over.
        self.phase = Phase.SYNC
        self._sync_sent_at = None
        self._lines.clear()
        self._next_send = self._in_flight_bytes = 0
        self._next_number = 1

    def _on_ok(self, number: int | None) -> None:
        if self.phase is Phase.SYNC:
            if number is None and self._sync_sent_at is not None:
                self.phase = Phase.IDENTIFY
                self._lines.append(_Line(self._next_number, IDENTIFY, None))
                self._next_number += 1
            return
        index = self._sent_index(number)
        if index is not None:
            self._acknowledge(index, confirmed=True)

    def _on_resend(self, number: int | None) -> None:
        self.stats.rejects += 1
        if self.phase is Phase.SYNC:
            self._sync_sent_at = None
            return
        index = self._sent_index(number)
        if index is not None:
            if index:
                self._acknowledge(index - 1, confirmed=False)
        else:
            sent = [i for i, line in enumerate(self._lines) if line.transmissions]
            after_all = sent and number is not None and (
                (self._wire(self._lines[sent[-1]]) + 1) & WIRE_NUMBER == number & WIRE_NUMBER
            )
            if after_all:
                self._acknowledge(sent[-1], confirmed=False)  # every line sent is in
        self._go_back()

    def _sent_index(self, number: int | None) -> int | None:
        if number is None:
            return None
        for index, line in enumerate(self._lines):
            if line.transmissions and self._wire(line) == number & WIRE_NUMBER:
                return index
        return None

    def _acknowledge(self, index: int, confirmed: bool) -> None:
        """Lines up to the index-th were queued by the printer; only the last one was
        `confirmed` by its own ok."""
        for position in range(index + 1):
            line = self._lines.popleft()
            self._next_send = max(0, self._next_send - 1)
            self._in_flight_bytes = max(0, self._in_flight_bytes - len(line.data))
            if line.ticket is None:
                continue
            own_ok = confirmed and position == index
            line.ticket.done, line.ticket.confirmed = True, own_ok
            self.stats.unconfirmed += not own_ok
            self._completed.append(line.ticket)

    @staticmethod
    def _wire(line: _Line) -> int:
        return line.number & WIRE_NUMBER
