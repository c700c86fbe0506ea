"""The printer: state, and a dispatch table from G-code to handlers.

execute() is a generator: it yields Sleep(until) when a command must wait for simulated time
(a full planner, a dwell, homing) and Report(text) for lines printed while it waits; the value
sent back in is the new current time. It returns the Reply for the command. Whoever drives it
(the trio session, or a test) owns the clock.
"""

import math
from collections.abc import Callable, Generator
from dataclasses import dataclass, field

from emulator.printer import gcode
from emulator.printer.planner import Planner, move_time
from emulator.printer.thermal import BED, HOTEND, Heater

AXES = "XYZE"


@dataclass(frozen=True)
class Sleep:
    until: float


@dataclass(frozen=True)
class Report:
    text: str


@dataclass(frozen=True)
class Reply:
    lines: tuple[str, ...] = ()
    ok_suffix: str = ""  # text Marlin prints on the `ok` line itself (M105's temperatures)

    def response_data(self) -> tuple[str, ...]:
        """Everything the command printed, one line each (for protocols without `ok` lines)."""
        return self.lines + ((self.ok_suffix,) if self.ok_suffix else ())


Step = Generator[Sleep | Report, float, Reply]


@dataclass(frozen=True)
class PrinterConfig:
    extruders: int = 1
    acceleration: float = 3000.0  # mm/s^2
    junction_speed: float = 10.0  # mm/s, what a move may enter and leave at
    max_feedrate: tuple[float, float, float, float] = (300.0, 300.0, 40.0, 45.0)  # mm/s
    steps_per_mm: tuple[float, float, float] = (80.0, 80.0, 400.0)
    homing_feedrate: tuple[float, float, float] = (50.0, 50.0, 10.0)  # mm/s
    default_feedrate: float = 1500.0  # mm/min until the first F word


@dataclass
class MotionState:
    position: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])
    feedrate: float = 1500.0  # mm/min
    relative: bool = False
    relative_e: bool = False


