"""Streaming G-code to a g2core board in "line mode", as a sans-IO state machine.

What the board promises (docs: /tmp/g2core/facts.md, read from g2core's source): it reads a
G-code line only while its planner has at least 4 of its 48 buffers free, and answers every line
it reads with exactly one response, `{"r":{...},"f":[1,<status>,<bytes>]}`, in the order it read
them. A JSON request (`{...}`) is scanned out of the receive ring ahead of any G-code waiting
there and answered at once, so its response may overtake those of lines sent before it. Reports
(`{"sr":...}`, `{"qr":...}`, `{"er":...}`, `{"prb":...}`) carry no footer and answer nothing. The
footer's third element is the length of the line answered, not a count of free buffers: the
board states no room at all, and when its planner is full it simply stops reading.

So the host keeps up to `window` job lines in flight (4 by default, within `RX_BUDGET` bytes of
the board's 1024-byte ring, so that a feedhold `!` always gets in), each `N<k> <gcode>` with k
from 1 and no checksum, and sends one more for each response. A response is the answer of
- the host's own request waiting, if it carries the name asked for (`{"qr":n}` -> `"qr"`);
- else, if it carries a name only the host asks for (a late answer to a request asked again), no
  one's: it is dropped;
- else the oldest line in flight: responses come in order. With `{jv:4}` a line's response
  also carries its `"n"`, which double-checks the match: a response naming a later line in
  flight means the lines before it went unanswered (lost, or their answers were), which is an
  error (PrinterNotResponding): g2core refuses no duplicates, so a line is never sent twice.
A caller's own JSON request goes out only with nothing else in flight, and the next response is
its answer.

Statuses (the footer's second element): 0 is OK; 3 (no operation: a block-delete `/` line) and
4 (completed: M117 and the like on a Marlin-compatible build) are informational: the line is
done. Any other status on a caller's line or request stops the job with CommandFailed, naming
the line, the status and its message (the board's fault, or the file's: the board would not run
it). What the board has already read after it (up to a window's worth) still runs. Statuses of
the host's own requests are noted and passed over (a 100.x board has no `qv`, say).

Connecting: the host sets `{"ej":1}` (JSON; first, so that a board in text mode answers in JSON),
`{"jv":4}` (responses with `n`), `{"qv":0}` (no queue reports: the host asks when it wants
them), `{"sv":1}` (filtered status reports), then reads `{"fb":n}`, `{"fv":n}` (the firmware
build and version) and `{"qr":n}` (the idle planner's free buffers), one at a time, each asked
again after `timeout` of silence, up to `max_transmissions` times. The power-up banner
(`{"r":{"fv":0.99,"fb":101.03,...,"msg":"SYSTEM READY"},"f":[1,0,1]}`) may come at any moment of
this, unasked: it is never an answer (its footer counts 1 byte, which no line can), it gives
the firmware's identity, and as the board resets its communication settings before it, the
settings start again from `{"ej":1}`. A banner after the caller's commands have gone out is a
restart (PrinterReset), except the first banner within GREETING_WINDOW of connecting: a
Marlin-compatible build greets a USB host 2 s after the port opens, and resets only settings
the host sets the same way.

Done-ness: a response means the line was read and planned, not run. The job is done (`idle`,
once the caller asked for that with request_drained()) when every line is answered and then
`{"sr":n}` shows the machine out of any cycle (stat 1 ready, 3 program stop, 4 program end) and
`{"qr":n}` shows the planner as empty as when the host connected. Until then the host asks
again every DRAIN_POLL, at once when the board reports stat 3 or 4 on its own; a stat of 2
(alarm), 12 (shutdown) or 13 (panic) is PrinterHalted. M0 leaves moves queued at stat 3: the job
waits for a resume (`~`).

Silence: while lines are in flight and nothing is heard for `timeout`, the host asks `{"sr":n}`
and `{"qr":n}` (answered even while the planner is full). An answer shows the board is alive, and
the host waits on: lines behind a long move or a feedhold can wait indefinitely. But a board not
in a hold with room to read (qr >= 4) that has not answered a line over STALL_CHECKS such checks
has lost it or its answer: PrinterNotResponding (sending it again could run it twice).

Feedhold (`!`), resume (`~`) and cancel: cancel drops what the caller has not sent, writes ^D
(job kill: the board empties its planner and drops what it has not read) and then a status
request, whose answer marks the point after which no dropped line will be answered; lines
unanswered by then never ran (their tickets are completed unconfirmed, counted as cancelled). On
a 100.x board ^D leaves the machine in alarm, which `{"clear":n}` then clears.
"""

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum, auto

