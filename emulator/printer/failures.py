"""What goes wrong inside a printer, and what the firmware says when it does.

As Marlin 2.1's `_temp_error()`: the reason and the heater, then kill() halts the printer
until it is reset; a firmware's profile says each in its words.
"""

from dataclasses import dataclass
from enum import Enum

from fake_marlin.emulator.printer.statements import Statement, state


class FailureKind(Enum):
    """What can go wrong inside the printer itself."""

    THERMAL_RUNAWAY = "thermal-runaway"
    MINTEMP = "mintemp"
    MAXTEMP = "maxtemp"
    FIRMWARE_ERROR = "firmware-error"  # an `Error:` line; the printer runs on
    HEATER_FAULT = "heater-fault"  # the heater dies: it only ever cools
    PLANNER_STALL = "planner-stall"  # the steppers stop for a while
    SD_REMOVED = "sd-removed"


@dataclass(frozen=True)
class Failure:
    """One failure, and what it needs to happen."""

    kind: FailureKind
    heater: str = "T0"  # T0.., or B for the bed: the thermal failures and heater-fault
    seconds: float = 0.0  # planner-stall: how long
    text: str = ""  # firmware-error: the message (default: `Something went wrong`)


_THERMAL_REASONS = {
    FailureKind.THERMAL_RUNAWAY: "thermal_runaway",
    FailureKind.MINTEMP: "mintemp",
    FailureKind.MAXTEMP: "maxtemp",
}


def heater_id(printer, name: str) -> str:
    return "bed" if name.upper().startswith("B") else str(_hotend_index(printer, name))


def _hotend_index(printer, name: str) -> int:
    digits = name[1:] if name[:1].upper() == "T" else ""
    index = int(digits) if digits.isdigit() else 0
    return index if index < len(printer.hotends) else 0


def heater(printer, name: str):
    return printer.bed if name.upper().startswith("B") else printer.hotends[_hotend_index(printer, name)]


def heaters(printer) -> dict:
    """Every heater by the name `heater` takes: T0, T1, ... and B."""
    return {f"T{index}": hotend for index, hotend in enumerate(printer.hotends)} | {"B": printer.bed}


# A command set's handler under this key takes a thermal error instead of kill() (RepRapFirmware:
# a heater fault turns that heater off and the printer runs on): `handler(printer, reason, heater,
# now)`, heater as Failure.heater names it; it returns what the firmware says.
HEATER_FAULT = "(heater fault)"


def thermal_error(printer, reason: str, heater_name: str, now: float) -> tuple[Statement, ...]:
    """`reason` is the statement's key: thermal_runaway, mintemp, maxtemp, heating_failed."""
    if (fault := printer.handlers.get(HEATER_FAULT)) is not None:
        return fault(printer, reason, heater_name, now)
    which = heater(printer, heater_name)
    if which is printer.bed:
        designator = "B"
    else:
        index = _hotend_index(printer, heater_name)
        designator = "T" if index == 0 else f"T{index}"
    delta = which.temperature(now) - which.target
    return printer.kill(state(reason, heater=heater_id(printer, heater_name),
                              designator=designator, delta=delta), now)


def apply(printer, failure: Failure, now: float) -> tuple[Statement, ...]:
    """Make the printer fail as `failure` says; returns the lines the firmware prints."""
    if printer.halted:
        return ()
    kind = failure.kind
    if kind in _THERMAL_REASONS:
        return thermal_error(printer, _THERMAL_REASONS[kind], failure.heater, now)
    if kind is FailureKind.FIRMWARE_ERROR:
        return (state("firmware_error", text=failure.text or "Something went wrong"),)
    if kind is FailureKind.HEATER_FAULT:
        heater(printer, failure.heater).break_down(now)
        return ()
    if kind is FailureKind.PLANNER_STALL:
        printer.planner.stall(now, failure.seconds)
        return ()
    if kind is FailureKind.SD_REMOVED:
        printer.sd.reset()
        printer.sd.mounted = False
        return (state("sd_released"),)
    raise ValueError(f"{kind.value} is not a printer fault the model handles")
