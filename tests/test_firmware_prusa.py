"""The prusa firmware: Prusa-Firmware 3.14.1 on an MK3S, as PrusaLink 0.8.1 hears it.

PrusaLink's regular expressions below are its own (prusa/link/printer_adapter/structures/
regular_expressions.py of prusalink 0.8.1): every answer it reads must match them exactly.
"""

import os
import re
import struct
import time
from pathlib import Path

import pytest
import trio

from fake_marlin.emulator.faults.rules import FaultKind, FaultRule, Trigger, printer_failure
from fake_marlin.emulator.firmware import Firmware, load_profile
from fake_marlin.emulator.printer import failures
from fake_marlin.emulator.printer.prusa import EEPROM_JOB_ID, board
from fake_marlin.testing import memory_printer
from tests.terminal import Terminal, numbered

FW_REGEX = re.compile(r"^(?P<version>\d+\.\d+\.\d+-.*)$")
PRINTER_TYPE_REGEX = re.compile(r"^(?P<code>\d{3,5})$")
VALID_SN_REGEX = re.compile(r"^(?P<sn>^CZPX\d{4}X\d{3}X.\d{5})$")
NOZZLE_REGEX = re.compile(r"^(?P<size>\d\.\d+)$")
PERCENT_REGEX = re.compile(r"^(?P<percent>\d{0,3})%$")
D3_OUTPUT_REGEX = re.compile(r"^(?P<address>\w{2,}) {2}(?P<data>([0-9a-fA-F]{2} ?)+)$")
M27_OUTPUT_REGEX = re.compile(
    r"^(?P<sdn_lfn>/.*\..*)|(?P<no_print>Not SD printing)|"
    r"(?P<serial_paused>Print saved)|(?P<sd_paused>SD print paused)|"
    r"(?P<byte_pos>SD printing byte (?P<current>\d+)/(?P<sum>\d+))|"
    r"(?P<printing_time>(?P<hours>\d+):(?P<minutes>\d{2}))$")
PRINT_INFO_REGEX = re.compile(
    r"^(?P<mode>(SILENT)|(NORMAL)) MODE: Percent done: (?P<progress>-?\d+); "
    r"[pP]rint time remaining in mins: (?P<remaining>-?\d+); Change in mins: (?P<change_in>-?\d+)")
TEMPERATURE_REGEX = re.compile(
    r"^T:(?P<ntemp>-?\d+\.\d+) /(?P<set_ntemp>-?\d+\.\d+) B:(?P<btemp>-?\d+\.\d+) "
    r"/(?P<set_btemp>-?\d+\.\d+) T0:(-?\d+\.\d+) /(-?\d+\.\d+) @:(?P<tpwm>-?\d+) "
    r"B@:(?P<bpwm>-?\d+) P:(?P<ptemp>-?\d+\.\d+)( A:(?P<atemp>-?\d+\.\d+))?$")
POSITION_REGEX = re.compile(
    r"^X:(?P<x>-?\d+\.\d+) Y:(?P<y>-?\d+\.\d+) Z:(?P<z>-?\d+\.\d+) E:(?P<e>-?\d+\.\d+) "
    r"Count X: (?P<count_x>-?\d+\.\d+) Y:(?P<count_y>-?\d+\.\d+) Z:(?P<count_z>-?\d+\.\d+) "
    r"E:(?P<count_e>-?\d+\.\d+)$")
FAN_REGEX = re.compile(r"E0:(?P<hotend_rpm>\d+) RPM PRN1:(?P<print_rpm>\d+) RPM "
                       r"E0@:(?P<hotend_power>\d+) PRN1@:(?P<print_power>\d+)")
