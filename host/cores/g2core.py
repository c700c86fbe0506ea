"""Streaming G-code to a g2core board exactly once, in order, as a sans-IO state machine.

What the board does (docs/protocols.md section 7, read from g2core's source): it reads a G-code
line only while its planner has at least 4 buffers free (and no feedhold or command of the line
before holds it), and answers every line it reads with one response,
`{"r":{...},"f":[1,<status>,<bytes>]}`, in the order it read them; with `{jv:4}` the response to
a line `N<k>` that ran carries `"n":k`. A line with a checksum (`N<k> ...*<xor>`) that does not
check out is refused with 118 (120: `*` without `N`) and never runs; such a refusal carries no
`n`. A JSON request is scanned out of the receive buffer ahead of any G-code waiting there and
answered at once. Reports (`{"sr":...}`, `{"qr":...}`, `{"er":...}`, `{"ack":true}`) carry no
footer and answer nothing. The footer's third element is the length of the line answered.

What the board does not do: sequence line numbers. Its check (cm_check_linenum) never runs (the
parser clears the flag that would run it), so a line that arrives twice runs twice, and one sent
again after later ones ran runs out of order. So the host never has more than one job line on
the board whose fate it does not know (`in_flight`, 0 or 1; `window` is how many the caller may
queue ahead), and sends a line again only once it knows the board has not run it and does not
hold it either.

A line goes as `N0<gcode>N<k>;*<xor>` (codecs.g2core.encode_line says why: g2core takes its last
N word, so only a line that reached the board whole carries k). It is done when a response with
`"n":k` comes (its status 0, or 3 or 4, informational; one below 100, which g2core never gives a
G-code line, is the 0 damaged on the way back; one of 100 or more, a refusal, see below). A
response naming an earlier line is a late or repeated answer of a line done: passed over, never
taken for this one's. Anything else (silence for `timeout`, a refusal, a response without `n`
or naming another line) leaves the line's fate unknown, and the host resolves it:
- it sends a fence (codecs.g2core.FENCES, a line the board always refuses and never runs; two
  lengths, used in turn, so that a late answer to an earlier resolution's fence is told from
  this one's). The board answers it in its turn, after the line, so its answer means the board
  has read the line or never got it: nothing of it waits in the receive buffer any more. A line
  cut short on the way (no line end) runs into the fence and is refused with it;
- while the fence is unanswered the host writes ENQ (answered `{"ack":true}` at once) every
  `timeout`, to know the board is alive, and another fence now and then (one may be lost). A
  board that says nothing at all for `max_transmissions` of them is PrinterNotResponding; one
  that says something may take as long as it likes (a long move, a feedhold, a heater's wait);
- once the fence is answered it asks `{"n":n,"jv":n,"stat":n}`: the last line number the board
  ran (`n`, the model's line number; only a line that ran sets it), its JSON verbosity, its
  state; until two answers in a row agree (a digit can be damaged on the way back). `n` = k: the
  line ran and its answer was lost: done, unconfirmed. Any other `n` (the one before the line:
  the host numbers from the board's `n` + 1, so it is never k; 0: only a piece of the line
  ran, cut short or in two on the way; another: a line of no one's, garbage with an N word,
  ran last) means it did not run, and it is not on the board: it is sent again, under the
  same number. (A line whose number was damaged past the XOR would run twice: two flips of one
  bit among its digits.) A `jv` other than 4 means the board has lost the host's
  settings: it restarted (its banner lost), PrinterReset. A halted `stat` is PrinterHalted.
  The host's requests are asked again after `timeout`; it gives up (PrinterNotResponding) after
  `max_transmissions` met by silence, not by damaged answers (the board is there).
A line refused (a status of 100 or more with its `n`: read, so not on the board; or, found out
so, without one) is sent again at once, under a new number where the board took its number:
a flip past the XOR may have made it a code the board refuses. Refused twice with the same
status (but 118-120, damage on the way) it is CommandFailed.

JSON requests and a line cut short: a line whose end is lost runs into whatever comes next. A
JSON request after it would make one line with no `*` of it, which g2core runs unchecked. So
the host writes a JSON request only when no line of its own can be cut short on the board: with
no job line unresolved, or after a fence's answer (ENQ, having no line end, is harmless). The
first thing written on connecting is a fence, for what a host before it left half-sent. (A
caller's feedhold, resume and cancel are single characters, which g2core takes only at the
start of a line: after a line cut short on the way they would join it.)

Statuses of the host's own requests are noted and passed over (a 100.x board has no `qv`, say).

Connecting: a fence, then `{"ej":1}` (JSON; first, so that a board in text mode answers in
JSON), `{"jv":4}` (responses with `n`), `{"qv":0}` (no queue reports: the host asks when it
wants them), `{"sv":1}` (filtered status reports), then `{"fb":n}`, `{"fv":n}` (the firmware
build and version), `{"qr":n}` (the idle planner's free buffers) and `{"n":n}` (the board's
line number: the job is numbered on from it), one at a time, each asked again after `timeout`
of silence, up to `max_transmissions` times. The power-up banner
(`{"r":{"fv":0.99,"fb":101.03,...,"msg":"SYSTEM READY"},"f":[1,0,1]}`) may come at any moment of
this, unasked: it is never an answer, it gives the firmware's identity, and as the board resets
its communication settings before it, the settings start again from `{"ej":1}`. A banner after
the caller's commands have gone out may be a restart, or the greeting of the connect, late (a
Marlin-compatible build greets a USB host 2 s after the port opens) or repeated on the way: the
host asks LINE_QUERY at once, and a jv back to its default (two answers agreeing) is
PrinterReset; a jv of 4 shows the host's settings there: it goes on.

Done-ness: a response means the line was read and planned, not run. The job is done (`idle`,
once the caller asked for that with request_drained()) when every line is done and then
`{"sr":n}` shows the machine out of any cycle (stat 1 ready, 3 program stop, 4 program end) and
`{"qr":n}` shows the planner as empty as when the host connected. Until then the host asks
again every DRAIN_POLL, at once when the board reports stat 3 or 4 on its own; a stat of 2
(alarm), 12 (shutdown) or 13 (panic), said twice in a row, is PrinterHalted (a report of it
while a line is unresolved makes the host ask at once). M0 leaves moves queued at stat 3: the
job waits for a resume (`~`).

Feedhold (`!`), resume (`~`) and cancel: cancel drops what the caller has not sent, writes ^D
(job kill: the board empties its planner and drops what it has not read) and then a status
request, whose answer marks the point after which no dropped line will be answered; a line
unanswered by then never ran (its ticket is completed unconfirmed, counted as cancelled). On
a 100.x board ^D leaves the machine in alarm, which `{"clear":n}` then clears.
"""

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum, auto

