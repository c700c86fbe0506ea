"""The quirks a host must survive, each switched on alone, line by line in simulated time; and
the same switches from the control channel while a host is connected."""

from contextlib import asynccontextmanager

import pytest

from fake_marlin.emulator.control.server import ControlError, Controller
from fake_marlin.emulator.firmware import Firmware, Quirks
from fake_marlin.emulator.printer.model import Printer
from fake_marlin.emulator.server.lifecycle import ServerConfig
from fake_marlin.testing import serve_in_memory
from tests.terminal import Terminal, numbered


@asynccontextmanager
async def marlin(tmp_path=None, **quirks):
    firmware = Firmware.make("marlin", quirks=Quirks(**quirks))
    sd = None
    if tmp_path is not None:
        sd = tmp_path / "sd"
        sd.mkdir()
    printer = Printer(firmware.printer_config(sd_dir=sd))
    async with serve_in_memory(ServerConfig(protocol="marlin"), printer, firmware) as running:
        terminal = Terminal(running.link.open_host())
        await terminal.read_until(lambda line: line == "//action:prompt_end")  # the greeting
        yield terminal, running


async def test_ok_before_output_puts_the_ok_first(autojump_clock):
    async with marlin(ok_before_output=True) as (terminal, _):
        await terminal.send("M114")
        assert [await terminal.read_line() for _ in range(2)] == [
            "ok", "X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0"]
    async with marlin() as (terminal, _):
        assert await terminal.command("M114") == [
            "X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0", "ok"]


async def test_a_resend_request_with_two_oks_or_none(autojump_clock):
    wrong = "N1 G28*0"
    async with marlin(extra_ok_after_resend=True) as (terminal, _):
        await terminal.send(wrong)
        assert await terminal.quiet_for(1) == [
            "Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok", "ok"]
    async with marlin(resend_without_ok=True) as (terminal, _):
        await terminal.send(wrong)
        assert await terminal.quiet_for(1) == ["Error:checksum mismatch, Last Line: 0", "Resend: 1"]


async def test_every_nth_ok_is_dropped(autojump_clock):
    async with marlin(drop_ok_every=3) as (terminal, running):
        for n in range(1, 7):
            await terminal.send(numbered(n, f"G1 X{n}"))
        lines = await terminal.quiet_for(1)
        assert lines == ["ok"] * 4  # the 3rd and the 6th were not sent
        assert running.journal == [f"G1 X{n}" for n in range(1, 7)]  # yet every move ran


async def test_busy_lines_at_the_interval_the_quirk_sets(autojump_clock):
    async with marlin(busy_interval=0.5) as (terminal, _):
        lines = await terminal.command("G4 S1.9")
        assert lines.count("echo:busy: processing") == 3 and lines[-1] == "ok"
    async with marlin(busy_interval=0) as (terminal, _):
        assert await terminal.command("G4 S5") == ["ok"]


async def test_no_m112_makes_it_an_unknown_command(autojump_clock):
    async with marlin(no_m112=True) as (terminal, running):
        assert await terminal.command("M112") == ['echo:Unknown command: "M112"', "ok"]
        assert not running.server.printer.halted


async def test_a_broken_m29_says_done_without_ok(autojump_clock, tmp_path):
    async with marlin(tmp_path, broken_m29=True) as (terminal, _):
        assert await terminal.command(numbered(1, "M28 a.gco")) == ["Writing to file: a.gco", "ok"]
        assert await terminal.command(numbered(2, "G1 X1")) == ["ok"]
        await terminal.send(numbered(3, "M29"))
        assert await terminal.quiet_for(2) == ["Done saving file."]
        assert await terminal.command("M105") != []  # and the printer runs on


async def test_unchecked_line_numbers_take_every_line_as_it_comes(autojump_clock):
    async with marlin(unchecked_line_numbers=True) as (terminal, running):
        assert await terminal.command("N7 G1 X1*0") == ["ok"]
        assert await terminal.command("N3 G1 X2") == ["ok"]
        assert running.journal == ["G1 X1", "G1 X2"]


async def test_a_locked_printer_runs_nothing_but_m511(autojump_clock):
    async with marlin(password="1234", locked=True) as (terminal, running):
        locked = "echo:Printer locked! (Unlock with M511 or LCD)"
        assert await terminal.command("M105") == [locked, "ok"]
        assert await terminal.command("G1 X5") == [locked, "ok"]
        assert await terminal.command("M511 P4321") == ["Incorrect Password", "ok"]
        assert await terminal.command("M511 P1234") == ["ok"]
        assert (await terminal.command("M105"))[0].startswith("ok T:")
        assert await terminal.command("M510") == ["ok"]
        assert await terminal.command("M114") == [locked, "ok"]
        assert running.journal.count("G1 X5") == 0


