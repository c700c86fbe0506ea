"""Marlin's PASSWORD_FEATURE: M510 locks the printer, M511 P<password> unlocks it, M512 P<old>
S<new> changes the password (feature/password/, gcode/feature/password/M510-M512.cpp).

While it is locked every command but M511 is refused (Printer.execute asks `refused()`), M105
included; commands the emergency parser takes still act. PASSWORD_LENGTH is 4 digits.
"""

from fake_marlin.emulator.printer import gcode
from fake_marlin.emulator.printer.gcode import Command
from fake_marlin.emulator.printer.statements import state
from fake_marlin.emulator.printer.steps import Reply, reply

PASSWORD_LENGTH = 4


def _entered(command: Command, letter: str) -> int:
    # parser.ulongval(): the digits as a number (missing: 0), so 0042 is 42.
    value = command.value(letter)
    return gcode.whole(value) if value is not None else 0


def refused(printer, command: Command) -> Reply | None:
    """The lock's answer to a command, or None where it runs."""
    if printer.locked and command.code != "M511":
        return Reply((state("printer_locked"),), effect="refused")  # it did not run
    return None


def lock(printer, command: Command, now: float):
    printer.locked = True
    return reply()


def unlock(printer, command: Command, now: float):
    if printer.locked:
        if _entered(command, "P") == _value(printer.password):
            printer.locked = False
        else:
            return reply(state("wrong_password"))
    return reply()


def set_password(printer, command: Command, now: float):
    if printer.password and _entered(command, "P") != _value(printer.password):
        return reply(state("wrong_password"))
    if not command.has("S"):
        printer.password = ""
        return reply(state("password_removed"), state("remember_to_save"))
    new = _entered(command, "S")
    if new >= 10 ** PASSWORD_LENGTH:
        return reply(state("password_too_long"), state("remember_to_save"))
    printer.password = str(new)
    return reply(state("password_set", password=new), state("remember_to_save"))


def _value(password: str) -> int:
    return int(password) if password.isdigit() else 0


HANDLERS = {"M510": lock, "M511": unlock, "M512": set_password}
