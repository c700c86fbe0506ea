"""Temperature and fan G-codes: M104/M109, M140/M190, M105, M155, M106/M107 and T<n>."""

from dataclasses import dataclass

from fake_marlin.emulator.printer.failures import thermal_error
from fake_marlin.emulator.printer import gcode
from fake_marlin.emulator.printer.gcode import Command
from fake_marlin.emulator.printer.statements import Heat, Statement, state
from fake_marlin.emulator.printer.steps import Reply, Report, Sleep, reply
from fake_marlin.emulator.printer.thermal import FULL_POWER

# Marlin's defaults: a heater must stay within TEMP_WINDOW of target for TEMP_RESIDENCY_TIME.
TEMP_WINDOW = 1.0
TEMP_RESIDENCY_TIME = 10.0
REPORT_INTERVAL = 1.0
# Marlin's heating watch (THERMAL_PROTECTION): while heating, the temperature must rise by
# WATCH_TEMP_INCREASE within WATCH_TEMP_PERIOD, or the heater is taken for dead.
WATCH_TEMP_PERIOD = {"hotend": 20.0, "bed": 60.0}
WATCH_TEMP_INCREASE = {"hotend": 2.0, "bed": 2.0}


@dataclass(frozen=True)
class HeatWait:
    """How M109 and M190 wait, as a firmware's profile says ([heating]): Marlin's by default."""

    residency: float = TEMP_RESIDENCY_TIME  # M109: seconds within `window` of the target
    window: float = TEMP_WINDOW
    bed_residency: float = TEMP_RESIDENCY_TIME  # M190's (0: done once within bed_window)
    bed_window: float = TEMP_WINDOW
    cools: bool = False  # M109 S waits for a hotter hotend to cool down too (Marlin 1.0)


def heats(printer, now: float, tool: int | None = None) -> dict[str, object]:
    """A temperature report's values: the active hotend (or `tool`), the bed, every hotend."""
    tool = printer.active_tool if tool is None else tool

    def heat(label: str, index: int, heater) -> Heat:
        power = heater.power(now)
        return Heat(label, index, heater.temperature(now), heater.target, power,
                    round(power * 255 / FULL_POWER))

    hotends = tuple(heat(f"T{index}", index, heater) for index, heater in enumerate(printer.hotends))
    return {"active": hotends[tool], "bed": heat("B", 0, printer.bed), "hotends": hotends,
            "tool": tool}


def temperature_report(printer, now: float, tool: int | None = None,
                       key: str = "temperatures") -> Statement:
    """Marlin's print_heater_states(), as a statement: `T:21.00 /0.00 B:21.00 /0.00 @:0 B@:0`
    in Marlin's words."""
    return Statement(key, heats(printer, now, tool))


def target_tool(printer, command: Command) -> int | Reply:
    """The hotend a command's T word names (the active one without it), or the refusal."""
    tool = command.value("T")
    tool = printer.active_tool if tool is None else gcode.whole(tool)
    if 0 <= tool < len(printer.hotends):
        return tool
    return reply(state("invalid_extruder", code=command.code, tool=tool))


def set_hotend(printer, command: Command, now: float):
    tool = target_tool(printer, command)
    if isinstance(tool, Reply):
        return tool
    if command.has("S"):
        printer.hotends[tool].set_target(now, command.value("S", 0.0))
        return reply(_hotend_target(printer, tool))
    return reply()


def _hotend_target(printer, tool: int) -> Statement:
    # Marlin says nothing of a new target; Repetier says `TargetExtr0:200`.
    return state("hotend_target", tool=tool, target=printer.hotends[tool].target)


def set_bed(printer, command: Command, now: float):
    if command.has("S"):
        printer.bed.set_target(now, command.value("S", 0.0))
        return reply(state("bed_target", target=printer.bed.target))
    return reply()


def wait_hotend(printer, command: Command, now: float):
    tool = target_tool(printer, command)
    if isinstance(tool, Reply):
        return tool
    heater = printer.hotends[tool]
    yield from _set_and_wait(printer, heater, command, now, tool)
    return reply(_hotend_target(printer, tool)) if command.has("S") else reply()


def wait_bed(printer, command: Command, now: float):
    yield from _set_and_wait(printer, printer.bed, command, now, None)
    return reply(state("bed_target", target=printer.bed.target)) if command.has("S") else reply()


