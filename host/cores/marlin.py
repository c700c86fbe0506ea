"""Sending numbered lines to a Marlin printer exactly once, as a sans-IO state machine.

Why nothing runs twice or goes missing. Marlin keeps a counter L, the number of the last
numbered line it accepted, and accepts a line only if its number is L + 1 and its checksum is
right (a repeat of L or L - 1 is dropped silently; anything else draws Error, Resend: L+1, ok).
So the printer itself refuses every duplicate, as long as the host
- gives each command one number for good: a resend is the same text under the same number, and
  the numbering never restarts within a session (M110 only once, before the first command);
- counts nothing as delivered until the printer's counter has passed it: a job ends only when
  the printer has said L >= the job's last line.
Then `ok`s are not needed for safety at all. They pace the sending (one line in flight: Marlin
says ok after running a command, so a second line would only wait in its 4-line queue) and carry
responses; when they are lost, damaged, or belong to a line error, the cost is time, not a
command.

Reading L without side effects: the probe (host.codecs.marlin.PROBE), a numbered M110 without a
checksum. Marlin skips the number check for M110 lines, so the probe is always refused, never
run, and the refusal states L twice: `Error:... Last Line: L` and `Resend: L+1`. Only a
refusal whose two numbers agree is believed (one damaged digit must not move the host), and an
L below one already believed is old news (from an earlier, delayed probe) and ignored.

When the host probes:
- on connecting: if L is 0 (the printer was reset when the port opened, as boards are) the job
  is numbered from 1 and nothing else is sent; otherwise `N0 M110 N0` sets it to 0 and a probe
  confirms it did. M110 is the one line Marlin never refuses as a repeat, so it is never resent
  blindly: only after a probe shows L unchanged. The journal therefore gets `M110 N0` exactly
  once when the counter was not 0, and nothing from the host when it was.
- when the line in flight (number n) meets silence: L = n - 1 means it never arrived, so it is
  sent again; L = n means it arrived and its ok was lost (or is late): the host waits for the
  ok a while longer (`received_timeout`, or as long as before when the printer sends
  keepalives), then counts it done. This also covers a lost ok for the last line of a job,
  where sending line n + 1 (the other way to find out) is impossible.
- at the end of a job (wait_idle): one probe, so a job never ends on an ok that was in fact the
  ok of a line error whose Error and Resend lines were lost.
If L shows that lines counted done never arrived (that misread ok), they are sent again from
the history kept here; a line is never renumbered.

Line errors: Marlin prints Error, Resend and ok together. That ok is not a permission to send
(printcore's bug, docs/hosts.md): the host decides once the ok has come, or when another line or a
short wait shows it was lost.

Firmwares that check no line numbers (Klipper, RepRapFirmware) or read M110 their own way
(Smoothieware) cannot be probed: the probe draws a plain `ok` (it ran as M105) or nothing (its
bad checksum dropped) or a bare resend request (`rs N0`: no Error line, no ok). A printer
that has never stated a counter and answers probes so
(UNCHECKED_AFTER times; silence counts only from a printer that has said anything at all: one
silent from the start gets one plain M105, which tells a dead port from RepRapFirmware, silent
until asked and deaf to a bad checksum) is taken to check nothing: the host sends `N0 M110 N0` and numbers its
lines on, one in flight, paced by `ok`; a resend request sends the line it names again (from the
history); a line met by silence counts as done, unconfirmed. Nothing runs twice then, but a line
lost on the way is lost: such a firmware gives a host no way to know.

Patience is silence-based: the printer has said nothing about its work for `timeout`
(`long_timeout` while a long command such as G28 or M109 runs). What counts: ok, line errors,
busy keepalives, M109/M190's waiting lines. Reports it sends on its own at intervals (M155
temperatures, M154 positions) and stray lines do not, or they would hide a lost ok for ever. A
printer that sends keepalives (every 2 s, M113) speaks at least that often while it works, so
once one is seen the silence allowed is 2.5 keepalive intervals, whatever the command: a line
lost behind G28 costs seconds, not minutes.
"""

import math
import re
from collections import deque
from dataclasses import dataclass
from enum import Enum, auto

