"""EEPROM settings: M500 stores them, M501 loads them, M502 loads the defaults, M503 reports
them, M504 checks the store (module/settings.cpp, gcode/eeprom/M500-M504.cpp).

What is stored outlives a reset, as a board's EEPROM does, and the process too where the
printer has an EEPROM file (`--eeprom-file`): EepromFile reads it when the printer is made and
writes it at each M500. The settings are the model's limits (motion.Limits): steps per mm,
feedrates, accelerations, home offset, PID, retraction; the password too, where there is one.
"""

import binascii
import json
import math
import os
from pathlib import Path

from fake_marlin.emulator.printer.gcode import Command
from fake_marlin.emulator.printer.statements import Statement, state
from fake_marlin.emulator.printer.steps import reply

STORED_SIZE = 621  # bytes of the stock layout (a real build's depends on its configuration)
_STORED = ("steps_per_mm", "max_feedrate", "max_acceleration", "acceleration",
           "retract_acceleration", "travel_acceleration", "home_offset", "pid", "retract_length",
           "retract_feedrate", "retract_zlift", "recover_extra", "recover_feedrate")


# What each stored setting must be for the model to run with it: the lists' lengths (None: a
# number), and whether it must be above 0 (the planner divides by steps, feedrates and
# accelerations) or only finite.
_SHAPES: dict[str, tuple[int | None, bool]] = {
    "steps_per_mm": (4, True), "max_feedrate": (4, True), "max_acceleration": (4, True),
    "acceleration": (None, True), "retract_acceleration": (None, True),
    "travel_acceleration": (None, True), "home_offset": (3, False), "pid": (3, False),
    "retract_length": (None, False), "retract_feedrate": (None, True),
    "retract_zlift": (None, False), "recover_extra": (None, False),
    "recover_feedrate": (None, True),
}


class EepromFileError(Exception):
    """An EEPROM file that cannot be read or written; the message names it and says why."""


def _number(value: object, positive: bool) -> bool:
    return (isinstance(value, (int, float)) and not isinstance(value, bool)
            and math.isfinite(value) and (value > 0 or not positive))


def _shown(value: object) -> str:
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _problem(stored: dict[str, object]) -> str | None:
    """What is wrong with the settings of an EEPROM file (a hand edit), naming the setting;
    None if the model can take them all."""
    for name, (length, positive) in _SHAPES.items():
        if name not in stored:
            continue
        value = stored[name]
        what = "a number" + (" above 0" if positive else "")
        if length is None:
            if not _number(value, positive):
                return f"{name} must be {what}, not {_shown(value)}"
        elif not (isinstance(value, list) and len(value) == length
                  and all(_number(item, positive) for item in value)):
            plural = "numbers" + (" above 0" if positive else "")
            return f"{name} must be a list of {length} {plural}, not {_shown(value)}"
    password = stored.get("password")
    if password is not None and not isinstance(password, str):
        return f"password must be a string, not {_shown(password)}"
    return None


class EepromFile:
    """The stored settings, in memory, and in a JSON file where one is given."""

    def __init__(self, path: str | os.PathLike[str] | None = None) -> None:
        self.path = Path(path) if path is not None else None
        self.stored: dict[str, object] | None = None
        if self.path is not None and self.path.exists():
            try:
                stored = json.loads(self.path.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError, ValueError) as error:
                raise EepromFileError(f"{self.path}: not an EEPROM file fake-marlin wrote: "
                                      f"{error}") from None
            if not isinstance(stored, dict):
                raise EepromFileError(f"{self.path}: not an EEPROM file fake-marlin wrote")
            if (problem := _problem(stored)) is not None:
                raise EepromFileError(f"{self.path}: not an EEPROM file fake-marlin wrote: "
                                      f"{problem}")
            self.stored = stored

    def store(self, values: dict[str, object]) -> None:
        self.stored = values
        if self.path is not None:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.path.write_text(json.dumps(values, sort_keys=True) + "\n", encoding="utf-8")
            except OSError as error:
                raise EepromFileError(f"{self.path}: cannot write: {error.strerror}") from None

    def crc(self) -> int:
        return binascii.crc_hqx(json.dumps(self.stored, sort_keys=True).encode(), 0)


def settings(printer) -> dict[str, object]:
    limits = printer.limits
    values: dict[str, object] = {name: getattr(limits, name) for name in _STORED}
    values["password"] = printer.password
    return json.loads(json.dumps(values))  # a copy, as JSON keeps it


def apply_stored(printer) -> bool:
    """The stored settings into the model (at a reset, M501); False if nothing is stored."""
    stored = printer.eeprom.stored
    if not stored:
        return False
    limits = printer.limits
    for name in _STORED:
        if name in stored:
            value = stored[name]
            setattr(limits, name, list(value) if isinstance(value, list) else float(value))
    if isinstance(stored.get("password"), str):
        printer.password = stored["password"]
    return True


def _enabled(printer) -> bool:
    return printer.config.capability("EEPROM")


def _notify(printer, text: str) -> list[Statement]:
    # Headless with HOST_PROMPT_SUPPORT, the LCD's messages go to the host.
    return [state("notification", text=text)] if printer.config.capability("PROMPT_SUPPORT") else []


def report(printer) -> Statement:
    limits = printer.limits
    return state("settings_report", steps=tuple(limits.steps_per_mm),
                 feedrates=tuple(limits.max_feedrate), max_accelerations=tuple(limits.max_acceleration),
                 accelerations=(limits.acceleration, limits.retract_acceleration,
                                limits.travel_acceleration),
                 home_offset=tuple(limits.home_offset), pid=tuple(limits.pid),
                 retract=(limits.retract_length, limits.retract_feedrate * 60, limits.retract_zlift),
                 recover=(limits.recover_extra, limits.recover_feedrate * 60))


def store(printer, command: Command, now: float):
    if not _enabled(printer):
        return reply(state("eeprom_disabled"))
    try:
        printer.eeprom.store(settings(printer))
    except EepromFileError as error:  # kept in memory all the same; the host hears why not
        return reply(state("firmware_error", text=f"EEPROM not written: {error}"))
    notified = _notify(printer, "Settings Stored")
    return reply(state("settings_stored", size=STORED_SIZE, crc=printer.eeprom.crc()),
                 *notified, *notified)  # said twice: LCD_MESSAGE and notify both reach the host


def load(printer, command: Command, now: float):
    if _enabled(printer) and apply_stored(printer):
        return reply(state("settings_retrieved", size=STORED_SIZE, crc=printer.eeprom.crc()),
                     *_notify(printer, "Stored settings retrieved"), report(printer))
    printer.reset_settings()
    if not _enabled(printer):  # load() is reset() and report()
        return reply(state("settings_defaults"), report(printer))
    return reply(state("settings_defaults"))


def defaults(printer, command: Command, now: float):
    printer.reset_settings()
    return reply(*_notify(printer, "Hardcoded Default Settings Loaded"), state("settings_defaults"))


def show(printer, command: Command, now: float):
    return reply(report(printer))


def check(printer, command: Command, now: float):
    if not _enabled(printer):  # as Printer.execute() says a code it has no handler for
        return reply(state("unknown_command", command=command.text,
                           name=command.code or command.text.upper()))
    return reply(state("eeprom_ok"))


HANDLERS = {"M500": store, "M501": load, "M502": defaults, "M503": show, "M504": check}
