"""EEPROM settings (printer/eeprom.py): M504 without an EEPROM in every firmware's words, and an
--eeprom-file edited by hand refused at start with one line that names the file and the
setting, not taken in to crash the printer later."""

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import pytest

from fake_marlin.emulator.firmware import Firmware
from fake_marlin.emulator.printer import eeprom
from fake_marlin.emulator.printer.eeprom import EepromFile, EepromFileError
from fake_marlin.emulator.printer.gcode import parse
from fake_marlin.emulator.printer.model import DEFAULT_CAPABILITIES, Printer, PrinterConfig

BIN = Path(sys.executable).parent


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


@pytest.mark.parametrize("stored, named", [
    ({"pid": "x"}, 'pid must be a list of 3 numbers, not "x"'),
    ({"steps_per_mm": [0, 80, 400, 500]},
     "steps_per_mm must be a list of 4 numbers above 0, not [0, 80, 400, 500]"),
    ({"steps_per_mm": [80, 80, 400]}, "steps_per_mm must be a list of 4 numbers above 0"),
    ({"max_feedrate": [300, 300, 5, -1]}, "max_feedrate must be a list of 4 numbers above 0"),
    ({"acceleration": 0}, "acceleration must be a number above 0, not 0"),
    ({"retract_feedrate": "45"}, 'retract_feedrate must be a number above 0, not "45"'),
    ({"home_offset": [0, 0, float("nan")]}, "home_offset must be a list of 3 numbers"),
    ({"retract_length": True}, "retract_length must be a number, not true"),
    ({"recover_extra": float("inf")}, "recover_extra must be a number, not Infinity"),
    ({"password": 1234}, "password must be a string, not 1234"),
    ({"pid": list(range(100))},  # a long value cut short
     "pid must be a list of 3 numbers, not [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11..."),
])
def test_a_file_edited_by_hand_is_refused_naming_the_file_and_the_setting(
        tmp_path, stored, named):
    path = tmp_path / "eeprom.json"
    path.write_text(json.dumps(stored))
    with pytest.raises(EepromFileError) as refused:
        EepromFile(path)
    assert str(refused.value).startswith(f"{path}: not an EEPROM file fake-marlin wrote: {named}")


def test_what_m500_stores_is_read_back_and_settings_it_does_not_know_are_left(tmp_path):
    path = tmp_path / "eeprom.json"
    printer = Printer(PrinterConfig(eeprom_file=path))
    printer.limits.steps_per_mm[0] = 100.0
    printer.eeprom.store({**eeprom.settings(printer), "from_a_later_version": [1, "x"]})
    again = Printer(PrinterConfig(eeprom_file=path))
    assert again.limits.steps_per_mm[0] == 100.0


def test_the_command_line_says_what_is_wrong_in_one_line(tmp_path):
    path = tmp_path / "eeprom.json"
    path.write_text('{"pid": "x"}')
    done = subprocess.run([BIN / "fake-marlin", "--eeprom-file", str(path), "--link",
                           str(tmp_path / "printer")], capture_output=True, text=True, timeout=60)
    assert (done.returncode, done.stdout) == (2, "")
    assert done.stderr == (f"fake-marlin: {path}: not an EEPROM file fake-marlin wrote: pid must "
                           'be a list of 3 numbers, not "x"\n')
