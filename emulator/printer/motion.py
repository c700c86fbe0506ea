"""Motion G-codes: moves, arcs, retraction, homing, probing, modes, limits and M114."""

import math
from dataclasses import dataclass, field

from fake_marlin.emulator.printer.gcode import Command, PlainMove
from fake_marlin.emulator.printer.planner import move_time
from fake_marlin.emulator.printer.statements import Statement, state
from fake_marlin.emulator.printer.steps import Sleep, reply

AXES = "XYZE"
MM_PER_ARC_SEGMENT = 1.0
PROBE_POINTS = ((20.0, 20.0), (180.0, 20.0), (100.0, 180.0))


@dataclass
class MotionState:
    position: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])
    feedrate: float = 1500.0  # mm/min
    relative: bool = False
    relative_e: bool = False
    homed: set[str] = field(default_factory=set)
    retracted: bool = False
    feedrate_percent: float = 100.0  # M220
    flow_percent: float = 100.0  # M221


@dataclass
class Limits:
    max_feedrate: list[float]
    acceleration: float
    retract_length: float = 3.0  # M207 S
    retract_feedrate: float = 45.0  # mm/s, M207 F (mm/min on the wire)
    retract_zlift: float = 0.0  # M207 Z
    recover_extra: float = 0.0  # M208 S
    recover_feedrate: float = 8.0  # mm/s, M208 F
    inactivity_timeout: float = 0.0  # M85 S
    # What M503 reports and M500 stores beside the above (Marlin 2.1's stock values).
    steps_per_mm: list[float] = field(default_factory=lambda: [80.0, 80.0, 400.0, 500.0])  # M92
    max_acceleration: list[float] = field(default_factory=lambda: [3000.0, 3000.0, 100.0,
                                                                   10000.0])  # M201
    retract_acceleration: float = 3000.0  # M204 R
    travel_acceleration: float = 3000.0  # M204 T
    home_offset: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])  # M206
    pid: list[float] = field(default_factory=lambda: [22.2, 1.08, 114.0])  # M301 P I D

    @classmethod
    def from_config(cls, config) -> "Limits":
        limits = cls(list(config.max_feedrate), config.acceleration)
        limits.steps_per_mm[:3] = list(config.steps_per_mm)
        return limits


def _target(printer, command: Command) -> list[float]:
    motion = printer.motion
    target = list(motion.position)
    for index, axis in enumerate(AXES):
        value = command.value(axis)
        if value is None:
            continue
        relative = motion.relative_e if axis == "E" else motion.relative
        target[index] = motion.position[index] + value if relative else value
    return target


def _duration(motion: MotionState, limits: Limits, junction_speed: float, start, target,
              speed: float) -> float:
    # Written out axis by axis: a batch of plain moves spends a third of its time here.
    dx, dy = abs(target[0] - start[0]), abs(target[1] - start[1])
    dz, de = abs(target[2] - start[2]), abs(target[3] - start[3])
    distance = math.hypot(dx, dy, dz) or de
    if distance == 0:
        return 0.0
    speed *= motion.feedrate_percent / 100.0
    # Slow the whole move so that no axis exceeds its own limit.
    limit = limits.max_feedrate
    if dx > 0 and (bound := limit[0] * distance / dx) < speed:
        speed = bound
    if dy > 0 and (bound := limit[1] * distance / dy) < speed:
        speed = bound
    if dz > 0 and (bound := limit[2] * distance / dz) < speed:
        speed = bound
    if de > 0 and (bound := limit[3] * distance / de) < speed:
        speed = bound
    return move_time(distance, speed, limits.acceleration, junction_speed)


def plan_move(printer, target: list[float], speed: float, now: float):
    """Queue one straight move, waiting for room in the planner; returns the time after."""
    start = tuple(printer.motion.position)
    duration = _duration(printer.motion, printer.limits, printer.config.junction_speed, start,
                         target, speed)
    while printer.planner.room(now) == 0:
        now = yield Sleep(printer.planner.next_change(now))
    _queue(printer, start, target, duration, now)
    return now


def _queue(printer, start: tuple[float, ...], target: list[float], duration: float,
           now: float) -> None:
    if duration > 0:
        printer.planner.add(now, duration, start, tuple(target))
    printer.motion.position = list(target)


