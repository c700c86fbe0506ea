"""What goes wrong inside a printer, and what the firmware says when it does.

The messages are Marlin 2.1's: `_temp_error()` prints the reason and the heater, then kill()
halts the printer until it is reset.
"""

from fake_marlin.emulator.faults.rules import FaultKind, FaultRule

_THERMAL_REASONS = {
    FaultKind.THERMAL_RUNAWAY: "Thermal Runaway",
    FaultKind.MINTEMP: "MINTEMP triggered",
    FaultKind.MAXTEMP: "MAXTEMP triggered",
}


def heater_id(printer, name: str) -> str:
    return "bed" if name.upper().startswith("B") else str(_hotend_index(printer, name))


def _hotend_index(printer, name: str) -> int:
    digits = name[1:] if name[:1].upper() == "T" else ""
    index = int(digits) if digits.isdigit() else 0
    return index if index < len(printer.hotends) else 0


def heater(printer, name: str):
    return printer.bed if name.upper().startswith("B") else printer.hotends[_hotend_index(printer, name)]


def thermal_error(printer, reason: str, heater_name: str, now: float) -> tuple[str, ...]:
    first = f"Error:{reason}, system stopped! Heater_ID: {heater_id(printer, heater_name)}"
    return printer.kill(first, now)


def apply(printer, rule: FaultRule, now: float) -> tuple[str, ...]:
    """Make the printer fail as `rule` says; returns the lines the firmware prints."""
    if printer.halted:
        return ()
    kind = rule.kind
    if kind in _THERMAL_REASONS:
        return thermal_error(printer, _THERMAL_REASONS[kind], rule.heater, now)
    if kind is FaultKind.FIRMWARE_ERROR:
        return (f"Error:{rule.text or 'Something went wrong'}",)
    if kind is FaultKind.HEATER_FAULT:
        heater(printer, rule.heater).break_down(now)
        return ()
    if kind is FaultKind.PLANNER_STALL:
        printer.planner.stall(now, rule.seconds)
        return ()
    if kind is FaultKind.SD_REMOVED:
        printer.sd.reset()
        printer.sd.mounted = False
        return ("echo:SD card released",)
    raise ValueError(f"{kind.value} is not a printer fault the model handles")