def _set_and_wait(printer, heater, command: Command, now: float, tool: int | None):
    """M109/M190: S waits only to heat up, R also waits to cool down; M108 ends the wait."""
    if not (command.has("S") or command.has("R")):
        return now
    heater.set_target(now, command.value("S", command.value("R", 0.0)))
    wait: HeatWait = printer.config.heat_wait
    cooling_allowed = (command.has("R") and not command.has("S")) or (tool is not None
                                                                      and wait.cools)
    residency_time, window = ((wait.residency, wait.window) if tool is not None
                              else (wait.bed_residency, wait.bed_window))
    if heater.target == 0.0 or (heater.temperature(now) >= heater.target and not cooling_allowed):
        return now
    printer.heating_cancelled = False
    # Compared against stored end times: `now - start >= span` can round short and never hold.
    residency_end = None
    next_report = now
    kind = "hotend" if tool is not None else "bed"
    watch_end, watch_goal = now + WATCH_TEMP_PERIOD[kind], heater.temperature(now) + WATCH_TEMP_INCREASE[kind]
    while not printer.heating_cancelled and not printer.halted:
        if residency_end is None and heater.target > heater.temperature(now) and now >= watch_end:
            if heater.temperature(now) < watch_goal:
                for line in thermal_error(printer, "heating_failed", "B" if tool is None else f"T{tool}", now):
                    yield Report(line)
                return now
            watch_end, watch_goal = now + WATCH_TEMP_PERIOD[kind], heater.temperature(now) + WATCH_TEMP_INCREASE[kind]
        if residency_end is None and abs(heater.temperature(now) - heater.target) <= window:
            residency_end = now + residency_time
        if residency_end is not None and now >= residency_end:
            break
        if now >= next_report:
            remaining = "?" if residency_end is None else str(int(residency_end - now))
            yield Report(Statement("heating", {**heats(printer, now, tool), "remaining": remaining,
                                               "heater": "B" if tool is None else f"T{tool}"}))
            next_report = now + REPORT_INTERVAL
        if residency_end is None:
            # (the heating watch is only while heating: a wait to cool down passes its end)
            watch = watch_end if heater.target > heater.temperature(now) else next_report
            wake = min(next_report, watch, max(heater.reached_at(now), now + 0.01))
        else:
            wake = min(next_report, residency_end)
        now = yield Sleep(wake)
    return now


def report_temperatures(printer, command: Command, now: float):
    tool = target_tool(printer, command)
    if isinstance(tool, Reply):
        return tool
    return Reply(answer=temperature_report(printer, now, tool))


def auto_report_temperatures(printer, command: Command, now: float):
    printer.auto_reports.temperature = max(0.0, min(60.0, command.value("S", 0.0)))
    return reply()


def set_fan(printer, command: Command, now: float):
    fan = gcode.whole(command.value("P", 0.0))
    if 0 <= fan < len(printer.fans):
        speed = 0.0 if command.code == "M107" else command.value("S", 255.0)
        printer.fans[fan] = int(max(0.0, min(255.0, speed)))
    return reply()


def cancel_heating(printer, command: Command, now: float):
    # The emergency parser already acted on M108 as it arrived; the queued copy does nothing.
    return reply()


def select_tool(printer, command: Command, now: float):
    tool = int(command.code[1:]) if command.code[1:].isdigit() else -1
    if not 0 <= tool < len(printer.hotends):
        return reply(state("invalid_tool", tool=tool))
    if len(printer.hotends) == 1:
        return reply()
    printer.active_tool = tool
    return reply(state("active_extruder", tool=tool))


def pid_settings(printer, command: Command, now: float):
    """M301 P I D: the hotend's PID, kept and reported (M503); the thermal model has its own."""
    for index, letter in enumerate("PID"):
        if command.has(letter):
            printer.limits.pid[index] = command.value(letter, 0.0)
    return reply()


HANDLERS = {
    "M301": pid_settings,
    "M104": set_hotend,
    "M105": report_temperatures,
    "M106": set_fan,
    "M107": set_fan,
    "M108": cancel_heating,
    "M109": wait_hotend,
    "M140": set_bed,
    "M155": auto_report_temperatures,
    "M190": wait_bed,
    **{f"T{n}": select_tool for n in range(10)},
}