HEATING_REGEX = re.compile(r"^T:(?P<ntemp>\d+\.\d+) E:\d+ B:(?P<btemp>\d+\.\d+)$")
HEATING_HOTEND_REGEX = re.compile(r"^T:(?P<ntemp>\d+\.\d+) E:([?]|\d+) W:([?]|\d+)$")
MBL_REGEX = re.compile(r"^(?P<no_mbl>Mesh bed leveling not active.)|"
                       r"(Num X,Y: (?P<num_x>\d+),(?P<num_y>\d+))|"
                       r"(?P<mbl_row>([ ]*-?\d+\.\d+)+)$")
LFN_CAPTURE = re.compile(
    r"^(?P<begin>Begin file list)|"
    r"(?P<dir_enter>DIR_ENTER: (?P<sdn>/[^ ]*/) \"(?P<ldn>[^\"]*)\")|"
    r"(?P<file>(?P<sfn>.*\.(?P<extension>GCO|G)) "
    r"((0x(?P<m_time>[0-9a-fA-F]+) ?)|(?P<size>\d+ ?)|(\"(?P<lfn>[^\"]*)\") ?)*)|"
    r"(?P<dir_exit>DIR_EXIT)|(?P<end>End file list)$")
SD_PRESENT_REGEX = re.compile(r"^(?P<ok>echo:SD card ok)|(?P<fail>(echo:SD init fail)|"
                              r"(Error:volume\.init failed)|(Error:openRoot failed))$")
ERROR_REASON_REGEX = re.compile(
    r"(Error:((?P<temp>(0: )?Heaters switched off\. M((?P<mintemp>IN)|(?P<maxtemp>AX))TEMP "
    r"(?P<bed>BED )?triggered!)|(?P<runaway>( ((?P<hotend_runaway>HOTEND)|"
    r"(?P<heatbed_runaway>HEATBED)))? THERMAL RUNAWAY( \( ?PREHEAT "
    r"((?P<preheat_hotend>HOTEND)|(?P<preheat_heatbed>HEATBED))\))?)))")

GREETING_END = "echo:SD card ok"


async def booted(running) -> Terminal:
    """A host that opened the port and spoke: the board reset and greeted it."""
    terminal = Terminal(running.open())
    await terminal.send("M79 S\"PL\"")
    lines = await terminal.read_until(lambda line: line.startswith("ok"))
    assert lines[0] == "start" and lines[-2] == GREETING_END
    return terminal


def only(lines: list[str]) -> list[str]:
    """A command's answer without its `ok`."""
    assert lines[-1] == "ok", lines
    return lines[:-1]


def d3_bytes(lines: list[str]) -> bytes:
    """What PrusaLink reads from a D3 answer: every dump line's bytes, joined."""
    assert lines[0] == "D3 - Read/Write EEPROM"
    data = ""
    for line in lines[1:]:
        match = D3_OUTPUT_REGEX.match(line)
        if match:
            data += match["data"].replace(" ", "")
    return bytes.fromhex(data)


def test_the_profile_loads_and_every_serial_number_is_prusas_and_the_printers_own():
    profile = load_profile("prusa")
    assert profile.reset_on_open and profile.bootloader and profile.halt.reboot_after > 0
    for seed in (0, 7):
        serials = [Firmware.make(profile, seed=seed, number=n).identity.serial
                   for n in (*range(1, 200), 9_999, 10_000, 99_999)]
        assert all(VALID_SN_REGEX.match(serial) for serial in serials), serials
        assert len(set(serials)) == len(serials)
    first, other = (Firmware.make(profile, seed=seed).identity.serial for seed in (0, 1))
    assert first != other


async def test_prusalinks_probe_finds_the_version_and_the_type(autojump_clock):
    async with memory_printer(firmware="prusa") as running:
        terminal = Terminal(running.open())
        assert await terminal.quiet_for(8) == []  # the greeting waits for the host's bytes
        await terminal.stream.send_all(b"PRUSA Fir\nM862.2 Q\n")  # one write, as PrusaLink
        lines = await terminal.read_until(lambda line: PRINTER_TYPE_REGEX.match(line) is not None,
                                          timeout=2)
        assert lines[:5] == ["start", "echo: 3.14.1-8237_000000000", "MMU is Off",
                             "SpoolJoin is Off", " External Reset"]
        assert "ok" not in lines[:lines.index(GREETING_END) + 1]  # no `ok` at the end of boot
        version = next(FW_REGEX.match(line)["version"] for line in lines if FW_REGEX.match(line))
        assert version == "3.14.1-8237"
        assert lines[-1] == "302" and await terminal.read_line() == "ok"