from fake_marlin.host.codecs.marlin import (
    PROBE,
    Line,
    LineError,
    LineKind,
    LineParser,
    Ok,
    ResendRequest,
    encode_line,
    encode_sync,
)
from fake_marlin.host.cores.queue import CommandQueue, Ticket, is_long_command
from fake_marlin.host.errors import (
    PrinterHalted,
    PrinterLocked,
    PrinterNotResponding,
    PrinterReset,
)

SYNC_COMMAND = "M110 N0"
KEEPALIVE_INTERVAL = 2.0  # Marlin's DEFAULT_KEEPALIVE_INTERVAL; M113 changes it (up to 60 s)
KEEPALIVE_MARGIN = 2.5  # intervals of silence before a printer that sends keepalives is silent
OK_AFTER_RESEND = 0.5  # the ok comes in the same write as its Error and Resend lines
HISTORY = 32  # completed lines kept for a resend
# Probes answered, but never legibly, that the host sends per silent one before it gives up. A
# probe's answer is three lines; at a bit error rate of 1e-3 each way half of them arrive
# damaged, so eight in a row are no proof of a dead printer, but 64 (once in 10^19) are.
GARBLED_PATIENCE = 8
# Answers in a row that count less than the printer had accepted, which prove it restarted: a
# late answer to an earlier probe is one; three are no longer late.
LOWER_COUNTS_MEAN_RESET = 3
# Probes answered by a plain ok or by nothing, from a printer that has never stated a counter,
# before the host takes it for one that checks no line numbers.
UNCHECKED_AFTER = 2
HELLO = b"M105\n"  # once, to a printer silent from the start (see _send_probe)
_M511 = re.compile(r"\s*[Mm]0*511(?!\d)")
_M113 = re.compile(r"\s*[Mm]0*113(?!\d)(?:.*?[Ss]\s*(\d+(?:\.\d*)?))?")


class LineState(Enum):
    SENT = auto()  # on its way, or waiting in the printer: no answer yet
    RECEIVED = auto()  # the printer's counter has reached it; its ok is still to come


@dataclass(eq=False)
class _Line:
    number: int
    text: str
    ticket: Ticket | None  # None for the host's own M110
    state: LineState = LineState.SENT
    since: float = 0.0  # when it was last sent, or found to have arrived
    transmissions: int = 0
    needs_transmit: bool = True


@dataclass
class _LineErrorReport:
    """Error, Resend and ok, as far as they have come."""

    since: float
    last_line: int | None = None
    error_seen: bool = False
    resend: int | None = None
    resend_seen: bool = False
    ok_seen: bool = False

    def printer_counter(self) -> int | None:
        """L, if both lines arrived and agree; None if the report cannot be believed."""
        if self.error_seen and self.resend_seen and self.last_line is not None:
            if self.resend == self.last_line + 1:
                return self.last_line
        return None

    def resend_hint(self) -> int | None:
        if self.resend is not None:
            return self.resend
        return None if self.last_line is None else self.last_line + 1


@dataclass
class MarlinStats:
    packets_sent: int = 0  # lines written, probes included
    resends: int = 0  # lines sent again
    timeouts: int = 0  # silences that made the host probe
    rejects: int = 0  # line errors for lines the host sent (not for probes)
    unconfirmed: int = 0  # lines counted done without their own ok
    probes: int = 0