async def test_m512_changes_the_password(autojump_clock):
    async with marlin(password="1234") as (terminal, _):
        assert await terminal.command("M512 P1111 S42") == ["Incorrect Password", "ok"]
        assert await terminal.command("M512 P1234 S0042") == [
            "Password is 42", "Remember to save!", "ok"]
        assert await terminal.command("M510") == ["ok"]
        assert await terminal.command("M511 P42") == ["ok"]
        assert await terminal.command("M512 P42 S123456") == [
            "Password too long", "Remember to save!", "ok"]


async def test_a_reset_unlocks_and_forgets_a_password_not_saved(autojump_clock):
    async with marlin(password="1234") as (terminal, running):
        assert await terminal.command("M512 P1234 S42") == [
            "Password is 42", "Remember to save!", "ok"]
        assert await terminal.command("M510") == ["ok"]
        again = Terminal(running.link.open_host())  # a reset: no PASSWORD_ON_STARTUP
        await again.read_until(lambda line: line == "//action:prompt_end")
        assert (await again.command("M105"))[0].startswith("ok T:")
        assert await again.command("M510") == ["ok"]
        assert await again.command("M511 P42") == ["Incorrect Password", "ok"]  # not saved
        assert await again.command("M511 P1234") == ["ok"]


async def test_without_a_password_m510_is_unknown(autojump_clock):
    async with marlin() as (terminal, _):
        assert await terminal.command("M510") == ['echo:Unknown command: "M510"', "ok"]


async def test_eeprom_settings_outlive_a_reset_and_the_process(autojump_clock, tmp_path):
    stored = tmp_path / "eeprom.json"
    firmware = Firmware.make("marlin")
    for run in range(2):
        printer = Printer(firmware.printer_config(eeprom_file=stored))
        async with serve_in_memory(ServerConfig(protocol="marlin"), printer, firmware) as running:
            terminal = Terminal(running.link.open_host())
            await terminal.read_until(lambda line: line == "//action:prompt_end")
            if run == 0:
                assert await terminal.command("M92 X100") == ["ok"]
                saved = await terminal.command("M500")
                assert saved[0].startswith("echo:Settings Stored (621 bytes; crc ")
                assert saved[1:] == ["//action:notification Settings Stored"] * 2 + ["ok"]
                assert await terminal.command("M92 X50") == ["ok"]
                again = Terminal(running.link.open_host())  # a reset: what was stored is back
                await again.read_until(lambda line: line == "//action:prompt_end")
                terminal = again
            report = await terminal.command("M503")
            assert "echo:  M92 X100.00 Y80.00 Z400.00 E500.00" in report
            assert report[0] == "echo:; Linear Units:" and report[-1] == "ok"
    async with marlin() as (terminal, _):
        assert await terminal.command("M502") == [
            "//action:notification Hardcoded Default Settings Loaded",
            "echo:Hardcoded Default Settings Loaded", "ok"]
        assert "echo:  M92 X80.00 Y80.00 Z400.00 E500.00" in await terminal.command("M503")
        assert await terminal.command("M504") == ["echo:EEPROM OK", "ok"]


async def test_without_eeprom_m500_is_refused_and_m115_says_so(autojump_clock):
    async with marlin(eeprom=False) as (terminal, _):
        assert await terminal.command("M500") == ["Error:EEPROM disabled", "ok"]
        assert "Cap:EEPROM:0" in await terminal.command("M115")


async def test_the_control_channel_switches_quirks_while_a_host_is_connected(autojump_clock):
    async with marlin() as (terminal, running):
        controller = Controller([running.server])
        assert controller.handle({"op": "quirks"})["ok_before_output"] is False
        now = controller.handle({"op": "quirks", "set": {"ok_before_output": True}})
        assert now["ok_before_output"] is True
        await terminal.send("M114")
        assert await terminal.read_line() == "ok"
        with pytest.raises(ControlError, match="no_such_quirk"):
            controller.handle({"op": "quirks", "set": {"no_such_quirk": True}})
        controller.handle({"op": "quirks", "set": {"password": "77", "locked": True,
                                                   "ok_before_output": False}})
        await terminal.quiet_for(1)
        assert (await terminal.command("G28"))[-2] == "echo:Printer locked! (Unlock with M511 or LCD)"
        controller.handle({"op": "action", "action": "pause"})
        assert await terminal.read_line() == "//action:pause"



async def test_numbers_too_long_for_a_long_are_clamped_not_a_crash(autojump_clock):
    async with marlin(password="1234", locked=True) as (terminal, running):
        assert await terminal.command("M511 P" + "9" * 400) == ["Incorrect Password", "ok"]
        assert await terminal.command("M511 P1234") == ["ok"]
        assert await terminal.command("M106 P" + "9" * 400 + " S100") == ["ok"]  # no such fan
        assert (await terminal.command("M104 T" + "9" * 400 + " S100"))[0].startswith(
            "echo:M104 Invalid extruder 2147483647")