async def test_m115_is_3_13s_form_with_the_printers_uuid(autojump_clock):
    async with memory_printer(firmware="prusa", seed=5) as running:
        terminal = await booted(running)
        lines = only(await terminal.command("M115"))
        uuid = running.server.firmware.identity.uuid
        assert lines == [
            "FIRMWARE_NAME:Prusa-Firmware 3.14.1+8237_000000000 based on Marlin FIRMWARE_URL:"
            "https://github.com/prusa3d/Prusa-Firmware PROTOCOL_VERSION:1.0 MACHINE_TYPE:Prusa i3 "
            f"MK3S EXTRUDER_COUNT:1 UUID:{uuid}",
            "Cap:AUTOREPORT_TEMP:1", "Cap:AUTOREPORT_FANS:1", "Cap:AUTOREPORT_POSITION:1",
            "Cap:EXTENDED_M20:1", "Cap:PRUSA_MMU2:1"]
        assert only(await terminal.command("M115 V")) == ["3.14.1"]
        assert await terminal.command("M115 U3.14.1") == ["ok"]


async def test_every_poll_of_prusalink_is_answered_as_it_reads_it(autojump_clock, tmp_path):
    async with memory_printer(firmware="prusa", sd_dir=tmp_path) as running:
        terminal = await booted(running)
        assert NOZZLE_REGEX.match(only(await terminal.command("M862.1 Q"))[0])["size"] == "0.40"
        assert only(await terminal.command("M862.3 Q")) == ["MK3S"]
        assert only(await terminal.command("M862.4 Q")) == ["3.14.1"]
        assert only(await terminal.command("M862.5 Q")) == ["1"]
        assert await terminal.command('M862.3 P "MK3S"') == ["ok"]  # a check that passes is silent
        (serial,) = only(await terminal.command("PRUSA SN"))
        assert VALID_SN_REGEX.match(serial) and serial == running.server.firmware.identity.serial
        assert only(await terminal.command("PRUSA Rev")) == ["1_75mm_MK3S-EINSy_10a-E3Dv6full"]
        assert M27_OUTPUT_REGEX.match(only(await terminal.command("M27 P"))[0])["no_print"]
        for code in ("M220", "M221"):
            assert PERCENT_REGEX.match(only(await terminal.command(code))[0])["percent"] == "100"
        info = [PRINT_INFO_REGEX.match(line) for line in only(await terminal.command("M73"))]
        assert [(m["mode"], m["progress"], m["remaining"]) for m in info] == [
            ("NORMAL", "-1", "-1"), ("SILENT", "-1", "-1")]
        # The sheets, as _get_sheet_settings() decodes them: 8 x 11 bytes.
        sheets = d3_bytes(await terminal.command("D3 AxD49 C88"))
        assert len(sheets) == 88
        names = [sheets[i:i + 7].decode("ascii") for i in range(0, 88, 11)]
        assert names == ["Smooth1", "Smooth2", "Textur1", "Textur2", "Satin  ", "NylonPA",
                         "Custom1", "Custom2"]
        assert struct.unpack_from("<h", sheets, 7)[0] / 400 == -0.875
        assert d3_bytes(await terminal.command("D3 AxDA1 C1")) == b"\x00"  # the active sheet
        assert d3_bytes(await terminal.command("D3 AxFFF C1")) == b"\x00"  # normal mode
        assert d3_bytes(await terminal.command("D3 AxFBB C1")) == b"\x00"  # no FlashAir
        assert d3_bytes(await terminal.command("D3 AxFF1 C4")) == bytes(4)  # filament
        assert d3_bytes(await terminal.command("D3 AxFED C4")) == bytes(4)  # print time
        assert only(await terminal.command("M420")) == ["Mesh bed leveling not active."]
        assert MBL_REGEX.match("Mesh bed leveling not active.")
        assert SD_PRESENT_REGEX.match(only(await terminal.command("M21"))[0])["ok"]
        listing = only(await terminal.command("M20 LT"))
        assert listing == ["Begin file list", "End file list"]
        for command in ("M72 S0", "M72 S1", 'M79 S"PL"', "M552 P192.0.2.2", "M300 P14 S50",
                        "M75", "M76", "M77", "M400", "M110 N0"):
            assert await terminal.command(command) == ["ok"], command
        assert only(await terminal.command("M72")) == ["PrinterState: 1"]
        assert await terminal.command("M117 ~PrusaLink OK.") == ["LCD status changed", "ok"]