SYNC_POLL = 1.0  # s: how often a wait for the moves looks again (a feedhold moves their end)


def synchronize(printer, now: float):
    """Wait until every planned move is done: looked at again after a while, since a feedhold
    or a stall moves their end (the wait still ends exactly when they do)."""
    while (drained := printer.planner.drained_at(now)) > now:
        now = yield Sleep(min(drained, now + SYNC_POLL))
    return now


def move(printer, command: Command, now: float):
    speed = _speed(printer, command)
    yield from plan_move(printer, _target(printer, command), speed, now)
    return reply()


def plan_plain_moves(printer, moves: list[tuple[PlainMove, float]]) -> None:
    """`move` for each (plain move, time it came), in order: moves gcode.plain_move() read,
    which the planner had room for when they came (a later F wins, as in parse()); nothing
    waits. The modes and limits hold for the whole batch: whatever changes them reads the
    motion state first, which plans the batch."""
    motion, limits, planner = printer.motion, printer.limits, printer.planner
    junction_speed = printer.config.junction_speed
    relative, relative_e = motion.relative, motion.relative_e
    start = motion.position
    origin = tuple(start)  # each move's target is the next one's origin: one tuple for both
    planned: list[tuple[float, float, tuple[float, ...], tuple[float, ...]]] = []
    for (first_feed, x, y, z, e, last_feed), now in moves:
        target = start.copy()
        if x is not None:
            target[0] = start[0] + float(x) if relative else float(x)
        if y is not None:
            target[1] = start[1] + float(y) if relative else float(y)
        if z is not None:
            target[2] = start[2] + float(z) if relative else float(z)
        if e is not None:
            target[3] = start[3] + float(e) if relative_e else float(e)
        feed = last_feed if last_feed is not None else first_feed
        if feed is not None and (feedrate := float(feed)) > 0:  # as _speed()
            motion.feedrate = feedrate
        duration = _duration(motion, limits, junction_speed, start, target, motion.feedrate / 60.0)
        destination = tuple(target)
        if duration > 0:  # as _queue()
            planned.append((now, duration, origin, destination))
        start, origin = target, destination
    motion.position = start
    planner.add_all(planned)


def _speed(printer, command: Command) -> float:
    """mm/s: F (mm/min) sets the feedrate for this move and the ones after it."""
    if command.value("F", 0.0) > 0:
        printer.motion.feedrate = command.value("F")
    return printer.motion.feedrate / 60.0


def arc(printer, command: Command, now: float):
    """G2 (clockwise) / G3: an arc in XY, cut into ~1 mm segments as Marlin does."""
    motion = printer.motion
    if command.value("F", 0.0) > 0:
        motion.feedrate = command.value("F")
    start = list(motion.position)
    target = _target(printer, command)
    clockwise = command.code == "G2"
    if command.has("R"):
        radius = command.value("R", 0.0)
        dx, dy = target[0] - start[0], target[1] - start[1]
        chord = math.hypot(dx, dy)
        if chord == 0 or abs(radius) < chord / 2:
            return reply(state("arc_bad_radius"))
        h = math.sqrt(radius * radius - chord * chord / 4) * (1 if clockwise == (radius < 0) else -1)
        center = (start[0] + dx / 2 - h * dy / chord, start[1] + dy / 2 + h * dx / chord)
    else:
        center = (start[0] + command.value("I", 0.0), start[1] + command.value("J", 0.0))
    radius = math.hypot(start[0] - center[0], start[1] - center[1])
    if radius == 0:
        return reply(state("arc_bad_center"))
    a0 = math.atan2(start[1] - center[1], start[0] - center[0])
    a1 = math.atan2(target[1] - center[1], target[0] - center[0])
    sweep = a1 - a0
    if clockwise and sweep >= 0:
        sweep -= 2 * math.pi
    elif not clockwise and sweep <= 0:
        sweep += 2 * math.pi
    segments = max(1, min(2000, int(abs(sweep) * radius / MM_PER_ARC_SEGMENT)))
    speed = motion.feedrate / 60.0
    for index in range(1, segments + 1):
        fraction = index / segments
        if index == segments:
            point = target
        else:
            angle = a0 + sweep * fraction
            point = [
                center[0] + radius * math.cos(angle),
                center[1] + radius * math.sin(angle),
                start[2] + (target[2] - start[2]) * fraction,
                start[3] + (target[3] - start[3]) * fraction,
            ]
        now = yield from plan_move(printer, point, speed, now)
    return reply()