class MarlinCore(CommandQueue):
    def __init__(
        self,
        timeout: float = 2.0,
        long_timeout: float = 300.0,
        received_timeout: float = 10.0,
        max_transmissions: int = 8,
    ) -> None:
        self.timeout = timeout
        self.long_timeout = long_timeout
        self.received_timeout = received_timeout
        self.max_transmissions = max_transmissions
        self.stats = MarlinStats()
        self.window = 1
        self._open_queue()
        self._lines: deque[_Line] = deque()  # numbered, not done; the first is in flight
        self._history: deque[_Line] = deque(maxlen=HISTORY)
        self._next_number = 1
        self._synced = False
        self._sync_line: _Line | None = None  # M110 N0, when the counter was not 0
        self._confirmed = -1  # the highest counter the printer has stated
        self._verify = False
        self._probe_wanted = True  # first of all: read the printer's counter
        self._probe_since: float | None = None  # a probe is out, sent then
        self._probe_streak = 0  # probes without a believable answer
        self._probe_silences = 0  # of those, probes that drew no line at all
        self._lower_counts = 0  # answers since, each counting less than the printer had accepted
        self._counter_seen = False  # the printer has stated its counter at least once
        self._unbelieving = 0  # probes it answered with a plain ok or nothing, never a counter
        self._hello_sent = False  # the plain M105 for a printer silent from the start
        self.unchecked = False  # it checks no line numbers: see the module's docstring
        self._ok_during_probe: tuple[str, ...] | None = None
        self._report: _LineErrorReport | None = None
        self._last_heard = -math.inf  # the last sign of work on what the host sent
        self._last_line = -math.inf  # the last line of any kind
        self._last_busy: float | None = None
        self._keepalive_interval: float | None = None  # None until a busy line is seen
        # Reading the printer (receive_data, next_event).
        self._parser = LineParser()
        self._received_at = -math.inf
        self._response: list[str] = []  # data lines since the last ok
        self.room: int | None = None  # ADVANCED_OK's P
        self.greeted = False  # any line at all

    @property
    def corrupt_frames(self) -> int:
        return self._parser.garbled

    # -- what the caller asks -----------------------------------------------------------
    @property
    def synced(self) -> bool:
        return self._synced

    @property
    def expecting_response(self) -> bool:
        """A command of the caller's is in flight, so data lines are its response."""
        return self._synced and self._in_flight() is not None

    def request_verification(self) -> None:
        """Before counting as idle, confirm the printer holds every line sent."""
        self._verify = True

    @property
    def idle(self) -> bool:
        return (
            self._synced
            and not self._backlog
            and not self._lines
            and self._report is None
            and self._probe_since is None
            and not self._probe_wanted
            and (not self._verify or self.unchecked or self._confirmed >= self._next_number - 1)
        )

    # -- time and transmission -----------------------------------------------------------
    def poll(self, now: float) -> list[bytes]:
        """Handle expired timers, then return what to write now (one line at most)."""
        self._expire(now)
        if self._report is not None or self._probe_since is not None:
            return []  # wait for the line error's ok, or the probe's answer
        if self._probe_wanted:
            return [self._send_probe(now)]
        head = self._head()
        if head is not None and head.needs_transmit:
            return [self._transmit(head, now)]
        if head is None and self._verify and self._synced:
            if self.unchecked or self._confirmed >= self._next_number - 1:
                self._verify = False
            else:
                return [self._send_probe(now)]
        return []

    def next_deadline(self) -> float | None:
        if self._report is not None:
            return max(self._report.since, self._last_heard) + min(self.timeout, OK_AFTER_RESEND)
        head = self._in_flight()
        if self._probe_since is not None:
            return max(self._probe_since, self._last_heard) + self._patience(head)
        if head is None or self._probe_wanted:
            return None
        patience = self._patience(head)
        if head.state is LineState.RECEIVED and self._keepalive_interval is None:
            # Its ok may only be late: without keepalives, silence does not say it has run.
            patience = max(patience, self.received_timeout)
        return max(head.since, self._last_heard) + patience

    def _patience(self, line: _Line | None) -> float:
        if self._keepalive_interval is not None:
            return max(self.timeout, KEEPALIVE_MARGIN * self._keepalive_interval)
        if line is not None and is_long_command(line.text):
            return self.long_timeout
        return self.timeout

    def _expire(self, now: float) -> None:
        deadline = self.next_deadline()
        if deadline is None or now < deadline:
            return
        if self._report is not None:
            self._settle_report(now)  # its ok was lost
        elif self._probe_since is not None:
            self.stats.timeouts += 1
            silent = self._last_line < self._probe_since
            self._probe_silences += silent
            # (Silence counts only from a printer that has said something: a dead port stays
            # one, and is given up on.)
            if not self._counter_seen and (silent and self.greeted
                                           or self._ok_during_probe is not None):
                self._unbelieving += 1
            self._probe_since, self._ok_during_probe = None, None
            if self._unbelieving >= UNCHECKED_AFTER and not self._synced:
                self._check_nothing()
            else:
                self._probe_wanted = True
        else:
            head = self._in_flight()
            assert head is not None  # else there was no deadline: nothing in flight, no probe
            if head.state is LineState.RECEIVED:
                self._complete(head, (), confirmed=False)
            elif self.unchecked and head.ticket is not None:
                self.stats.timeouts += 1
                self._complete(head, (), confirmed=False)  # at most once: nothing to ask
            else:
                self.stats.timeouts += 1
                self._probe_wanted = True

    def _head(self) -> _Line | None:
        """The line to send or in flight: M110 while syncing, then the caller's in order."""
        if not self._synced:
            return self._sync_line
        if not self._lines and self._backlog:
            ticket = self._backlog.popleft()
            self._lines.append(_Line(self._next_number, ticket.text, ticket))
            self._next_number += 1
        return self._lines[0] if self._lines else None

    def _in_flight(self) -> _Line | None:
        head = self._sync_line if not self._synced else (self._lines[0] if self._lines else None)
        if head is None or head.transmissions == 0 or head.needs_transmit:
            return None
        return head

    def _transmit(self, line: _Line, now: float) -> bytes:
        if line.transmissions >= self.max_transmissions:
            raise PrinterNotResponding(
                f"line {line.number} ({line.text!r}) was sent {line.transmissions} times "
                "without being accepted; is a Marlin printer on the port?"
            )
        self.stats.resends += line.transmissions > 0
        self.stats.packets_sent += 1
        line.transmissions += 1
        line.needs_transmit = False
        line.state = LineState.SENT
        line.since = now
        if line.ticket is None:
            # (Without the line feed before it where the printer answers every line, blank
            # ones too: Klipper would `ok` it, and the host run a line ahead of its oks.)
            return encode_line(0, line.text) if self.unchecked else encode_sync(line.text)
        return encode_line(line.number, line.text)

    def _send_probe(self, now: float) -> bytes:
        if (self._probe_silences >= self.max_transmissions
                or self._probe_streak >= self.max_transmissions * GARBLED_PATIENCE):
            raise PrinterNotResponding(
                f"no believable answer to {self._probe_streak} requests for the line number "
                f"({self._probe_silences} unanswered); is a Marlin printer on the port?"
            )
        self._probe_streak += 1
        self._probe_wanted = False
        self._probe_since = now
        self._ok_during_probe = None
        self.stats.probes += 1
        self.stats.packets_sent += 1
        if not self.greeted and not self._hello_sent and self._probe_silences >= UNCHECKED_AFTER:
            # Silent from the start, probes and all: a plain M105, which any firmware answers,
            # tells a dead port from one that drops the probe (RepRapFirmware).
            self._hello_sent = True
            return HELLO
        return PROBE

    # -- what the printer says -----------------------------------------------------------
    def receive_data(self, data: bytes, now: float) -> None:
        self._parser.receive_data(data)
        self._received_at = now

    def next_event(self) -> Line | None:
        """The printer's lines, each handled; those that are no command's response come out.
        Data lines while a command of the caller's is in flight are its response, which its
        ok closes (with what M105 says on the ok line itself)."""
        now = self._received_at
        while (event := self._parser.next_event()) is not None:
            self.greeted = True
            if isinstance(event, Ok):
                response = (*self._response, event.text) if event.text else tuple(self._response)
                self._response.clear()
                if event.planner_free is not None:
                    self.room = event.planner_free
                self.on_ok(event, response, now)
            elif isinstance(event, LineError):
                self.on_line_error(event.last_line, now)
            elif isinstance(event, ResendRequest):
                self.on_resend(event.line, now)
            else:
                self.on_line(event.kind, event.text, now)
                if event.kind in (LineKind.DATA, LineKind.ECHO) and self.expecting_response:
                    self._response.append(event.text)
                else:
                    return event
        return None

    def on_ok(self, ok: Ok, response: tuple[str, ...], now: float) -> None:
        self._heard(now)
        if self._report is not None:
            self._report.ok_seen = True
            self._settle_report(now)  # the ok that closes a line error: no permission
            return
        if self._probe_since is not None:
            # Either the late ok of the line in flight, or the probe's own (its Error and
            # Resend lost): the probe's answer will tell which.
            self._ok_during_probe = response
            return
        head = self._in_flight()
        if head is None:
            return  # nothing of ours is waiting for an ok
        if not self._synced and self.unchecked:
            self._synced, self._sync_line = True, None  # M110's ok: number on from 1
        elif not self._synced:
            self._probe_wanted = True  # M110's ok: confirm with the counter itself
        elif ok.line_number is None or ok.line_number == head.number:
            self._complete(head, response, confirmed=True)

    def on_line_error(self, last_line: int | None, now: float) -> None:
        self._heard(now)
        if self.unchecked:
            return  # its resend request, if any, says which line
        if self._report is not None:
            self._settle_report(now)  # the previous report's ok was lost
        self._report = _LineErrorReport(now, last_line=last_line, error_seen=True)

    def on_resend(self, line: int | None, now: float) -> None:
        self._heard(now)
        if self.unchecked:
            self._resend_from(line)
            return
        if self._report is not None and self._report.resend_seen:
            self._settle_report(now)
        if self._report is None:
            self._report = _LineErrorReport(now)
        self._report.resend, self._report.resend_seen = line, True

    def on_line(self, kind: LineKind, text: str, now: float) -> None:
        """Any other line: for some kinds a sign of work, or news."""
        if self._report is not None:
            self._settle_report(now)  # nothing comes between Resend and its ok: it was lost
        working = kind in (LineKind.BUSY, LineKind.START) or (kind is LineKind.REPORT and " W:" in text)
        self._heard(now, busy=kind is LineKind.BUSY, working=working)
        if kind is LineKind.HALTED:
            raise PrinterHalted(f"the printer halted: {text}")
        if kind is LineKind.LOCKED:
            head = self._in_flight()
            if head is None or not _M511.match(head.text):
                raise PrinterLocked(f"the printer is locked ({text}): it runs nothing until "
                                    "M511 P<password> unlocks it")
        if kind is LineKind.START:
            if self._synced:
                raise PrinterReset(
                    f"the printer restarted ({text!r}); commands it had queued may be lost"
                )
            if self._probe_since is not None:
                self._probe_since = now  # it was booting: the answer is still to come
        elif kind is LineKind.WAIT:
            # Marlin's queue is empty: the line in flight ran (its ok was lost) or never came.
            head = self._in_flight()
            if head is not None and self._probe_since is None and not self._probe_wanted:
                if head.state is LineState.RECEIVED or self.unchecked:
                    self._complete(head, (), confirmed=False)
                else:
                    self._probe_wanted = True

    def _heard(self, now: float, busy: bool = False, working: bool = True) -> None:
        if busy:
            # Two keepalives with nothing between them measure the interval (M113 may have
            # changed it from 2 s).
            interval = KEEPALIVE_INTERVAL
            if self._last_busy is not None and self._last_busy == self._last_line:
                interval = min(60.0, now - self._last_busy)
            self._keepalive_interval = max(self._keepalive_interval or 0.0, interval)
            self._last_busy = now
        self._last_line = now
        if working:
            self._last_heard = max(self._last_heard, now)

    # -- deciding ------------------------------------------------------------------------
    def _settle_report(self, now: float) -> None:
        report, self._report = self._report, None
        assert report is not None  # called only with a report open
        counter = report.printer_counter()
        if self._probe_since is not None:  # the answer to the probe (no line goes out meanwhile)
            self._probe_since = None
            ok, self._ok_during_probe = self._ok_during_probe, None
            if counter is not None:
                self._printer_has(counter, now, ok)
                return
            # Smoothieware's answer to anything it will not take: `rs N<n>` alone, never an
            # Error line, never an ok: no counter to read, ever.
            if (report.resend_seen and not report.error_seen and not report.ok_seen
                    and not self._counter_seen and not self._synced):
                self._unbelieving += 1
                if self._unbelieving >= UNCHECKED_AFTER:
                    self._check_nothing()
                    return
            self._probe_wanted = True
            return
        self.stats.rejects += 1
        if not self._synced:
            # M110 is never resent on a refusal alone: it may be an old probe's late answer,
            # from before the M110 went out. Only a probe sent after it can say it did not run.
            self._probe_wanted = True
            return
        if counter is not None:
            self._printer_has(counter, now)
            return
        head = self._in_flight()
        if head is not None and report.resend_hint() == head.number:
            head.needs_transmit = True  # always safe: Marlin refuses it if it has it
        else:
            self._probe_wanted = True

    def _check_nothing(self) -> None:
        """The printer checks no line numbers (the module's docstring): M110 N0, then on."""
        self.unchecked = True
        self._probe_wanted = False
        self._sync_line = _Line(0, SYNC_COMMAND, None)

    def _resend_from(self, line: int | None) -> None:
        """A firmware that checks numbers but cannot be probed (Smoothieware's `rs N5`): the
        line it names and those after it go again, if the host still has them."""
        if line is None or line < 1 or line >= self._next_number:
            return
        head = self._lines[0] if self._lines else None
        if head is not None and head.number == line:
            head.needs_transmit = True
            return
        if head is not None and head.number < line:
            return  # ahead of what is in flight: nothing to send again
        try:
            self._resend_missing(line - 1)
        except PrinterReset:
            return  # older than the history: it ran, or is lost for good
        for again in self._lines:  # it dropped those after it too: each goes again in turn
            again.needs_transmit, again.state = True, LineState.SENT

    def _printer_has(self, last: int, now: float, late_ok: tuple[str, ...] | None = None) -> None:
        """The printer's counter is `last`: it accepted every line up to it, none after."""
        self._counter_seen = True
        if not self._synced:
            self._probe_streak = self._probe_silences = 0
            self._sync(last)
            return
        if last < self._confirmed:
            # Older news (a delayed answer to an earlier probe), unless the printer says it
            # again and again: then it counts from less than it had, and restarted (its
            # `start` line lost on a noisy line).
            self._lower_counts += 1
            if self._lower_counts >= LOWER_COUNTS_MEAN_RESET:
                raise PrinterReset(
                    f"the printer counts line {last}, though it had accepted line "
                    f"{self._confirmed}: it restarted, and what it had queued is gone"
                )
            return
        self._probe_streak = self._probe_silences = self._lower_counts = 0
        if last >= self._next_number:
            raise PrinterReset(
                f"the printer counts line {last}, but this host has sent only up to "
                f"{self._next_number - 1}: another program may be using the port"
            )
        self._confirmed = last
        self._resend_missing(last)
        while self._lines and self._lines[0].number < last:
            self._complete(self._lines[0], (), confirmed=False)  # done before, sent again
        head = self._lines[0] if self._lines else None
        if head is None:
            return
        if head.number == last:
            if late_ok is not None:
                self._complete(head, late_ok, confirmed=True)
            elif head.transmissions > 0:
                head.state, head.since, head.needs_transmit = LineState.RECEIVED, now, False
        else:
            head.needs_transmit = True

    def _resend_missing(self, last: int) -> None:
        """Lines counted done after `last` never arrived (their ok was a line error's): put
        them back, under their own numbers."""
        expected = self._lines[0].number if self._lines else self._next_number
        while expected > last + 1:
            if not self._history or self._history[-1].number != expected - 1:
                raise PrinterReset(
                    f"the printer's last line is {last}, but it had acknowledged up to "
                    f"{expected - 1}: it was reset, or another program is using the port"
                )
            line = self._history.pop()
            line.needs_transmit = True
            self._lines.appendleft(line)
            expected -= 1

    def _sync(self, last: int) -> None:
        if last == 0:  # reset when the port opened, or our M110 N0 ran
            self._synced = True
            self._sync_line = None
            self._confirmed = 0
        elif self._sync_line is None:
            self._sync_line = _Line(0, SYNC_COMMAND, None)
        else:
            self._sync_line.needs_transmit = True  # the counter did not move: it never ran

    def _complete(self, line: _Line, response: tuple[str, ...], confirmed: bool) -> None:
        self._lines.remove(line)
        self._history.append(line)
        keepalive = _M113.match(line.text)
        if keepalive and keepalive[1] is not None:
            # The caller changed the keepalive interval; with S0 silence proves nothing again.
            seconds = min(60.0, float(keepalive[1]))
            if not seconds:
                self._keepalive_interval = None
            elif self._keepalive_interval is not None:
                self._keepalive_interval = seconds
            self._last_busy = None
        ticket = line.ticket
        if ticket is None or ticket.done:
            return  # a line sent again after its ok: counted once
        ticket.done, ticket.response, ticket.confirmed = True, response, confirmed
        self.stats.unconfirmed += not confirmed
        self._completed.append(ticket)