async def test_the_job_id_write_reads_back_and_the_eeprom_outlives_a_reset(autojump_clock):
    async with memory_printer(firmware="prusa") as running:
        terminal = await booted(running)
        assert int(d3_bytes(await terminal.command("D3 AxD05 C4")).hex(), 16) == 0
        assert only(await terminal.command(f"D3 Ax0D05 X{7:08x}")) == [
            "D3 - Read/Write EEPROM", "4 bytes written to EEPROM at address 0x0d05",
            "000d05  00 00 00 07"]
        assert int(d3_bytes(await terminal.command("D3 AxD05 C4")).hex(), 16) == 7
        await terminal.command("M73 P42 R10")
        again = await booted(running)  # the host opens the port again: the board resets
        assert int(d3_bytes(await again.command("D3 AxD05 C4")).hex(), 16) == 7
        assert only(await again.command("M73"))[0].startswith("NORMAL MODE: Percent done: -1;")
        assert board(running.server.printer).eeprom[EEPROM_JOB_ID + 3] == 7


async def test_d3_reads_sixteen_bytes_a_line_from_where_it_starts(autojump_clock):
    async with memory_printer(firmware="prusa") as running:
        terminal = await booted(running)
        lines = only(await terminal.command("D3 Ax0d05 C20"))
        assert [line[:8] for line in lines[1:]] == ["000d05  ", "000d15  "]
        assert len(lines[1].split()) == 17 and len(lines[2].split()) == 5
        assert only(await terminal.command("D3 Ax0ffe")) == ["D3 - Read/Write EEPROM",
                                                            "000ffe  ff 00"]  # to the end
        assert only(await terminal.command("D3 Ax1000 C4")) == ["D3 - Read/Write EEPROM"]


async def test_m155_c7_reports_temperatures_and_positions_as_prusalink_reads_them(autojump_clock):
    async with memory_printer(firmware="prusa") as running:
        terminal = await booted(running)
        assert await terminal.command("M155 S2 C7") == ["ok"]
        heard = await terminal.quiet_for(5)
        assert len(heard) == 6
        assert all(TEMPERATURE_REGEX.match(line) for line in heard[0::2])
        assert all(POSITION_REGEX.match(line) for line in heard[1::2])
        await terminal.command("M155 S1")  # no C: temperatures only
        assert all(TEMPERATURE_REGEX.match(line) for line in await terminal.quiet_for(3))
        await terminal.command("M155 S0")
        await terminal.quiet_for(2)
        (answer,) = await terminal.command("M105")
        assert answer.startswith("ok T:") and TEMPERATURE_REGEX.match(answer[3:])
        assert POSITION_REGEX.match(only(await terminal.command("M114"))[0])
        assert FAN_REGEX.match(only(await terminal.command("M123"))[0])