from fake_marlin.host.codecs.g2core import (
    ENQUIRY,
    Boot,
    Event,
    Line,
    LineKind,
    Noise,
    Report,
    ReplyReader,
    Response,
    compact,
    encode_fence,
    encode_line,
    encode_request,
    fence_size,
    is_fence_answer,
    is_request,
)
from fake_marlin.host.cores.queue import CommandQueue, Ticket
from fake_marlin.host.errors import CommandFailed, PrinterHalted, PrinterNotResponding, PrinterReset
from fake_marlin.wire import g2core as wire

WINDOW = 4  # commands the caller may queue ahead of the line in flight
DRAIN_POLL = 0.5  # seconds between status requests while the board finishes a job
MAX_FENCE_GAP = 8  # timeouts between fences at most, while the board says it is alive
INFORMATIONAL = frozenset({wire.NOOP, 4})  # statuses that do not stop a job (4: STAT_COMPLETE)
REFUSED = frozenset({wire.CHECKSUM_MISMATCH, wire.LINE_NUMBER_OUT_OF_SEQUENCE,
                     wire.MISSING_LINE_NUMBER})  # damaged on the way: never ran
IDLE_STATES = frozenset({1, 3, 4})  # ready, program stop, program end
HALTED_STATES = {2: "ALARM", 12: "SHUTDOWN", 13: "PANIC"}
HOST_JV = 4
SETUP = (
    ("ej", '{"ej":1}'),
    ("jv", '{"jv":4}'),
    ("qv", '{"qv":0}'),
    ("sv", '{"sv":1}'),
    ("fb", '{"fb":n}'),
    ("fv", '{"fv":n}'),
    ("qr", '{"qr":n}'),
    ("n", '{"n":n}'),
)
# What the host's settings must read back as (the rest of SETUP are questions).
SETTINGS_WANTED = {"ej": 1, "jv": HOST_JV, "qv": 0, "sv": 1}
MAX_SETUP_RETRIES = 8
STATUS_REQUEST = '{"sr":n}'
QUEUE_REQUEST = '{"qr":n}'
CLEAR_REQUEST = '{"clear":n}'
LINE_QUERY = '{"n":n,"jv":n,"stat":n}'  # its answer is told by "jv", which no line's carries
# Names in the host's own requests: a line's response never carries them (but "n").
HOST_NAMES = frozenset({name for name, _ in SETUP} | {"sr", "qr"}) - {"n"}


class Phase(Enum):
    SETUP = auto()  # the host's settings and questions, one at a time
    READY = auto()