def dwell(printer, command: Command, now: float):
    seconds = command.value("S", 0.0) + command.value("P", 0.0) / 1000.0
    now = yield from synchronize(printer, now)
    if seconds > 0:
        yield Sleep(now + seconds)
    return reply()


def retract(printer, command: Command, now: float):
    """G10 / G11: firmware retraction (M207 / M208 set how)."""
    motion, limits = printer.motion, printer.limits
    retracting = command.code == "G10"
    if motion.retracted == retracting:
        return reply()
    target = list(motion.position)
    if retracting:
        target[3] -= limits.retract_length
        target[2] += limits.retract_zlift
        speed = limits.retract_feedrate
    else:
        target[3] += limits.retract_length + limits.recover_extra
        target[2] -= limits.retract_zlift
        speed = limits.recover_feedrate
    logical_e = motion.position[3]
    yield from plan_move(printer, target, speed, now)
    motion.position[3] = logical_e  # the filament moved; the E the host counts in did not
    motion.retracted = retracting
    return reply()


def home(printer, command: Command, now: float):
    now = yield from synchronize(printer, now)
    named = [axis for axis in "XYZ" if command.has(axis)]
    seconds = 0.0
    for axis in named or ["X", "Y", "Z"]:
        index = "XYZ".index(axis)
        # A fast approach from wherever it is, then a bump and a slow second touch.
        travel = max(abs(printer.motion.position[index]), 10.0) + 5.0
        seconds += travel / printer.config.homing_feedrate[index] + 0.5
        printer.motion.position[index] = 0.0
        printer.motion.homed.add(axis)
    yield Sleep(now + seconds)
    return reply()


def probe_bed(printer, command: Command, now: float):
    """G29 as a 3-point probing cycle: travel to each point, probe down, report."""
    if not {"X", "Y", "Z"} <= printer.motion.homed:
        missing = "".join(axis for axis in "XYZ" if axis not in printer.motion.homed)
        return reply(state("home_first", axes=missing))
    now = yield from synchronize(printer, now)
    lines = []
    for index, (x, y) in enumerate(PROBE_POINTS):
        travel = math.dist(printer.motion.position[:2], (x, y))
        now += travel / printer.config.homing_feedrate[0] + 2 * 5.0 / printer.config.homing_feedrate[2]
        printer.motion.position[0:2] = [x, y]
        z = 0.01 * (index - 1)
        lines.append(state("probe_point", x=x, y=y, z=z))
        yield Sleep(now)
    lines.append(state("bed_leveling_applied"))
    return reply(*lines)


def set_absolute(printer, command: Command, now: float):
    printer.motion.relative = printer.motion.relative_e = command.code == "G91"
    return reply()


def set_extruder_mode(printer, command: Command, now: float):
    printer.motion.relative_e = command.code == "M83"
    return reply()


def set_position(printer, command: Command, now: float):
    named = [axis for axis in AXES if command.has(axis)]
    for axis in named or AXES:
        printer.motion.position[AXES.index(axis)] = command.value(axis, 0.0)
    return reply()


def finish_moves(printer, command: Command, now: float):
    yield from synchronize(printer, now)
    return reply()


def disable_steppers(printer, command: Command, now: float):
    if command.has("S") and not any(command.has(a) for a in AXES):
        printer.limits.inactivity_timeout = command.value("S", 0.0)
        return reply()
    yield from synchronize(printer, now)
    printer.motion.homed.clear()  # disabled steppers lose their position
    return reply()


def enable_steppers(printer, command: Command, now: float):
    """M17: the model keeps no state for stepper power, so it only acknowledges."""
    return reply()


def inactivity_timeout(printer, command: Command, now: float):
    printer.limits.inactivity_timeout = command.value("S", 0.0)
    return reply()


def max_feedrates(printer, command: Command, now: float):
    for index, axis in enumerate(AXES):
        value = command.value(axis)
        if value is not None and value > 0:
            printer.limits.max_feedrate[index] = value
    return reply()