async def test_a_print_as_prusalink_sends_it(autojump_clock):
    async with memory_printer(firmware="prusa") as running:
        terminal = await booted(running)
        for command in (f"D3 Ax0D05 X{1:08x}", "M400", "M110 N0", "M75"):
            await terminal.command(command)
        job = ["G90", "M83", "G28 W", "G1 X10.00 Y20.00 E0.10 F1500", "G1 X12.00 Y20.00 E0.10"]
        for n, gcode in enumerate(job, start=1):
            body = f"N{n} {gcode} "  # PrusaLink's own form: a space before the `*`
            checksum = 0
            for byte in body.encode():
                checksum ^= byte
            lines = await terminal.command(f"{body}*{checksum}")
            assert lines[-1] == "ok" and not any(line.startswith("Error") for line in lines)
        info = only(await terminal.command("M73 Q42 S0 C-1 P42 R0 D-1"))
        assert [PRINT_INFO_REGEX.match(line)["progress"] for line in info] == ["42", "42"]
        assert await terminal.command("M77") == ["ok"]
        assert running.journal[-7:] == [*job, "M73 Q42 S0 C-1 P42 R0 D-1", "M77"]


async def test_numbers_too_large_or_none_are_what_the_firmware_makes_of_them(autojump_clock):
    async with memory_printer(firmware="prusa") as running:
        terminal = await booted(running)
        # code_value() is strtod's (1e999 and nan are numbers), cast to an integer as avr-gcc
        # casts: 0 for what 32 bits cannot hold; NaN is not <= 0 (C and D), so it is cast too.
        assert only(await terminal.command("M73 S1e999 R1e999 C1e999 Dnan")) == [
            "NORMAL MODE: Percent done: -1; print time remaining in mins: 0; Change in mins: 0",
            "SILENT MODE: Percent done: -1; print time remaining in mins: 0; Change in mins: 0"]
        # code_value_uint8() is strtol's: the digits up to the first that is not one.
        assert only(await terminal.command("M73 P1e2 Q1e999"))[0].startswith(
            "NORMAL MODE: Percent done: 1;")
        assert await terminal.command("M72 S1e999") == ["ok"]
        assert only(await terminal.command("M72")) == ["PrinterState: 1"]
        assert await terminal.command("M220 S1e999") == ["ok"]  # code_value_short(): 1
        assert only(await terminal.command("M220")) == ["1%"]
        assert only(await terminal.command("D3 A1e999 C2"))[1].startswith("000000  ")
        assert await terminal.command("M155 S1e999") == ["ok"]  # a period of 1 s
        heard = await terminal.quiet_for(3.5)  # at once, then each second
        assert len(heard) == 4 and all(TEMPERATURE_REGEX.match(line) for line in heard)
        assert await terminal.command("M155 S0 C" + "9" * 400) == ["ok"]  # LONG_MAX: 0xff


async def test_line_errors_ask_for_the_line_again_and_a_repeat_is_one(autojump_clock):
    async with memory_printer(firmware="prusa") as running:
        terminal = await booted(running)
        await terminal.command("N0 M110 N0*125")
        assert await terminal.command("N1 G28*99") == [
            "Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok"]
        assert (await terminal.command(numbered(1, "G90")))[-1] == "ok"
        assert await terminal.command(numbered(1, "G90")) == [
            "Error:Line Number is not Last Line Number+1, Last Line: 1", "Resend: 2", "ok"]
        assert await terminal.command("N2 G90") == [
            "Error:No Checksum with line number, Last Line: 1", "Resend: 2", "ok"]
        assert await terminal.command("G90*3") == [
            "Error:No Line Number with checksum, Last Line: 1", "Resend: 2", "ok"]
        assert await terminal.command("G90") == ["ok"]  # numbers are optional


