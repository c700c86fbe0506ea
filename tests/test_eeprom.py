"""EEPROM settings (printer/eeprom.py): M504 without an EEPROM in every firmware's words."""

import dataclasses

import pytest

from fake_marlin.emulator.firmware import Firmware
from fake_marlin.emulator.printer import eeprom
from fake_marlin.emulator.printer.gcode import parse
from fake_marlin.emulator.printer.model import DEFAULT_CAPABILITIES, Printer, PrinterConfig


def replied(step):
    """The reply of a command that does not wait (Printer.execute() is a generator)."""
    try:
        next(step)
    except StopIteration as done:
        return done.value
    raise AssertionError("the command waited")


def without_eeprom() -> Printer:
    return Printer(dataclasses.replace(
        PrinterConfig(), capabilities=(*DEFAULT_CAPABILITIES, ("EEPROM", False))))


@pytest.mark.parametrize("firmware, said", [
    ("marlin", 'echo:Unknown command: "M504"'),
    ("klipper", '// Unknown command:"M504"'),  # its words name the code: {name}
    ("reprapfirmware", "Warning: M504: Command is not supported"),
])
def test_m504_without_an_eeprom_is_an_unknown_command_as_the_model_states_one(firmware, said):
    printer = without_eeprom()
    (statement,) = eeprom.check(printer, parse("M504"), 0.0).lines
    # What Printer.execute() states for a code it has no handler for, value for value.
    unknown = Printer(dataclasses.replace(PrinterConfig(), unsupported=frozenset({"M504"})))
    assert statement == replied(unknown.execute("M504", 0.0)).lines[0]
    assert Firmware.make(firmware).words.say(statement) == [said]