def accelerations(printer, command: Command, now: float):
    """M204 S/P (printing), R (retract), T (travel); M201 X Y Z E (each axis's maximum)."""
    limits = printer.limits
    if command.code == "M201":
        for index, axis in enumerate(AXES):
            if command.value(axis, 0.0) > 0:
                limits.max_acceleration[index] = command.value(axis, 0.0)
        return reply()
    for letter in ("S", "P"):
        if command.value(letter, 0.0) > 0:
            limits.acceleration = command.value(letter)
    if command.value("R", 0.0) > 0:
        limits.retract_acceleration = command.value("R", 0.0)
    if command.value("T", 0.0) > 0:
        limits.travel_acceleration = command.value("T", 0.0)
    return reply()


def steps_per_unit(printer, command: Command, now: float):
    """M92: steps per mm of each axis (the model moves in mm; M114's counts are in steps)."""
    for index, axis in enumerate(AXES):
        if command.value(axis, 0.0) > 0:
            printer.limits.steps_per_mm[index] = command.value(axis, 0.0)
    return reply()


def home_offset(printer, command: Command, now: float):
    """M206: kept and reported (M503); the model's positions do not apply it."""
    for index, axis in enumerate("XYZ"):
        if command.has(axis):
            printer.limits.home_offset[index] = command.value(axis, 0.0)
    return reply()


def retract_settings(printer, command: Command, now: float):
    limits = printer.limits
    if command.code == "M207":
        limits.retract_length = command.value("S", limits.retract_length)
        limits.retract_feedrate = command.value("F", limits.retract_feedrate * 60.0) / 60.0
        limits.retract_zlift = command.value("Z", limits.retract_zlift)
    else:
        limits.recover_extra = command.value("S", limits.recover_extra)
        limits.recover_feedrate = command.value("F", limits.recover_feedrate * 60.0) / 60.0
    return reply()


def feedrate_percent(printer, command: Command, now: float):
    percent = command.value("S")
    if percent is None:
        return reply(state("feedrate_percent", percent=printer.motion.feedrate_percent))
    printer.motion.feedrate_percent = max(1.0, percent)
    return reply()


def flow_percent(printer, command: Command, now: float):
    percent = command.value("S")
    if percent is None:
        return reply(state("flow_percent", tool=printer.active_tool,
                           percent=printer.motion.flow_percent))
    printer.motion.flow_percent = max(1.0, percent)
    return reply()


def position_report(printer, now: float, key: str = "position") -> Statement:
    """M114's report: where the axes are going, and where the steppers are (in steps);
    `X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0` in Marlin's words."""
    x, y, z, e = printer.motion.position
    stepper = printer.planner.stepper_position(now, tuple(printer.motion.position))
    counts = {f"count_{axis}": round(value * steps) for axis, value, steps in
              zip("xyz", stepper, printer.limits.steps_per_mm)}
    if key == "position":  # (and in mm: whole steps over steps per mm)
        counts.update({f"stepper_{axis}": round(value * steps) / steps for axis, value, steps in
                       zip("xyze", stepper, printer.limits.steps_per_mm)})
    return Statement(key, {"x": x, "y": y, "z": z, "e": e, **counts})


def report_position(printer, command: Command, now: float):
    return reply(position_report(printer, now))


def quickstop(printer, now: float) -> None:
    """M410: stop all motion now; the position is wherever the steppers are."""
    stepper = printer.planner.stepper_position(now, tuple(printer.motion.position))
    printer.planner.clear()
    printer.motion.position[:3] = list(stepper[:3])


HANDLERS = {
    "G0": move,
    "G1": move,
    "G2": arc,
    "G3": arc,
    "G4": dwell,
    "G10": retract,
    "G11": retract,
    "G28": home,
    "G29": probe_bed,
    "G90": set_absolute,
    "G91": set_absolute,
    "G92": set_position,
    "M17": enable_steppers,
    "M18": disable_steppers,
    "M82": set_extruder_mode,
    "M83": set_extruder_mode,
    "M84": disable_steppers,
    "M85": inactivity_timeout,
    "M114": report_position,
    "M92": steps_per_unit,
    "M201": accelerations,
    "M203": max_feedrates,
    "M204": accelerations,
    "M206": home_offset,
    "M207": retract_settings,
    "M208": retract_settings,
    "M220": feedrate_percent,
    "M221": flow_percent,
    "M400": finish_moves,
}