class Printer:
    def __init__(self, config: PrinterConfig | None = None, now: float = 0.0) -> None:
        self.config = config or PrinterConfig()
        self.planner = Planner()
        self.hotends = [Heater(HOTEND, now) for _ in range(self.config.extruders)]
        self.bed = Heater(BED, now)
        self.motion = MotionState(feedrate=self.config.default_feedrate)
        self.active_tool = 0
        self._handlers: dict[str, Callable[[gcode.Command, float], Reply | Step]] = {
            "G0": self._move,
            "G1": self._move,
            "G4": self._dwell,
            "G28": self._home,
            "G90": self._absolute,
            "G91": self._relative,
            "G92": self._set_position,
            "M82": self._absolute_e,
            "M83": self._relative_e,
            "M104": self._set_hotend,
            "M105": self._report_temperatures,
            "M114": self._report_position,
            "M140": self._set_bed,
            "M400": self._finish_moves,
        }

    def reset(self, now: float) -> None:
        """What a reset does: motion forgotten, heaters off (but still as hot as they are)."""
        self.planner.clear()
        self.motion = MotionState(feedrate=self.config.default_feedrate)
        self.active_tool = 0
        for heater in (*self.hotends, self.bed):
            heater.set_target(now, 0.0)

    # -- the interface the sessions use ------------------------------------------------
    def room(self, now: float) -> int:
        return self.planner.room(now)

    def next_room_change(self, now: float) -> float | None:
        return self.planner.next_change(now)

    def execute(self, line: str, now: float) -> Step:
        command = gcode.parse(line)
        if not command.text:
            return Reply()
        handler = self._handlers.get(command.code)
        if handler is None:
            return Reply((f'echo:Unknown command: "{command.text}"',))
        outcome = handler(command, now)
        if isinstance(outcome, Generator):
            outcome = yield from outcome
        return outcome

    # -- motion ------------------------------------------------------------------------
    def _move(self, command: gcode.Command, now: float) -> Step:
        motion = self.motion
        if command.has("F") and command.value("F", 0.0) > 0:
            motion.feedrate = command.value("F")
        start = tuple(motion.position)
        target = list(start)
        for index, axis in enumerate(AXES):
            value = command.value(axis)
            if value is None:
                continue
            relative = motion.relative_e if axis == "E" else motion.relative
            target[index] = start[index] + value if relative else value
        duration = self._move_duration(start, target, motion.feedrate / 60.0)
        while self.planner.room(now) == 0:
            now = yield Sleep(self.planner.next_change(now))
        if duration > 0:
            self.planner.add(now, duration, start, tuple(target))
        motion.position = target
        return Reply()

    def _move_duration(self, start, target, speed: float) -> float:
        deltas = [abs(b - a) for a, b in zip(start, target)]
        distance = math.hypot(*deltas[:3]) or deltas[3]
        if distance == 0:
            return 0.0
        # Slow the whole move so that no axis exceeds its own limit.
        for delta, limit in zip(deltas, self.config.max_feedrate):
            if delta > 0:
                speed = min(speed, limit * distance / delta)
        return move_time(distance, speed, self.config.acceleration, self.config.junction_speed)

    def _dwell(self, command: gcode.Command, now: float) -> Step:
        seconds = command.value("S", 0.0) + command.value("P", 0.0) / 1000.0
        now = yield from self._synchronize(now)
        if seconds > 0:
            yield Sleep(now + seconds)
        return Reply()

    def _finish_moves(self, command: gcode.Command, now: float) -> Step:
        yield from self._synchronize(now)
        return Reply()

    def _synchronize(self, now: float) -> Generator[Sleep, float, float]:
        drained = self.planner.drained_at(now)
        if drained > now:
            now = yield Sleep(drained)
        return now

    def _home(self, command: gcode.Command, now: float) -> Step:
        now = yield from self._synchronize(now)
        named = [axis for axis in "XYZ" if command.has(axis)]
        axes = named or ["X", "Y", "Z"]
        seconds = 0.0
        for axis in axes:
            index = "XYZ".index(axis)
            # Fast approach from wherever it is, then a bump and a slow second touch.
            travel = max(abs(self.motion.position[index]), 10.0) + 5.0
            seconds += travel / self.config.homing_feedrate[index] + 0.5
            self.motion.position[index] = 0.0
        yield Sleep(now + seconds)
        return Reply()

    def _absolute(self, command: gcode.Command, now: float) -> Reply:
        self.motion.relative = self.motion.relative_e = False
        return Reply()

    def _relative(self, command: gcode.Command, now: float) -> Reply:
        self.motion.relative = self.motion.relative_e = True
        return Reply()

    def _absolute_e(self, command: gcode.Command, now: float) -> Reply:
        self.motion.relative_e = False
        return Reply()

    def _relative_e(self, command: gcode.Command, now: float) -> Reply:
        self.motion.relative_e = True
        return Reply()

    def _set_position(self, command: gcode.Command, now: float) -> Reply:
        named = [axis for axis in AXES if command.has(axis)]
        for axis in named or AXES:
            self.motion.position[AXES.index(axis)] = command.value(axis, 0.0)
        return Reply()

    def _report_position(self, command: gcode.Command, now: float) -> Reply:
        x, y, z, e = self.motion.position
        stepper = self.planner.stepper_position(now, tuple(self.motion.position))
        counts = " ".join(
            f"{axis}:{round(value * steps)}"
            for axis, value, steps in zip("XYZ", stepper, self.config.steps_per_mm)
        )
        return Reply((f"X:{x:.2f} Y:{y:.2f} Z:{z:.2f} E:{e:.2f} Count {counts}",))

    # -- temperature -------------------------------------------------------------------
    def _tool(self, command: gcode.Command) -> int | None:
        tool = command.value("T")
        tool = self.active_tool if tool is None else int(tool)
        return tool if 0 <= tool < len(self.hotends) else None

    def _set_hotend(self, command: gcode.Command, now: float) -> Reply:
        tool = self._tool(command)
        if tool is None:
            return Reply((f"echo:Invalid extruder {int(command.value('T'))}",))
        if command.has("S"):
            self.hotends[tool].set_target(now, command.value("S", 0.0))
        return Reply()

    def _set_bed(self, command: gcode.Command, now: float) -> Reply:
        if command.has("S"):
            self.bed.set_target(now, command.value("S", 0.0))
        return Reply()

    def temperature_report(self, now: float) -> str:
        """Marlin's temperature line: `T:21.00 /0.00 B:21.00 /0.00 @:0 B@:0`."""
        active = self.hotends[self.active_tool]
        parts = [f"T:{active.temperature(now):.2f} /{active.target:.2f}"]
        parts.append(f"B:{self.bed.temperature(now):.2f} /{self.bed.target:.2f}")
        if len(self.hotends) > 1:
            parts += [
                f"T{index}:{heater.temperature(now):.2f} /{heater.target:.2f}"
                for index, heater in enumerate(self.hotends)
            ]
        parts.append(f"@:{active.power(now)} B@:{self.bed.power(now)}")
        return " ".join(parts)

    def _report_temperatures(self, command: gcode.Command, now: float) -> Reply:
        return Reply(ok_suffix=self.temperature_report(now))