class Purpose(Enum):
    SETUP = auto()
    STATUS = auto()  # {"sr":n} of a drain check
    QUEUE = auto()  # {"qr":n} of a drain check
    QUERY = auto()  # LINE_QUERY: what became of the line in flight
    CANCEL_MARK = auto()  # the request after ^D
    CLEAR = auto()  # {"clear":n} after ^D on 100.x
    CALLER = auto()  # a caller's own JSON request


@dataclass(eq=False)
class _Request:
    text: str
    purpose: Purpose
    key: str | None  # the name its answer carries; None: sent alone, the next response is it
    ticket: Ticket | None = None
    sent_at: float | None = None  # None: not (yet, or again) on its way
    transmissions: int = 0
    silences: int = 0  # timeouts waited through (a caller's request is never asked again)
    unheard: int = 0  # timeouts with nothing at all from the board (damaged answers are something)


@dataclass(eq=False)
class _Line:
    number: int
    ticket: Ticket
    data: bytes
    sent_at: float = -math.inf  # its last transmission
    transmissions: int = 0
    due: bool = True  # to be sent (again)
    refusals: list[int] = field(default_factory=list)  # statuses it was refused with, one a try


@dataclass(eq=False)
class _Resolution:
    """The host finding out what became of the line in flight (see the module's docstring)."""

    generation: int  # of its fences (their length)
    probe_at: float  # the last ENQ (or the start): the next is due `timeout` later
    next_fence_at: float
    fence_due: bool = True
    fences: int = 0
    fenced: bool = False  # a fence of this generation answered: the line is read or lost
    heard: bool = False  # the board said something since the last probe
    silent: int = 0  # probes in a row met by silence
    answers: list[tuple[int | None, int | None, int | None]] = field(default_factory=list)


@dataclass
class G2coreStats:
    packets_sent: int = 0  # lines and JSON requests written (single characters are not counted)
    resends: int = 0  # job lines sent again, and the host's own requests asked again
    timeouts: int = 0  # silences: a request unanswered, or a line and nothing heard of it
    rejects: int = 0  # refusals and statuses that stop a job, or that refuse the host's request
    unconfirmed: int = 0  # commands completed without their own response (ran; or cancelled)
    noops: int = 0  # lines answered with an informational status (3, 4)
    requests: int = 0  # the host's own JSON requests written
    reports: int = 0  # reports of the board's own (sr, qr, er, prb, ack...)
    cancelled: int = 0  # commands dropped by cancel() before the board ran them
    mismatches: int = 0  # responses naming a line done before (late or repeated answers)
    resolutions: int = 0  # times a line's fate was unknown and found out
    fences: int = 0
    enquiries: int = 0  # ENQs written while a fence was unanswered
    damaged_statuses: int = 0  # a line's response with a status g2core never gives a line


