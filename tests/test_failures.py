"""Printer faults as the firmware reports them."""

import pytest

from fake_marlin.emulator.faults.rules import FaultKind, FaultRule, Trigger, printer_failure
from fake_marlin.emulator.firmware import Firmware
from fake_marlin.emulator.printer import failures
from fake_marlin.emulator.printer.model import Printer, PrinterConfig

ONCE = Trigger(nth=1)
MARLIN = Firmware.make().words  # what the model states, in Marlin's words


@pytest.mark.parametrize(
    "kind, heater, first",
    [
        (FaultKind.THERMAL_RUNAWAY, "T0", "Error:Thermal Runaway, system stopped! Heater_ID: 0"),
        (FaultKind.MINTEMP, "T1", "Error:MINTEMP triggered, system stopped! Heater_ID: 1"),
        (FaultKind.MAXTEMP, "B", "Error:MAXTEMP triggered, system stopped! Heater_ID: bed"),
    ],
)
def test_thermal_faults_kill_with_marlins_words(kind, heater, first):
    printer = Printer(PrinterConfig(extruders=2))
    lines = MARLIN.lines(failures.apply(printer, printer_failure(FaultRule(kind, ONCE, heater=heater)), 0.0))
    assert tuple(lines[:2]) == (first, "Error:Printer halted. kill() called!") and printer.halted
    assert failures.apply(printer, printer_failure(FaultRule(kind, ONCE)), 1.0) == ()  # dead already


def test_a_firmware_error_line_does_not_halt():
    printer = Printer()
    rule = FaultRule(FaultKind.FIRMWARE_ERROR, ONCE, text="Z probe out of range")
    assert MARLIN.lines(failures.apply(printer, printer_failure(rule), 0.0)) == ["Error:Z probe out of range"]
    assert not printer.halted


def test_pulling_the_sd_card_stops_its_print(tmp_path):
    (tmp_path / "a.gco").write_text("G1 X1\n")
    printer = Printer(PrinterConfig(sd_dir=tmp_path))
    list(printer.execute("M23 a.gco", 0.0))
    list(printer.execute("M24", 0.0))
    assert printer.sd.printing
    sd_removed = printer_failure(FaultRule(FaultKind.SD_REMOVED, ONCE))
    assert MARLIN.lines(failures.apply(printer, sd_removed, 0.0)) == ["echo:SD card released"]
    assert not printer.sd.printing and not printer.sd.mounted


def test_a_planner_stall_delays_every_planned_move():
    printer = Printer()
    list(printer.execute("G1 X10 F600", 0.0))
    before = printer.planner.drained_at(0.0)
    failures.apply(printer, printer_failure(FaultRule(FaultKind.PLANNER_STALL, ONCE, seconds=30.0)), 0.5)
    assert printer.planner.drained_at(0.5) == pytest.approx(before + 30.0)
