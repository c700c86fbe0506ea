"""One boot of a g2core board speaking its JSON protocol (docs/protocols.md section 7).

The board answers every line once: a control (`{...}`) at once, ahead of queued G-code; a data
line as it is read, which happens only while the planner has PLANNER_HEADROOM buffers free, no
feedhold blocks it and no command of the line before is still waiting. It says the status
report's changed fields every `si` ms while they change (sv 1; all of them with sv 2), and the
free planner buffers (`qr`) whenever they change, at `qv` 1 or 2.
"""

import math
from collections.abc import Callable, Iterable
from enum import Enum

import trio

from fake_marlin.emulator.firmware import Firmware
from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.printer import g2core as board
from fake_marlin.emulator.printer import motion
from fake_marlin.emulator.printer.g2core import BoardState, BoardView, Build, MachineState
from fake_marlin.emulator.printer.gcode import parse
from fake_marlin.emulator.printer.model import Printer, Reply
from fake_marlin.emulator.printer.statements import Statement
from fake_marlin.emulator.protocols.base import CommandReceived
from fake_marlin.emulator.protocols.g2core import (
    BadLine,
    BadRequest,
    G2coreProtocol,
    JsonRequest,
    find_end,
    Report,
    Response,
    SingleCharacter,
)
from fake_marlin.emulator.sessions.base import Session
from fake_marlin.emulator.sessions.driver import CommandRun, finish
from fake_marlin.wire import g2core
from fake_marlin.wire.g2core import Number, OutValue

# The Marlin codes that only a Marlin host sends (seed 001's canaries): g2core's Marlin
# compatibility (gcode_parser.cpp:1127-1200) switches the connection to Marlin's protocol.
CANARIES = frozenset({"M105", "M108", "M110", "M114", "M115"})
# controller.cpp:340-366: the banner 2 s after a USB connect on a build with Marlin
# compatibility (10 ms without), time for a Marlin host to show itself first.
BANNER_DELAY = 2.0
PROGRAM_END = frozenset({"M2", "M30"})
MOTION_MODES = {"G0": 0, "G1": 1, "G2": 2, "G3": 3}  # `momo` (gcode.h)
# Seed 001's lightning codes: Marlin's G-code meanings from then on (an `E` word too).
FLAVOUR_CODES = frozenset({"M82", "M83", "M104", "M109", "M140", "M190", "M106", "M107", "G29"})
# g2core's codes that set a mode or a spindle/coolant output and move nothing, which the printer
# model (Marlin's codes) lacks or means otherwise (M30 deletes an SD file there): taken, in order,
# as they come (gcode_parser.cpp:677-846).
MODAL_ONLY = frozenset({
    "G17", "G18", "G19", "G20", "G21", "G40", "G43", "G49", "G54", "G55", "G56", "G57", "G58",
    "G59", "G61", "G64", "G80", "G93", "G94", "G95", "M2", "M3", "M4", "M5", "M7", "M8", "M9",
    "M30", "M48", "M49", "M50", "M51", "M60",
})


class Flavour(Enum):
    """The G-code's meaning, switched apart from the protocol (seed 001's lightning codes)."""

    G2CORE = "g2core"
    MARLIN = "marlin"