class G2coreCore(CommandQueue):
    def __init__(
        self,
        window: int = WINDOW,
        timeout: float = 2.0,
        max_transmissions: int = 8,
    ) -> None:
        if window < 1:
            raise ValueError(f"window must be at least 1, not {window}")
        self.window = window  # commands the caller may queue ahead
        self.timeout = timeout
        self.max_transmissions = max_transmissions
        self.stats = G2coreStats()
        self.phase = Phase.SETUP
        self.firmware_build: float | None = None  # fb, e.g. 101.03
        self.firmware_version: float | None = None  # fv, e.g. 0.99
        self.machine_state: int | None = None  # stat, as last reported
        self.room: int | None = None  # free planner buffers (qr), as last reported
        self.greeted = False  # the board has said something
        self.corrupt_frames = 0
        self._open_queue()
        self._setup_step = 0
        self._setup_retries = 0
        self._line: _Line | None = None  # the job line whose fate is not known yet
        self._resolution: _Resolution | None = None
        self._generation = 0  # of the last fence written: the connect fence is generation 0
        self._fence_on_connect = True
        self._base = 0  # the board's line number (n) as last known: what the line in flight met
        self._next_number = 1
        self._request: _Request | None = None  # the one JSON request on its way
        self._urgent: list[bytes] = []  # single characters to write before anything else
        self._idle_room = wire.PLANNER_QUEUE_SIZE
        self._started_at: float | None = None  # the first poll: when the host connected
        self._banner: str | None = None  # a banner after the caller's first command, unsettled
        self._check_answers: list[tuple[int | None, int | None, int | None]] = []
        self._caller_sent = False  # a caller's command has gone out
        self._reader = ReplyReader()
        self._received_at = -math.inf
        self._heard_at = -math.inf  # the board's last line, whatever it was
        # A drain check: running, its status answer, halted answers in a row.
        self._checking = False
        self._check_stat: int | None = None
        self._halted_answers = 0
        self._want_drained = False
        self._drained = False
        self._next_drain_check = -math.inf
        # cancel() is under way: its mark (and on 100.x the clear) not yet answered.
        self._cancelling = False

    # -- what the caller asks -----------------------------------------------------------
    def request_drained(self) -> None:
        """Idle only once the board has also run everything (see the module's docstring)."""
        self._want_drained = True

    @property
    def idle(self) -> bool:
        return (
            self.phase is Phase.READY
            and not self._backlog
            and self._line is None
            and not self._cancelling
            and (self._request is None or self._request.purpose is not Purpose.CALLER)
            and (self._drained or not self._want_drained)
        )

    @property
    def in_flight(self) -> int:
        """Job lines sent whose fate is not known yet: 0 or 1."""
        return int(self._line is not None)

    def feedhold(self) -> None:
        """`!`: the board decelerates to a stop and (101.x) reads no G-code until resume()."""
        self._urgent.append(bytes([wire.FEEDHOLD]))

    def resume(self) -> None:
        """`~`: ends a feedhold (or starts motion queued behind M0)."""
        self._urgent.append(bytes([wire.CYCLE_START]))

    def cancel(self) -> None:
        """Stop the job: nothing more is sent, and the board drops what it has queued and not
        read (^D, job kill); idle once the board has answered a request sent after it."""
        for ticket in self._backlog:
            self._drop(ticket)
        self._backlog.clear()
        self._urgent.append(bytes([wire.KILL_JOB]))
        abandoned = self._request
        if abandoned is not None and abandoned.ticket is not None:
            self._drop(abandoned.ticket)  # (should its answer come first, it is shown, not kept)
        # The mark asks for another name than a request left on its way, whose late answer
        # (read before the ^D) must not pass for it.
        mark = (QUEUE_REQUEST, "qr") if abandoned is not None and abandoned.key == "sr" else (STATUS_REQUEST, "sr")
        self._request = _Request(mark[0], Purpose.CANCEL_MARK, mark[1])
        self._checking = False
        self._resolution = None
        self._cancelling = True
        self._drained = False

    def _drop(self, ticket: Ticket) -> None:
        ticket.done, ticket.confirmed, ticket.response = True, False, ()
        self.stats.cancelled += 1
        self.stats.unconfirmed += 1
        self._completed.append(ticket)

    # -- time and transmission -----------------------------------------------------------
    def poll(self, now: float) -> list[bytes]:
        """Handle the timers due by `now`; return what to write now, in order."""
        if self._started_at is None:
            self._started_at = now
        out, self._urgent = self._urgent, []
        if self._fence_on_connect:
            self._fence_on_connect = False
            out.append(self._fence(self._generation))
        self._expire(now, out)
        if self.phase is Phase.SETUP:
            if self._request is None:
                name, text = SETUP[self._setup_step]
                self._request = _Request(text, Purpose.SETUP, name)
        elif not self._cancelling:
            resolution = self._resolution
            if resolution is not None and resolution.fence_due:
                resolution.fence_due = False
                resolution.fences += 1
                gap = min(resolution.fences, MAX_FENCE_GAP)
                resolution.next_fence_at = now + self.timeout * gap
                out.append(self._fence(resolution.generation))
            if self._banner is not None and self._request is None and self._resolution is None:
                self._request = _Request(LINE_QUERY, Purpose.QUERY, "jv")  # (asked after another)
            out += self._send_line(now)
            if self._request is None and not self._checking and self._drain_due(now):
                self._start_drain_check()
        request = self._request
        if request is not None and request.sent_at is None:
            out.append(self._transmit(request, now))
        return out

    def _fence(self, generation: int) -> bytes:
        self.stats.fences += 1
        return encode_fence(generation)

    def _send_line(self, now: float) -> list[bytes]:
        if self._request is not None:
            return []  # (no line goes while a request may be asked again: see the docstring)
        line = self._line
        if line is None:
            if not self._backlog:
                return []
            ticket = self._backlog.popleft()
            self._caller_sent = True
            if is_request(ticket.text):
                # Alone: its answer may overtake those of lines before it.
                self._request = _Request(ticket.text, Purpose.CALLER, None, ticket)
                return []
            number = self._take_number()
            line = self._line = _Line(number, ticket, encode_line(number, ticket.text))
        if not line.due or self._resolution is not None:
            return []
        line.due = False
        self.stats.resends += line.transmissions > 0
        line.transmissions += 1
        line.sent_at = now
        self.stats.packets_sent += 1
        self._drained = False
        return [line.data]

    def _take_number(self) -> int:
        number = self._next_number = max(self._next_number, self._base + 1)
        self._next_number += 1
        return number

    def _transmit(self, request: _Request, now: float) -> bytes:
        if request.unheard >= self.max_transmissions:
            raise PrinterNotResponding(
                f"no answer to {request.text} after {request.transmissions} tries, the last "
                f"{request.unheard} met by silence; "
                "is a g2core board on the port?"
            )
        self.stats.resends += request.transmissions > 0
        self.stats.packets_sent += 1
        self.stats.requests += request.purpose is not Purpose.CALLER
        request.transmissions += 1
        request.sent_at = now
        if request.purpose is Purpose.CALLER:
            self._drained = False
        return encode_request(request.text)

    def next_deadline(self) -> float | None:
        """When to poll again if nothing comes (None: only once something does)."""
        # (What is to be sent at once needs no deadline: whatever makes it due, a line from the
        # board or the caller's submit, wakes the shell to poll.)
        deadlines: list[float] = []
        request = self._request
        if request is not None and request.sent_at is not None:
            deadlines.append(request.sent_at + self.timeout * (request.silences + 1))
        line = self._line
        if self.phase is Phase.READY and line is not None and not line.due and not self._cancelling:
            resolution = self._resolution
            if resolution is None:
                deadlines.append(line.sent_at + self.timeout)
            elif not resolution.fenced:
                deadlines.append(resolution.probe_at + self.timeout)
        if (request is None and line is None and self.phase is Phase.READY
                and self._want_drained and not self._drained and not self._backlog
                and not self._cancelling and self._next_drain_check != -math.inf):
            deadlines.append(self._next_drain_check)
        return min(deadlines) if deadlines else None

    def _drain_due(self, now: float) -> bool:
        return (
            self._want_drained
            and not self._drained
            and not self._backlog
            and self._line is None
            and now >= self._next_drain_check
        )

    def _expire(self, now: float, out: list[bytes]) -> None:
        request = self._request
        if request is not None and request.sent_at is not None:
            if now >= request.sent_at + self.timeout * (request.silences + 1):
                if request.purpose is Purpose.CALLER:
                    # Never asked again (it may not be harmless twice): given up on in time.
                    silences = int((now - request.sent_at) // self.timeout)
                    self.stats.timeouts += silences - request.silences
                    request.silences = silences
                    if silences >= self.max_transmissions:
                        raise PrinterNotResponding(
                            f"no answer to {request.text} in {now - request.sent_at:g} s; "
                            "is a g2core board on the port?"
                        )
                else:
                    self.stats.timeouts += 1
                    request.unheard += self._heard_at < request.sent_at
                    request.sent_at = None  # asked again
        line = self._line
        if self.phase is not Phase.READY or line is None or line.due or self._cancelling:
            return
        resolution = self._resolution
        if resolution is None:
            if now >= line.sent_at + self.timeout:
                self.stats.timeouts += 1
                self._resolve(now)
        elif not resolution.fenced and now >= resolution.probe_at + self.timeout:
            self.stats.timeouts += 1
            resolution.silent = 0 if resolution.heard else resolution.silent + 1
            if resolution.silent >= self.max_transmissions:
                raise PrinterNotResponding(
                    f"line {line.number} ({line.ticket.text!r}) is unanswered, and the board has "
                    f"said nothing for {now - line.sent_at:g} s; is a g2core board on the port?"
                )
            resolution.heard = False
            resolution.probe_at = now
            out.append(ENQUIRY)
            self.stats.enquiries += 1
            if now >= resolution.next_fence_at:
                resolution.fence_due = True

    def _resolve(self, now: float) -> None:
        """The line's fate is unknown: find it out (see the module's docstring)."""
        line = self._line
        if self._resolution is not None or self._cancelling or line is None or line.due:
            return
        self._generation += 1
        self.stats.resolutions += 1
        self._resolution = _Resolution(self._generation, probe_at=now, next_fence_at=now)

    def _start_drain_check(self) -> None:
        self._checking = True
        self._check_stat = None
        self._request = _Request(STATUS_REQUEST, Purpose.STATUS, "sr")

    def _ask(self, resolution: _Resolution) -> None:
        if self._request is None:
            self._request = _Request(LINE_QUERY, Purpose.QUERY, "jv")

    # -- what the board says -------------------------------------------------------------
    def receive_data(self, data: bytes, now: float) -> None:
        """Bytes from the board, come at `now`; handled as next_event() is drained."""
        self._reader.receive_data(data)
        self._received_at = now

    def next_event(self) -> Line | None:
        """The board's lines, each handled; those that answer none of the caller's commands
        come out. Raises a RemoteError where the board's words end the session."""
        while (event := self._reader.next_event()) is not None:
            self.greeted = True
            line = self.on_event(event, self._received_at)
            if line is not None:
                return line
        return None

    def on_event(self, event: Event, now: float) -> Line | None:
        """One line of the board's, handled; returns what the caller should be shown."""
        self._heard_at = max(self._heard_at, now)
        if self._resolution is not None:
            self._resolution.heard = True  # (a damaged line too: the board is alive)
        if isinstance(event, Noise):
            self.corrupt_frames += event.damaged
            return Line(LineKind.NOISE, event.text)
        if isinstance(event, Report):
            return self._on_report(event, now)
        if isinstance(event, Boot):
            return self._on_boot(event, now)
        return self._on_response(event, now)

    def _on_report(self, report: Report, now: float) -> Line:
        self.stats.reports += 1
        body = report.body
        kind = LineKind.EXCEPTION if report.name == "er" else LineKind.REPORT
        room = _integer(body.get("qr"))
        if room is not None:
            self._saw_room(room)
        status = body.get("sr")
        if isinstance(status, Mapping):
            stat = _integer(status.get("stat"))
            if stat is not None:
                self._saw_state(stat, now)
                if stat in HALTED_STATES and self._line is not None and not self._cancelling:
                    # Halted, or a digit damaged: ask at once (nothing runs on a halted board,
                    # so the question cannot join a line cut short into one that runs).
                    self._resolve(now)
                    if self._resolution is not None:
                        self._ask(self._resolution)
        return Line(kind, report.text, body)

    def _on_boot(self, boot: Boot, now: float) -> Line:
        self._take_identity(boot.body)
        if self._caller_sent:
            # A restart, or the greeting of a connect (late, or repeated on the way): a board
            # that restarted has its settings back to the defaults, jv 2. Asked at once (a
            # restarted board holds nothing of the host's that could join the question).
            self._banner = boot.text
            self._check_answers.clear()
            line = self._line
            if line is not None and not line.due:
                self._resolve(now)
            if self._resolution is not None:
                self._resolution.answers.clear()
                self._ask(self._resolution)
            elif self._request is None:
                self._request = _Request(LINE_QUERY, Purpose.QUERY, "jv")
        else:
            # Before the caller's first command: its communication settings were just reset,
            # so the host's start again (a late answer to one asked before is passed over).
            # Nothing of the caller's was on the board either, so a cancel has nothing left to do.
            self.phase = Phase.SETUP
            self._setup_step = 0
            self._request = None
            self._checking = False
            self._cancelling = False
        return Line(LineKind.BOOT, boot.text, boot.body)

    def _on_response(self, response: Response, now: float) -> Line | None:
        request = self._request
        body = response.body
        fence = is_fence_answer(response)
        if request is not None and request.sent_at is not None and (
            request.key in body if request.key is not None
            else self._answers_alone(request, response)
        ):
            self._request = None
            self._on_answer(request, response, now)
            return None
        if body.keys() & HOST_NAMES:
            return None  # a late answer to a request of the host's asked again
        line = self._line
        if fence:
            resolution = self._resolution
            if (line is not None and resolution is not None and not resolution.fenced
                    and response.length == fence_size(resolution.generation)):
                resolution.fenced = True
                resolution.answers.clear()  # (what was asked early is asked again)
                self._ask(resolution)
            return None  # else a fence's late answer
        if line is not None and self.phase is Phase.READY:
            if not line.due:  # (due: not on the board, so nothing said now is about it)
                self._on_line_answer(line, response, now)
            return None
        return Line(LineKind.RESPONSE, response.text, body)

    @staticmethod
    def _answers_alone(request: _Request, response: Response) -> bool:
        """Whether a response is the answer of a request sent alone: the next one, but a fence's
        late answer, or a line's late one (a body of `n` only, of another length)."""
        if is_fence_answer(response):
            return False
        return not (response.body.keys() == {"n"}
                    and response.length != len(encode_request(request.text)) + 1)

    def _on_line_answer(self, line: _Line, response: Response, now: float) -> None:
        number = _integer(response.body.get("n"))
        if number == line.number:
            status = response.status
            if status >= 100:
                # It was read (so it is not on the board any more), and refused or failed.
                self._refused(line, status, response.body.get("msg"))
                self._base = line.number  # its number is the board's now
                line.number = self._take_number()  # so the next try goes under another
                line.data = encode_line(line.number, line.ticket.text)
                self._send_again(line)
                return
            self._done(line, response)
            return
        if number is not None and number < line.number:
            self.stats.mismatches += 1  # a late or repeated answer of a line done
            return
        status = response.status
        fenced = self._resolution is not None and self._resolution.fenced
        if (number is None and status != wire.OK and response.length == len(line.data)
                and "err" not in response.body and not fenced):
            # Likely its own refusal (a JSON request's has `err` at jv 4; and once a fence is
            # answered the line has been read: what comes after is another line's).
            self._refused(line, status, response.body.get("msg"))
        self._resolve(now)

    def _refused(self, line: _Line, status: int, said: object = None) -> None:
        """A refusal of the line: a second with the same status (but 118-120, damage on the
        way) is CommandFailed; the first may be damage past the XOR, and it is tried again."""
        self.stats.rejects += 1
        if status in REFUSED or len(line.refusals) >= line.transmissions:
            return  # (damage on the way; or a refusal of this transmission said again)
        line.refusals.append(status)
        if line.refusals[-2:] == [status, status]:
            raise CommandFailed(self._refusal(f"line {line.number} ({line.ticket.text!r})",
                                              status, said), status)

    def _done(self, line: _Line, response: Response | None) -> None:
        """The line ran: its response came, or the board's line number says so."""
        self._line = None
        self._resolution = None
        self._base = line.number
        if self._request is not None and self._request.purpose is Purpose.QUERY:
            self._request = None  # (its answer, should it come, is passed over)
        ticket = line.ticket
        if response is None:
            ticket.done, ticket.confirmed, ticket.response = True, False, ()
            self.stats.unconfirmed += 1
            self._completed.append(ticket)
            return
        status = response.status
        if status < 100 and status != wire.OK and status not in INFORMATIONAL:
            self.stats.damaged_statuses += 1  # no G-code line gets one: a 0 damaged
            response = Response(response.body, wire.OK, response.length, response.text)
        self._finish(ticket, response, f"line {line.number} ({ticket.text!r})")

    def _finish(self, ticket: Ticket, response: Response, what: str) -> None:
        status = response.status
        if status != wire.OK and status not in INFORMATIONAL:
            self.stats.rejects += 1
            raise CommandFailed(self._failure(what, response), status)
        self.stats.noops += status != wire.OK
        data = {name: value for name, value in response.body.items() if name != "n"}
        ticket.done, ticket.confirmed = True, True
        ticket.response = (compact(data),) if data else ()
        self._completed.append(ticket)

    @staticmethod
    def _failure(what: str, response: Response) -> str:
        return G2coreCore._refusal(what, response.status, response.body.get("msg"))

    @staticmethod
    def _refusal(what: str, status: int, said: object = None) -> str:
        message = wire.STATUS_MESSAGES.get(status, "a status g2core does not list")
        detail = f": {said}" if isinstance(said, str) and said and said != message else ""
        return f"the board refused {what}: status {status} ({message}){detail}"

    def _on_answer(self, request: _Request, response: Response, now: float) -> None:
        body = response.body
        purpose = request.purpose
        if purpose is Purpose.CALLER:
            assert request.ticket is not None  # a caller's request has its ticket
            self._finish(request.ticket, response, request.text)
            return
        if purpose is Purpose.QUERY:
            self._on_query(response, now)
            return
        if response.status != wire.OK:
            self.stats.rejects += 1  # noted; the host goes on without it
        if purpose is Purpose.SETUP:
            self._take_identity(body)
            room = _integer(body.get("qr"))
            if room is not None and response.status == wire.OK:
                self._idle_room = room
                self._saw_room(room)
            if request.key == "n":
                self._base = max(0, _integer(body.get("n")) or 0)
            key = request.key or ""
            wanted = SETTINGS_WANTED.get(key)
            if wanted is not None and _integer(body.get(key)) != wanted:
                # The setting did not take as sent (a digit damaged on the way: {jv:5}): set
                # it again, a few times at the most.
                self._setup_retries += 1
                if self._setup_retries > MAX_SETUP_RETRIES:
                    raise PrinterNotResponding(
                        f"the board keeps answering {request.text} with {response.text}")
                return
            self._setup_retries = 0
            self._setup_step += 1
            if self._setup_step == len(SETUP):
                self.phase = Phase.READY
        elif purpose is Purpose.STATUS:
            status = body.get("sr")
            stat = _integer(status.get("stat")) if isinstance(status, Mapping) else None
            if stat is not None:
                self._saw_state(stat, now)
            if stat in HALTED_STATES:
                self._halted_answers += 1
                if self._halted_answers >= 2:  # twice in a row: not a digit damaged
                    self._checking = False
                    raise PrinterHalted(self._halt_message(stat, response.text))
                self._request = _Request(STATUS_REQUEST, Purpose.STATUS, "sr")
                return
            self._halted_answers = 0
            self._check_stat = stat
            if self._checking:
                self._request = _Request(QUEUE_REQUEST, Purpose.QUEUE, "qr")
        elif purpose is Purpose.QUEUE:
            room = _integer(body.get("qr"))
            if room is not None:
                self._saw_room(room)
            self._end_drain_check(room, now)
        elif purpose is Purpose.CANCEL_MARK:
            line = self._line
            if line is not None:
                self._drop(line.ticket)
                self._line = None
            if self.firmware_build is not None and self.firmware_build < 101:
                self._request = _Request(CLEAR_REQUEST, Purpose.CLEAR, None)
            else:
                self._cancelling = False
        elif purpose is Purpose.CLEAR:
            self._cancelling = False

    def _on_query(self, response: Response, now: float) -> None:
        """An answer to LINE_QUERY: settles the line in flight (or a banner) once two in a row
        agree."""
        line, resolution = self._line, self._resolution
        if resolution is None and self._banner is None:
            return  # the line's own answer came meanwhile
        body = response.body
        answer = (_integer(body.get("n")), _integer(body.get("jv")), _integer(body.get("stat")))
        if response.status != wire.OK:
            answer = (None, None, None)  # (no use, and no reason to give up: asked again)
        answers = resolution.answers if resolution is not None else self._check_answers
        answers.append(answer)
        if len(answers) < 2 or answers[-1] != answers[-2] or answer == (None, None, None):
            if len(answers) >= 2 * self.max_transmissions:
                raise PrinterNotResponding(
                    f"the board's answers to {LINE_QUERY} disagree ({len(answers)} of them)"
                )
            if resolution is not None:
                self._ask(resolution)
            else:
                self._request = _Request(LINE_QUERY, Purpose.QUERY, "jv")
            return
        number, jv, stat = answer
        if jv is not None and jv != HOST_JV:
            said = (f"its banner ({self._banner})" if self._banner is not None
                    else "its banner has not reached the host")
            raise PrinterReset(
                f"the board restarted: its jv is {jv}, not the {HOST_JV} the host set ({said}); "
                "what it had queued is gone"
            )
        self._banner = None  # (a greeting: the host's settings are there)
        self._check_answers.clear()
        if stat is not None:
            self._saw_state(stat, now)
            if stat in HALTED_STATES:
                raise PrinterHalted(self._halt_message(stat, response.text))
        if line is None or resolution is None:
            return
        if number == line.number:
            self._done(line, None)  # it ran; its answer was lost
            return
        if not resolution.fenced:
            answers.clear()  # asked early, for a halt reported: the fence's answer settles the rest
            return
        # Not run: the number is the one before it, or 0 (only a piece of it ran, the line cut
        # short or in two on the way), or a line of no one's (garbage with an N word) ran last.
        self._send_again(line)

    def _send_again(self, line: _Line) -> None:
        """The board has not run the line and does not hold it: send it again."""
        if line.transmissions >= self.max_transmissions:
            raise PrinterNotResponding(
                f"line {line.number} ({line.ticket.text!r}) was sent {line.transmissions} times "
                "and never ran"
            )
        self._resolution = None
        if self._request is not None and self._request.purpose is Purpose.QUERY:
            self._request = None  # (its answer, should it come, is passed over)
        line.due = True

    def _end_drain_check(self, room: int | None, now: float) -> None:
        self._checking = False
        if (
            self._check_stat in IDLE_STATES
            and (room is None or room >= self._idle_room)  # (None: a board without qr)
            and self._line is None
            and not self._backlog
        ):
            self._drained = True
        else:
            self._next_drain_check = now + DRAIN_POLL

    def _saw_room(self, room: int) -> None:
        self.room = room
        self._idle_room = max(self._idle_room, room) if self.phase is Phase.READY else self._idle_room

    def _saw_state(self, stat: int, now: float) -> None:
        self.machine_state = stat
        if stat in IDLE_STATES:
            self._next_drain_check = min(self._next_drain_check, now)  # worth asking at once

    def _take_identity(self, body: Mapping[str, object]) -> None:
        build, version = _number(body.get("fb")), _number(body.get("fv"))
        if build is not None:
            self.firmware_build = build
        if version is not None:
            self.firmware_version = version

    def _halt_message(self, stat: int, text: str) -> str:
        return f"the board is in {HALTED_STATES[stat]} (stat {stat}: {text}); it runs nothing until cleared"


def _integer(value: object) -> int | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    if isinstance(value, float) and not value.is_integer():
        return None
    return int(value)


def _number(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return None
    return float(value)