async def test_unknown_commands_in_prusas_words(autojump_clock):
    async with memory_printer(firmware="prusa") as running:
        terminal = await booted(running)
        assert await terminal.command("M999") == ["Unknown M code: M999", "ok"]
        assert await terminal.command("G99 X1") == ["Unknown G code: G99 X1", "ok"]
        assert await terminal.command("D99") == ["Unknown D code: D99", "ok"]
        assert await terminal.command("Mfoo") == ["Invalid M code: Mfoo", "ok"]
        assert await terminal.command("m105") == ['echo:Unknown command: "m105"(2)', "ok"]
        assert await terminal.command("FOO") == ['echo:Unknown command: "FOO"(2)', "ok"]
        assert await terminal.command("PRUSA whatever") == ["ok"]
        assert await terminal.command("T1") == ["echo:T49", "Invalid extruder", "ok"]


async def test_m112_reboots_the_printer(autojump_clock):
    async with memory_printer(firmware="prusa") as running:
        terminal = await booted(running)
        await terminal.send("M112")
        assert await terminal.quiet_for(3) == ["Error:Printer halted. kill() called!",
                                               "M112 called. Emergency Stop."]
        lines = await terminal.command("M105")  # the new boot greets the host's next bytes
        assert lines[0] == "start" and " Watchdog Reset" in lines
        assert lines[-1].startswith("ok T:")
        assert running.server.boots == 3  # power-up, the host's open, the watchdog


async def test_prusa_reset_reboots_without_an_ok(autojump_clock):
    async with memory_printer(firmware="prusa") as running:
        terminal = await booted(running)
        await terminal.send("PRUSA RESET")
        assert await terminal.quiet_for(3) == []
        lines = await terminal.command("M105")
        assert lines[0] == "start" and " Watchdog Reset" in lines


async def test_a_thermal_error_stops_the_printer_until_it_is_reset(autojump_clock):
    async with memory_printer(firmware="prusa") as running:
        terminal = await booted(running)
        server = running.server
        rule = FaultRule(FaultKind.MINTEMP, Trigger(nth=1), heater="B")
        server.announce(failures.apply(server.printer, printer_failure(rule), trio.current_time()))
        lines = await terminal.quiet_for(1)
        assert lines == ["LCD status changed", "Error:Heaters switched off. MINTEMP BED triggered!",
                         "//action:cancel",
                         "Error:Printer stopped due to errors. Supervision required."]
        assert ERROR_REASON_REGEX.search(lines[1])["bed"]
        await terminal.send("M105")
        assert await terminal.quiet_for(5) == []  # Stopped: dropped, no answer
        assert server.boots == 2  # no reboot
        again = await booted(running)  # DTR: the only way back
        assert (await again.command("M105"))[0].startswith("ok T:")


async def test_m109_and_m190_wait_as_prusa_does(autojump_clock):
    async with memory_printer(firmware="prusa") as running:
        terminal = await booted(running)
        lines = await terminal.command("M109 S200")
        assert lines[0] == "LCD status changed" and lines[-2:] == ["LCD status changed", "ok"]
        waits = [line for line in lines if line.startswith("T:")]
        assert all(HEATING_HOTEND_REGEX.match(line) for line in waits)
        assert waits[0].endswith("W:?") and [w[-1] for w in waits[-3:]] == ["2", "1", "0"]
        assert "echo:busy: processing" in lines
        lines = await terminal.command("M190 S60")
        waits = [line for line in lines if line.startswith("T:")]
        assert waits and all(HEATING_REGEX.match(line) for line in waits)
        assert re.fullmatch(r"T:\d+\.\d\d E:0 B:\d+\.\d", waits[0])


async def test_pause_resume_and_stop_say_prusalinks_actions(autojump_clock):
    async with memory_printer(firmware="prusa") as running:
        terminal = await booted(running)
        await terminal.command("M75")
        assert await terminal.command("M601") == ["//action:paused", "LCD status changed", "ok"]
        assert M27_OUTPUT_REGEX.match(only(await terminal.command("M27 P"))[0])["serial_paused"]
        assert await terminal.command("M602") == ["LCD status changed", "//action:resumed", "ok"]
        assert only(await terminal.command("M27 P")) == ["Not SD printing"]
        assert await terminal.command("M603") == ["//action:cancel", "ok"]