class G2coreSession:
    def __init__(
        self,
        printer: Printer,
        journal: Journal,
        send: Callable[[bytes], None],
        before_command: Callable[[str], None] = lambda text: None,
        firmware: Firmware | None = None,
        restart: Callable[[str], None] = lambda reason: None,
        build: Build | None = None,
        marlin: Callable[[], Session] | None = None,
    ) -> None:
        self.printer = printer
        self.journal = journal
        self._send = send
        self._before_command = before_command
        self.firmware = firmware or Firmware.make("g2core")
        self._restart = restart
        self.build = build or Build()
        self.protocol = G2coreProtocol()
        self.state = BoardState()
        self._waiting: tuple[CommandRun, float] | None = None  # a command that waits for time
        self._work = trio.Event()
        self._changed = trio.Event()  # the planner or the state changed: reports may be due
        self._resetting = False
        self._last_room: int | None = None
        self._make_marlin = marlin
        self._marlin: Session | None = None  # the Marlin session a canary handed the line to
        self._marlin_started = trio.Event()
        self._marlin_scope = trio.CancelScope()
        self._sr_requested = False  # report.cpp: a line read, a cycle's end, motion
        self.flavour = Flavour.G2CORE
        self._banner_at: float | None = None  # when the banner is due
        self._banner_due = trio.Event()

    # -- what a session is ------------------------------------------------------------------
    def boot(self) -> None:
        """The board starts, or a host opens its USB port: its banner in BANNER_DELAY, unless a
        Marlin host has spoken by then (report.cpp:113-120)."""
        self._banner_at = trio.current_time() + BANNER_DELAY
        self._banner_due.set()

    def _say_banner(self) -> None:
        view = self._view()
        body: dict[str, OutValue] = {name: board.READ[name](view)
                                     for name in ("fv", "fb", "fbs", "fbc", "hp", "hv", "id")}
        body["msg"] = "SYSTEM READY"
        self._respond(body, g2core.OK, 1)

    def feed(self, data: bytes) -> None:
        if self._marlin is not None:
            self._feed_marlin(data)
            return
        if self._resetting:
            return
        self.protocol.receive_data(data)
        self._read()

    def _feed_marlin(self, data: bytes) -> None:
        """A connection in Marlin's protocol: a `{...}` line is still g2core's JSON, answered
        in JSON (controller.cpp dispatches it before Marlin's mode); the rest is Marlin's."""
        held = self._marlin_held + data
        passed = bytearray()
        start = 0
        while (end := find_end(held, start)) is not None:
            line = held[start:end + 1]
            if line.lstrip()[:1] == b"{":
                self._marlin_json(bytes(passed), line)
                passed.clear()
            else:
                passed += line
            start = end + 1
        rest = held[start:]
        self._marlin_held = rest if rest.lstrip()[:1] == b"{" else b""
        if not self._marlin_held:
            passed += rest
        if passed and self._marlin is not None:
            self._marlin.feed(bytes(passed))

    def _marlin_json(self, before: bytes, line: bytes) -> None:
        if before and self._marlin is not None:
            self._marlin.feed(before)
        json_lines = G2coreProtocol()
        json_lines.receive_data(line)
        while (event := json_lines.next_event()) is not None:
            if isinstance(event, JsonRequest):
                self._json(event)
            elif isinstance(event, BadRequest):
                self._respond({}, event.status, event.size)

    _marlin_held = b""

    async def run(self) -> None:
        while True:
            async with trio.open_nursery() as nursery:
                nursery.start_soon(self._execute)
                nursery.start_soon(self._report)
                nursery.start_soon(self._banner)
                await self._marlin_started.wait()
                nursery.cancel_scope.cancel()  # Marlin's protocol from now on: its session runs
            assert self._marlin is not None
            with self._marlin_scope:
                await self._marlin.run()
            # The port was opened again (announce): the new connection is g2core's again.
            self._marlin_scope = trio.CancelScope()

    def announce(self, statements: Iterable[Statement]) -> None:
        """What the firmware says on its own: the banner to a host that opens the port (10 ms
        after a USB connect, controller.cpp:340-366), which ends a Marlin host's connection's
        Marlin mode; an error as an exception report (or in Marlin's words, to a Marlin host)."""
        statements = tuple(statements)
        if any(statement.key == "connected" for statement in statements):
            if self._marlin is not None:
                self._marlin_scope.cancel()  # run() starts g2core's tasks again
                self._marlin, self._marlin_started = None, trio.Event()
                self.protocol = G2coreProtocol()
                self._waiting = None
                self.flavour = Flavour.G2CORE
            self.boot()
            statements = tuple(statement for statement in statements
                               if statement.key != "connected")
        if self._marlin is not None:
            self._marlin.announce(statements)
            return
        alarm = self.printer.halted and self.state.stat is not MachineState.ALARM
        if alarm:  # a kill (a thermal fault): g2core's alarm, until {clear:n} (alarm.cpp)
            self.state.stat = MachineState.ALARM
            self._sr_requested = True
            self._changed.set()
        for line in self.firmware.words.lines(statements):
            if alarm or line.startswith("Error:") or line.startswith("!!"):
                status, kind = (18, "System alarm") if alarm else (200, "Generic error")
                self._say(Report("er", {"fb": Number(self.build.fb, 2), "st": status,
                                        "msg": f"{kind} - {line}"}))
                alarm = False

    def block_queue(self, seconds: float, nursery: trio.Nursery) -> None:
        async def hold() -> None:
            self._blocked = True
            await trio.sleep(seconds)
            self._blocked = False
            self._read()
        nursery.start_soon(hold)

    _blocked = False
    _held_since = 0.0
    _after_wait: Callable[[], object] | None = None  # M100's JSON, run when its wait ends
    _home_position = (0.0, 0.0, 0.0)  # G28.1's, where g2core's G28 goes
    _program_ends = False  # an M2/M30 read, waiting for the moves before it

    # -- reading ----------------------------------------------------------------------------
    def _can_read_gcode(self) -> bool:
        return (self._waiting is None and not self._blocked
                and self.state.stat is not MachineState.HOLD
                and self.printer.room(trio.current_time()) >= g2core.PLANNER_HEADROOM)

    def _read(self) -> None:
        protocol = self.protocol
        protocol.reading_gcode = self._can_read_gcode()
        while not self._resetting and self._marlin is None and (
                event := protocol.next_event()) is not None:
            if isinstance(event, JsonRequest):
                self._json(event)
            elif isinstance(event, SingleCharacter):
                self._single(event.byte)
            elif isinstance(event, BadRequest):
                body: dict[str, OutValue] = {}
                if event.status == g2core.JSON_SYNTAX_ERROR and self.state.settings.jv >= 2:
                    body["err"] = event.text
                self._respond(body, event.status, event.size)
            elif isinstance(event, BadLine):
                self._respond({}, event.status, event.size)
            elif isinstance(event, CommandReceived):
                self._gcode(event)
            protocol.reading_gcode = self._can_read_gcode()
            self._sr_requested = True  # every line read asks for a (timed) report
        self._changed.set()

    def _json(self, request: JsonRequest) -> None:
        body, status = board.answer(self._view(), request.pairs)
        if self.state.settings.jv < 2:
            body.pop("msg", None)
        self._respond(body, status, request.size)

    def _single(self, byte: int) -> None:
        state = self.state
        if byte == g2core.ENQ:
            self._send(b'{"ack":true}\n')
        elif byte == g2core.RESET:
            self._resetting = True
            self._restart(" ^X")
        elif byte == g2core.FEEDHOLD:
            if state.stat in (MachineState.RUN, MachineState.HOMING):
                state.stat = MachineState.HOLD
                self._sr_requested = True
                self._held_since = trio.current_time()
                self.printer.planner.hold(self._held_since)
        elif byte == g2core.CYCLE_START:
            if state.stat is MachineState.HOLD:
                self.printer.planner.release(trio.current_time(), self._held_since)
                state.stat = MachineState.RUN
                self._work.set()
        elif byte == g2core.QUEUE_FLUSH:
            if state.stat is MachineState.HOLD:  # a control only while a hold exists
                self.protocol.discard_data()
                motion.quickstop(self.printer, trio.current_time())  # stopped where it is
                state.stat = MachineState.PROGRAM_STOP
        elif byte == g2core.KILL_JOB:
            if state.stat not in (MachineState.ALARM, MachineState.SHUTDOWN, MachineState.PANIC):
                self.protocol.discard_data()
                motion.quickstop(self.printer, trio.current_time())  # stopped where it is
                for heater in (*self.printer.hotends, self.printer.bed):
                    heater.set_target(trio.current_time(), 0.0)
                state.stat = MachineState.PROGRAM_END
                self._say(Report("er", {"fb": Number(self.build.fb, 2), "st": 207,
                                        "msg": "Kill job - Job killed by ^d"}))
        self._changed.set()

    def _gcode(self, received: CommandReceived) -> None:
        line = normalize_gcode(received.text)
        code = parse(line).code if line else ""
        if code in CANARIES and self._make_marlin is not None:
            self._hand_to_marlin(received)
            return
        if code in FLAVOUR_CODES or _has_word(line, "E"):
            self.flavour = Flavour.MARLIN  # from this line on, Marlin's meanings
        text, json_after = _to_model(self, line)
        model_code = parse(text).code if text else ""
        if (text and code not in MODAL_ONLY and code != "G4" and model_code[:1] in ("G", "M")
                and model_code not in self.printer.handlers):
            # gcode_parser.cpp:677-846: refused as it is parsed, before its line number is
            # taken (929-930), so it never runs and its answer has no `n`
            self._respond({}, g2core.MCODE_UNSUPPORTED if model_code[0] == "M"
                          else g2core.GCODE_COMMAND_UNSUPPORTED, received.size)
            return
        if received.number is not None:
            self.state.line = received.number
        if self.state.stat is MachineState.ALARM:  # alarm.cpp:106-112: refused, not run
            self._respond({}, g2core.ALARMED, received.size)
            return
        body: dict[str, OutValue] = {}
        jv = self.state.settings.jv
        if jv >= 5:
            body["gc"] = received.text
        if jv >= 4 and received.number:
            body["n"] = received.number
        if line.startswith("M100.1"):  # its JSON at once, answered as a request is
            answer, status = board.answer(self._view(), json_after)
            body.update(answer)
            self._respond(body, status, received.size)
            return
        if not text:  # a comment, a blank line
            self._respond(body, g2core.OK, received.size)
            return
        executed = received.text.split(";", 1)[0].strip()  # what the journal says ran
        if code == "G4":
            self._dwell(parse(text), executed, body, received.size)
            return
        if code in MODAL_ONLY:
            self._before_command(received.text)
            self.journal.record(executed)
            self._respond(body, g2core.OK, received.size)
            if code in PROGRAM_END:
                self._program_ends = True  # once the moves before it are done (it is queued)
            return
        self._before_command(received.text)
        if self.printer.halted:  # a fault on this very line: alarmed before it ran
            self._respond({}, g2core.ALARMED, received.size)
            return
        run = CommandRun(self.printer, text, self.journal, lambda statement: None,
                         recorded=executed)
        until = run.advance()
        if json_after:  # M100's JSON, in order with the moves: once the ones before it are done
            self._after_wait = lambda: board.answer(self._view(), json_after)
            if until is None:
                self._after_wait()
                self._after_wait = None
        status = _status(run.reply, code)
        self._respond(body, status, received.size)
        if model_code in MOTION_MODES and status == g2core.OK:
            self.state.motion_mode = MOTION_MODES[model_code]
        if self.printer.planner.moves(trio.current_time()):
            self.state.stat = MachineState.RUN
        if until is not None:
            self._waiting = (run, until)
            self._work.set()

    def _dwell(self, command, executed: str, body: dict[str, OutValue], size: int) -> None:
        """G4 P<seconds> (g2core's P is seconds, canonical_machine.cpp:1283): a planner buffer
        of its own, queued behind the moves; the lines after it are read on (planner.cpp:427)."""
        self._before_command(executed)
        seconds = command.value("P", command.value("S", 0.0))
        seconds = min(max(0.0, seconds), 1e6) if seconds == seconds else 0.0
        now = trio.current_time()
        here = tuple(self.printer.motion.position)
        self.printer.planner.add(now, seconds, here, here)
        self.journal.record(executed)
        self._respond(body, g2core.OK, size)
        self.state.stat = MachineState.RUN

    def _hand_to_marlin(self, received: CommandReceived) -> None:
        """A Marlin host showed itself: Marlin's protocol from this line until the port closes."""
        assert self._make_marlin is not None
        marlin = self._marlin = self._make_marlin()
        marlin.boot()
        self._marlin_started.set()
        marlin.feed(self.protocol.last_line + b"\n" + self.protocol.take_unread())


    # -- its own time -----------------------------------------------------------------------
    async def _banner(self) -> None:
        while True:
            due = self._banner_due = trio.Event()
            if self._banner_at is not None:
                with trio.move_on_at(self._banner_at):
                    await due.wait()
                    continue
                self._banner_at = None
                if self._marlin is None and not self._resetting:
                    self._say_banner()
            await due.wait()

    async def _execute(self) -> None:
        while True:
            if self._waiting is not None:
                run, until = self._waiting
                await finish(run, until)
                self._waiting = None
                if self._after_wait is not None:
                    self._after_wait()
                    self._after_wait = None
                self._read()
            work = self._work = trio.Event()
            await work.wait()

    async def _report(self) -> None:
        """Status and queue reports, as report.cpp times them."""
        while self._marlin is None:
            now = trio.current_time()
            view = self._view()
            moving = bool(self.printer.planner.moves(now))
            if self._waiting is None and not moving and self._program_ends:
                self._program_ends = False
                self.state.stat = MachineState.PROGRAM_END  # M2/M30, reached
                self._sr_requested = True
            elif self._waiting is None and not moving and (
                    self.state.stat in (MachineState.RUN, MachineState.HOMING)):
                self.state.stat = MachineState.PROGRAM_STOP  # the cycle's end
                self._sr_requested = True
            self._queue_report(view)
            if self._sr_requested or (moving and self.state.stat is not MachineState.HOLD):
                self._sr_requested = False
                self._status_report(view)
            self._read()  # room may have opened for the next line
            changed = self._changed = trio.Event()
            wake = self.printer.next_room_change(now)
            interval = self.state.settings.si / 1000
            with trio.move_on_at(min(wake if wake is not None else math.inf, now + interval)):
                await changed.wait()
                await trio.sleep(0)

    def _queue_report(self, view: BoardView) -> None:
        """`{"qr":N}` (qv 1) or `{"qr":N,"qi":in,"qo":out}` (qv 2) when the free buffers change."""
        last, self._last_room = self._last_room, view.room
        if last is None or last == view.room or not self.state.settings.jv:
            return
        qv = self.state.settings.qv
        if qv == 1:
            self._say(Report("qr", view.room))
        elif qv == 2:
            self._send(g2core.dumps({"qr": view.room, "qi": max(0, last - view.room),
                                     "qo": max(0, view.room - last)}).encode() + b"\n")

    def _status_report(self, view: BoardView) -> None:
        sv = self.state.settings.sv
        if not sv:
            return
        fields = board.status_report(view) if sv == 2 else board.changed_fields(view)
        if fields:
            self.state.last_sr.update(board.status_report(view))
            self._say(Report("sr", fields))

    # -- saying -----------------------------------------------------------------------------
    def _view(self) -> BoardView:
        now = trio.current_time()
        return BoardView(self.printer, self.state, self.build, now, self.printer.room(now))

    def _respond(self, body: dict[str, OutValue], status: int, size: int) -> None:
        jv = self.state.settings.jv
        if jv == 0 or (jv == 6 and status == g2core.OK):
            return
        self._say(Response(body, status, size))

    def _say(self, event: Response | Report) -> None:
        self._send(self.protocol.send(event))