from fake_marlin.host.codecs.g2core import (
    Boot,
    Event,
    Line,
    LineKind,
    Noise,
    Report,
    ReplyReader,
    Response,
    compact,
    encode_line,
    encode_request,
    is_request,
)
from fake_marlin.host.cores.queue import CommandQueue, Ticket
from fake_marlin.host.errors import CommandFailed, PrinterHalted, PrinterNotResponding, PrinterReset
from fake_marlin.wire import g2core as wire

WINDOW = 4  # job lines in flight
RX_BUDGET = 768  # bytes of lines in flight, of the board's 1024-byte RX ring (one line always may go)
DRAIN_POLL = 0.5  # seconds between status requests while the board finishes a job
STALL_CHECKS = 2  # silent checks with room to read and a line unanswered: it was lost
GREETING_WINDOW = 3.0  # s after connecting in which a banner is the connect greeting
INFORMATIONAL = frozenset({wire.NOOP, 4})  # statuses that do not stop a job (4: STAT_COMPLETE)
IDLE_STATES = frozenset({1, 3, 4})  # ready, program stop, program end
HALTED_STATES = {2: "ALARM", 12: "SHUTDOWN", 13: "PANIC"}
HOLD = 6
SETUP = (
    ("ej", '{"ej":1}'),
    ("jv", '{"jv":4}'),
    ("qv", '{"qv":0}'),
    ("sv", '{"sv":1}'),
    ("fb", '{"fb":n}'),
    ("fv", '{"fv":n}'),
    ("qr", '{"qr":n}'),
)
STATUS_REQUEST = '{"sr":n}'
QUEUE_REQUEST = '{"qr":n}'
CLEAR_REQUEST = '{"clear":n}'
# Names in the host's own requests: a line's response never carries them.
HOST_NAMES = frozenset({name for name, _ in SETUP} | {"sr", "qr"})


class Phase(Enum):
    SETUP = auto()  # the host's settings and questions, one at a time
    READY = auto()


class Purpose(Enum):
    SETUP = auto()
    STATUS = auto()  # {"sr":n} of a check
    QUEUE = auto()  # {"qr":n} of a check
    CANCEL_MARK = auto()  # the request after ^D
    CLEAR = auto()  # {"clear":n} after ^D on 100.x
    CALLER = auto()  # a caller's own JSON request


class Check(Enum):
    """Why the host asks for the board's status."""

    KEEPALIVE = auto()  # lines in flight, and the board silent
    DRAIN = auto()  # every line answered: has it run them?


@dataclass(eq=False)
class _Request:
    text: str
    purpose: Purpose
    key: str | None  # the name its answer carries; None: sent alone, the next response is it
    ticket: Ticket | None = None
    sent_at: float | None = None  # None: not (yet, or again) on its way
    transmissions: int = 0
    silences: int = 0  # timeouts waited through (a caller's request is never asked again)


@dataclass(eq=False)
class _Line:
    number: int
    ticket: Ticket
    data: bytes


@dataclass
class G2coreStats:
    packets_sent: int = 0  # lines and JSON requests written (single characters are not counted)
    resends: int = 0  # the host's own requests asked again (job lines never are)
    timeouts: int = 0  # silences: a request unanswered, or lines in flight and nothing heard
    rejects: int = 0  # responses with a status that stops a job, or that refuse the host's request
    unconfirmed: int = 0  # commands completed without their own response: only cancelled ones
    noops: int = 0  # lines answered with an informational status (3, 4)
    requests: int = 0  # the host's own JSON requests written
    reports: int = 0  # reports of the board's own (sr, qr, er, prb...)
    cancelled: int = 0  # commands dropped by cancel() before the board ran them
    mismatches: int = 0  # responses whose "n" named no line in flight (matched in order anyway)