async def test_the_card_as_prusa_lists_and_prints_it(autojump_clock, tmp_path: Path):
    (tmp_path / "cube.gcode").write_text("G28\nG4 S300\nM400\n")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "Long Name.gcode").write_text("G1 X1\n")
    (tmp_path / "notes.txt").write_text("not G-code\n")
    async with memory_printer(firmware="prusa", sd_dir=tmp_path) as running:
        terminal = await booted(running)
        listing = only(await terminal.command("M20 LT"))
        assert all(LFN_CAPTURE.match(line) for line in listing)
        assert [re.sub(r" 0x[0-9a-f]+", "", line) for line in listing] == [
            "Begin file list", 'CUBE~1.GCO 17 "cube.gcode"', 'DIR_ENTER: /SUB/ "sub"',
            '/SUB/LONGNA~1.GCO 6 "Long Name.gcode"', "DIR_EXIT", "End file list"]
        assert only(await terminal.command("M20")) == [
            "Begin file list", "CUBE~1.GCO 17", "/SUB/LONGNA~1.GCO 6", "End file list"]
        assert only(await terminal.command("M23 cube~1.gco")) == [
            "echo:Now fresh file: cube~1.gco", "File opened: /cube.gcode Size: 17",
            "File selected", "LCD status changed"]
        await terminal.command("M24")
        await terminal.quiet_for(60)  # in G4 S300: M27 waits for it, as the firmware's queue does
        status = [line for line in only(await terminal.command("M27 P"))
                  if not line.startswith("echo:busy")]
        assert status == ["/cube.gcode", "SD printing byte 12/17", "0:5"]  # h:m, not h:mm
        assert [M27_OUTPUT_REGEX.match(line) is not None for line in status] == [True, True, False]
        await terminal.quiet_for(1)
        assert only(await terminal.command("M27")) == ["Not SD printing"]
        failed = only(await terminal.command("M23 missing.gco"))
        assert failed[-1] == "open failed, File: missing.gco."


async def test_m20_t_says_the_fat_time_in_utc_whatever_the_machines_time_zone(
        autojump_clock, tmp_path: Path, monkeypatch):
    (tmp_path / "cube.gcode").write_text("G28\n")
    (tmp_path / "old.gcode").write_text("G28\n")
    os.utime(tmp_path / "cube.gcode", (1_700_000_000, 1_700_000_000))  # 2023-11-14 22:13:20 UTC
    os.utime(tmp_path / "old.gcode", (0, 0))  # 1970: before FAT's first day
    monkeypatch.setenv("TZ", "JST-9")
    time.tzset()
    try:
        async with memory_printer(firmware="prusa", sd_dir=tmp_path) as running:
            terminal = await booted(running)
            assert only(await terminal.command("M20 T")) == [
                "Begin file list", "CUBE~1.GCO 4 0x576eb1aa", "OLD~1.GCO 4 0x210000",
                "End file list"]
    finally:
        monkeypatch.undo()
        time.tzset()


async def test_m29_ends_the_upload_without_an_ok(autojump_clock, tmp_path: Path):
    async with memory_printer(firmware="prusa", sd_dir=tmp_path) as running:
        terminal = await booted(running)
        await terminal.command("N0 M110 N0*125")
        opened = only(await terminal.command(numbered(1, "M28 up.gco")))
        assert opened[1] == "Writing to file: /up.gco"
        assert await terminal.command(numbered(2, "G1 X5")) == ["ok"]
        await terminal.send(numbered(3, "M29"))
        assert await terminal.quiet_for(2) == ["Done saving file."]
        assert (tmp_path / "up.gco").read_bytes() == b"G1 X5\r\n"


@pytest.mark.parametrize("code", ["M108", "M154", "M410", "M876 S1"])
async def test_what_prusa_firmware_has_not(autojump_clock, code):
    async with memory_printer(firmware="prusa") as running:
        terminal = await booted(running)
        assert await terminal.command(code) == [f"Unknown M code: {code}", "ok"]