def _status(reply: Reply, code: str) -> int:
    """The footer status of a data line the model ran."""
    for statement in reply.lines:
        if statement.key == "unknown_command":
            return g2core.MCODE_UNSUPPORTED if code.startswith("M") else (
                g2core.GCODE_COMMAND_UNSUPPORTED)
    return g2core.OK


def normalize_gcode(text: str) -> str:
    """A data line as g2core's parser first reads it (gcode_parser.cpp:320-420): comments go (the
    active `({...})` one stays, for M100/M101), `;` ends it, upper case."""
    line = text.split(";", 1)[0]
    out: list[str] = []
    depth = 0
    active = ""
    for index, char in enumerate(line):
        if char == "(":
            if depth == 0 and line[index + 1:index + 2] == "{":
                active = line[index + 1:line.find(")", index) if ")" in line[index:] else None]
            depth += 1
        elif char == ")":
            depth = max(0, depth - 1)
        elif not depth:
            out.append(char)
    body = "".join(out).strip().upper()
    return f"{body} ({active})" if active else body


def _has_word(line: str, letter: str) -> bool:
    head = line.split("(", 1)[0]
    return letter in head


def _active_json(line: str) -> dict[str, g2core.JsonValue]:
    start = line.find("({")
    if start < 0:
        return {}
    try:
        return g2core.parse_request(line[start + 1:line.rfind(")")])
    except g2core.RelaxedJsonError:
        return {}