class G2coreCore(CommandQueue):
    def __init__(
        self,
        window: int = WINDOW,
        timeout: float = 2.0,
        max_transmissions: int = 8,
        rx_budget: int = RX_BUDGET,
    ) -> None:
        if window < 1:
            raise ValueError(f"window must be at least 1, not {window}")
        self.window = window  # lines in flight, and commands the caller may queue ahead
        self.timeout = timeout
        self.max_transmissions = max_transmissions
        self.rx_budget = rx_budget
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
        self._lines: deque[_Line] = deque()  # in flight, oldest first
        self._in_flight_bytes = 0
        self._next_number = 1
        self._request: _Request | None = None  # the one JSON request on its way
        self._urgent: list[bytes] = []  # single characters to write before anything else
        self._idle_room = wire.PLANNER_QUEUE_SIZE
        self._started_at: float | None = None  # the first poll: when the host connected
        self._banners = 0
        self._caller_sent = False  # a caller's command has gone out
        self._last_heard = -math.inf  # anything from the board, or a line of ours sent
        self._reader = ReplyReader()
        self._received_at = -math.inf
        # Checks: why one is running, its status answer, silent checks in a row.
        self._check: Check | None = None
        self._check_stat: int | None = None
        self._stalls = 0
        self._answered_since_check = False
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
            and not self._lines
            and not self._cancelling
            and (self._request is None or self._request.purpose is not Purpose.CALLER)
            and (self._drained or not self._want_drained)
        )

    @property
    def in_flight(self) -> int:
        """Job lines sent and not yet answered."""
        return len(self._lines)

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
        self._check = None
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
        self._expire(now)
        if self.phase is Phase.SETUP:
            if self._request is None:
                name, text = SETUP[self._setup_step]
                self._request = _Request(text, Purpose.SETUP, name)
        elif not self._cancelling:
            out += self._send_lines(now)
            if self._request is None and self._check is None and self._drain_due(now):
                self._start_check(Check.DRAIN)
        request = self._request
        if request is not None and request.sent_at is None:
            out.append(self._transmit(request, now))
        return out

    def _send_lines(self, now: float) -> list[bytes]:
        out: list[bytes] = []
        if self._request is not None and self._request.key is None:
            return out  # a request that is sent alone: the next response is its answer
        while self._backlog:
            ticket = self._backlog[0]
            if is_request(ticket.text):
                if self._lines or self._request is not None:
                    break  # alone: its answer may overtake those of lines before it
                self._backlog.popleft()
                self._request = _Request(ticket.text, Purpose.CALLER, None, ticket)
                self._caller_sent = True
                break
            data = encode_line(self._next_number, ticket.text)
            if self._lines and (
                len(self._lines) >= self.window or self._in_flight_bytes + len(data) > self.rx_budget
            ):
                break
            self._backlog.popleft()
            self._lines.append(_Line(self._next_number, ticket, data))
            self._next_number += 1
            self._in_flight_bytes += len(data)
            self._caller_sent = True
            self._drained = False
            self.stats.packets_sent += 1
            self._last_heard = max(self._last_heard, now)
            out.append(data)
        return out

    def _transmit(self, request: _Request, now: float) -> bytes:
        if request.transmissions >= self.max_transmissions:
            raise PrinterNotResponding(
                f"no answer to {request.text} after {request.transmissions} tries; "
                "is a g2core board on the port?"
            )
        self.stats.resends += request.transmissions > 0
        self.stats.packets_sent += 1
        self.stats.requests += request.purpose is not Purpose.CALLER
        request.transmissions += 1
        request.sent_at = now
        self._last_heard = max(self._last_heard, now)
        if request.purpose is Purpose.CALLER:
            self._drained = False
        return encode_request(request.text)

    def next_deadline(self) -> float | None:
        """When to poll again if nothing comes (None: only once something does)."""
        # (What is to be sent at once needs no deadline: whatever makes it due, a line from the
        # board or the caller's submit, wakes the shell to poll.)
        request = self._request
        if request is not None:
            if request.sent_at is None:
                return None
            return request.sent_at + self.timeout * (request.silences + 1)
        if self.phase is not Phase.READY:
            return None
        if self._lines:
            return self._last_heard + self.timeout
        if self._want_drained and not self._drained and not self._backlog and not self._cancelling:
            return None if self._next_drain_check == -math.inf else self._next_drain_check
        return None

    def _drain_due(self, now: float) -> bool:
        return (
            self._want_drained
            and not self._drained
            and not self._backlog
            and not self._lines
            and now >= self._next_drain_check
        )

    def _expire(self, now: float) -> None:
        request = self._request
        if request is not None:
            deadline = self.next_deadline()
            if request.sent_at is not None and deadline is not None and now >= deadline:
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
                    request.sent_at = None  # asked again below
            return
        if self.phase is Phase.READY and self._lines and now >= self._last_heard + self.timeout:
            self.stats.timeouts += 1
            self._start_check(Check.KEEPALIVE)

    def _start_check(self, why: Check) -> None:
        self._check = why
        self._check_stat = None
        self._answered_since_check = False
        self._request = _Request(STATUS_REQUEST, Purpose.STATUS, "sr")

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
        if isinstance(event, Noise):
            self.corrupt_frames += event.damaged
            return Line(LineKind.NOISE, event.text)
        self._last_heard = max(self._last_heard, now)
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
                if stat in HALTED_STATES and self._lines and not self._cancelling:
                    raise PrinterHalted(self._halt_message(stat, report.text))
        return Line(kind, report.text, body)

    def _on_boot(self, boot: Boot, now: float) -> Line:
        self._banners += 1
        self._take_identity(boot.body)
        greeting = (
            self._banners == 1
            and self._started_at is not None
            and now - self._started_at <= GREETING_WINDOW
        )
        if self._caller_sent and not greeting:
            raise PrinterReset(
                f"the board restarted ({boot.text}); what it had queued is gone"
            )
        if not self._caller_sent:
            # Before the caller's first command: its communication settings were just reset,
            # so the host's start again (a late answer to one asked before is passed over).
            # Nothing of the caller's was on the board either, so a cancel has nothing left to do.
            self.phase = Phase.SETUP
            self._setup_step = 0
            self._request = None
            self._check = None
            self._cancelling = False
        return Line(LineKind.BOOT, boot.text, boot.body)

    def _on_response(self, response: Response, now: float) -> Line | None:
        request = self._request
        body = response.body
        if request is not None and request.sent_at is not None and (
            request.key is None or request.key in body
        ):
            self._request = None
            self._on_answer(request, response, now)
            return None
        if body.keys() & HOST_NAMES:
            return None  # a late answer to a request of the host's asked again
        if self._lines:
            self._on_line_answer(response)
            return None
        return Line(LineKind.RESPONSE, response.text, body)

    def _on_line_answer(self, response: Response) -> None:
        number = _integer(response.body.get("n"))
        head = self._lines[0]
        if number is not None and number != head.number:
            later = [line for line in self._lines if line.number == number]
            if later:
                missing = f"{head.number}" if number == head.number + 1 else f"{head.number}-{number - 1}"
                raise PrinterNotResponding(
                    f"the board answered line {number} before line(s) {missing}: those lines "
                    "or their answers were lost, and g2core cannot say which (nothing is sent twice)"
                )
            self.stats.mismatches += 1
        self._lines.popleft()
        self._in_flight_bytes -= len(head.data)
        self._answered_since_check = True
        self._stalls = 0
        self._finish(head.ticket, response, f"line {head.number} ({head.ticket.text!r})")

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
        status = response.status
        message = wire.STATUS_MESSAGES.get(status, "a status g2core does not list")
        said = response.body.get("msg")
        detail = f": {said}" if isinstance(said, str) and said and said != message else ""
        return f"the board refused {what}: status {status} ({message}){detail}"

    def _on_answer(self, request: _Request, response: Response, now: float) -> None:
        body = response.body
        purpose = request.purpose
        if purpose is Purpose.CALLER:
            assert request.ticket is not None  # a caller's request has its ticket
            self._finish(request.ticket, response, request.text)
            return
        if response.status != wire.OK:
            self.stats.rejects += 1  # noted; the host goes on without it
        if purpose is Purpose.SETUP:
            self._take_identity(body)
            room = _integer(body.get("qr"))
            if room is not None and response.status == wire.OK:
                self._idle_room = room
                self._saw_room(room)
            self._setup_step += 1
            if self._setup_step == len(SETUP):
                self.phase = Phase.READY
        elif purpose is Purpose.STATUS:
            status = body.get("sr")
            stat = _integer(status.get("stat")) if isinstance(status, Mapping) else None
            if stat is not None:
                self._saw_state(stat, now)
                if stat in HALTED_STATES:
                    self._check = None
                    raise PrinterHalted(self._halt_message(stat, response.text))
            self._check_stat = stat
            if self._check is Check.KEEPALIVE and stat == HOLD:
                self._check = None  # held: the lines wait for resume()
            elif self._check is not None:
                self._request = _Request(QUEUE_REQUEST, Purpose.QUEUE, "qr")
        elif purpose is Purpose.QUEUE:
            room = _integer(body.get("qr"))
            if room is not None:
                self._saw_room(room)
            self._end_check(room, now)
        elif purpose is Purpose.CANCEL_MARK:
            for line in self._lines:
                self._drop(line.ticket)
            self._lines.clear()
            self._in_flight_bytes = 0
            if self.firmware_build is not None and self.firmware_build < 101:
                self._request = _Request(CLEAR_REQUEST, Purpose.CLEAR, None)
            else:
                self._cancelling = False
        elif purpose is Purpose.CLEAR:
            self._cancelling = False

    def _end_check(self, room: int | None, now: float) -> None:
        why, self._check = self._check, None
        if why is Check.DRAIN:
            if (
                self._check_stat in IDLE_STATES
                and (room is None or room >= self._idle_room)  # (None: a board without qr)
                and not self._lines
                and not self._backlog
            ):
                self._drained = True
            else:
                self._next_drain_check = now + DRAIN_POLL
        elif why is Check.KEEPALIVE and self._lines and not self._answered_since_check:
            if room is not None and room >= wire.PLANNER_HEADROOM:
                self._stalls += 1
                if self._stalls >= STALL_CHECKS:
                    head = self._lines[0]
                    raise PrinterNotResponding(
                        f"line {head.number} ({head.ticket.text!r}) has had no answer for "
                        f"{self._stalls} checks while the board had room to read it "
                        f"(qr {room}): the line or its answer was lost, and g2core cannot say "
                        "which (nothing is sent twice)"
                    )

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