def _to_model(self: "G2coreSession", line: str) -> tuple[str, dict[str, g2core.JsonValue]]:
    """A normalized line in the printer model's words, and M100's JSON to run after it: G28.2
    homes, G28.3 sets the origin, G28.1 keeps the position that g2core's G28 goes to (Marlin's
    G28 homes, once the flavour is Marlin's), A is the first extruder's axis (E), M6 takes the
    tool already selected, M100 runs its JSON when the moves before it are done, M101 waits
    for a heater at temperature."""
    if not line:
        return "", {}
    head = line.split("(", 1)[0].replace(" ", "")
    code = parse(head).code
    if head.startswith("G28.2"):
        return "G28" + _axis_words(head[5:], drop_values=True), {}
    if head.startswith("G28.3"):
        return "G92" + _axis_words(head[5:]), {}
    if head.startswith("G28.1"):
        x, y, z = self.printer.motion.position[:3]  # the model's (planned) position
        self._home_position = (x, y, z)
        return "M400", {}
    if code == "G28" and self.flavour is Flavour.G2CORE:
        x, y, z = self._home_position
        return f"G0 X{x:.3f} Y{y:.3f} Z{z:.3f}", {}  # g2core's G28: to the G28.1 position
    if head.startswith("G38."):  # a probe that meets the surface at its target (101.03
        return "G1" + _axis_words(head[5:]), {}  # sends no probe report)
    if code == "G53":  # machine coordinates, which are the model's (it has no work offsets)
        return head[3:] or "M400", {}
    if code == "G10":
        return "M400", {}  # offsets and the tool table: taken, not applied (docs: 7.14)
    if code == "M6":
        return "M400", {}  # the tool change is queued, and no more
    if head.startswith("M100.1"):
        return "", _active_json(line)
    if code == "M100":
        return "M400", _active_json(line)
    if code == "M101":
        waits = [name for name, value in _active_json(line).items()
                 if value is True and name.startswith("he") and name.endswith("at")]
        if waits:
            heater = waits[0][2]
            target = (self.printer.bed if heater == "3" else self.printer.hotends[0]).target
            return (f"M190 S{target:.1f}" if heater == "3" else f"M109 S{target:.1f}"), {}
        return "M400", {}
    return head.replace("A", "E") if "E" not in head else head, {}


def _axis_words(words: str, drop_values: bool = False) -> str:
    parts: list[str] = []
    current = ""
    for char in words:
        if char.isalpha():
            if current:
                parts.append(current)
            current = char
        else:
            current += char
    if current:
        parts.append(current)
    if drop_values:
        return "".join(f" {part[0]}" for part in parts)
    return "".join(f" {part}" for part in parts)
