"""Marlin 1.1.9 (stock configuration, an AVR board with SD, a heated bed and EEPROM) byte for byte,
in memory on trio's autojump clock: what a host hears from `--firmware marlin-1.1`."""

import re

import trio

from fake_marlin.emulator.faults.rules import FaultKind, FaultRule, Trigger
from fake_marlin.testing import memory_printer
from tests.terminal import RawPort, greeted_printer, numbered

REPORT = [
    b"echo:  G21    ; (mm)",
    b"",
    b"echo:Filament settings: Disabled",
    b"echo:  M200 D3.00",
    b"echo:  M200 D0",
    b"echo:Steps per unit:",
    b"echo:  M92 X80.00 Y80.00 Z400.00 E500.00",
    b"echo:Maximum feedrates (units/s):",
    b"echo:  M203 X300.00 Y300.00 Z40.00 E45.00",
    b"echo:Maximum Acceleration (units/s2):",
    b"echo:  M201 X3000 Y3000 Z100 E10000",
    b"echo:Acceleration (units/s2): P<print_accel> R<retract_accel> T<travel_accel>",
    b"echo:  M204 P3000.00 R3000.00 T3000.00",
    b"echo:Advanced: Q<min_segment_time_us> S<min_feedrate> T<min_travel_feedrate> "
    b"X<max_x_jerk> Y<max_y_jerk> Z<max_z_jerk> E<max_e_jerk>",
    b"echo:  M205 Q20000 S0.00 T0.00 X10.00 Y10.00 Z0.30 E5.00",
    b"echo:Home offset:",
    b"echo:  M206 X0.00 Y0.00 Z0.00",
    b"echo:PID settings:",
    b"echo:  M301 P22.20 I1.08 D114.00",
]
GREETING = b"\n".join([
    b"start",
    b"echo: External Reset",
    b"Marlin 1.1.9",
    b"",
    b"echo: Last Updated: 2018-08-01 | Author: (none, default config)",
    b"echo:Compiled: Sep 22 2018",
    b"echo: Free Memory: 4992  PlannerBufferBytes: 1232",
    b"echo:V55 stored settings retrieved (621 bytes; crc 47016)",
    *REPORT,
    b"echo:SD card ok",
]) + b"\n"
CAPABILITIES = [
    ("SERIAL_XON_XOFF", 0), ("EEPROM", 1), ("VOLUMETRIC", 1), ("AUTOREPORT_TEMP", 1),
    ("PROGRESS", 0), ("PRINT_JOB", 1), ("AUTOLEVEL", 0), ("Z_PROBE", 0), ("LEVELING_DATA", 0),
    ("BUILD_PERCENT", 0), ("SOFTWARE_POWER", 0), ("TOGGLE_LIGHTS", 0),
    ("CASE_LIGHT_BRIGHTNESS", 0), ("EMERGENCY_PARSER", 0), ("AUTOREPORT_SD_STATUS", 0),
    ("THERMAL_PROTECTION", 1),
]
IDLE = b"ok T:21.00 /0.00 B:21.00 /0.00 @:0 B@:0\n"
KILLED = b"Error:Printer halted. kill() called!\n"


def marlin_1_1(tmp_path=None):
    return greeted_printer("marlin-1.1", GREETING, tmp_path)


async def test_the_greeting_has_echo_before_the_reset_a_blank_line_and_the_settings(autojump_clock):
    async with memory_printer(firmware="marlin-1.1") as printer:  # --protocol auto
        port = RawPort(printer.open())
        # (auto: the board greets once the host's first byte says it speaks Marlin's lines)
        assert await port.ask("M105") == GREETING + IDLE
        again = RawPort(printer.open())  # DTR resets the board: the greeting again
        assert await again.ask("M105") == GREETING + IDLE
        assert printer.server.boots == 3


async def test_m115_has_no_date_and_the_16_capabilities_of_1_1_9(autojump_clock):
    async with marlin_1_1() as (port, printer):
        uuid = printer.server.firmware.identity.uuid
        expected = (b"FIRMWARE_NAME:Marlin 1.1.9 (Github) SOURCE_CODE_URL:https://github.com/"
                    b"MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 MACHINE_TYPE:3D Printer 1 "
                    b"EXTRUDER_COUNT:1 UUID:" + uuid.encode() + b"\n")
        expected += b"".join(b"Cap:%s:%d\n" % (name.encode(), value) for name, value in CAPABILITIES)
        assert await port.ask("M115") == expected + b"ok\n"


async def test_m105_and_m114(autojump_clock):
    async with marlin_1_1() as (port, _):
        assert await port.ask("M105") == IDLE
        assert await port.ask("M114") == b"X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0\nok\n"
        await port.command("G1 X10 Y5 F3000")
        await trio.sleep(2)
        assert await port.ask("M114") == b"X:10.00 Y:5.00 Z:0.00 E:0.00 Count X:800 Y:400 Z:0\nok\n"
        await port.command("M104 S200")
        await trio.sleep(5)
        assert re.fullmatch(rb"ok T:\d+\.\d\d /200\.00 B:21\.00 /0\.00 @:127 B@:0\n",
                            await port.ask("M105"))


async def test_m109_reports_each_second_with_busy_lines_between_and_waits_ten_seconds(autojump_clock):
    async with marlin_1_1() as (port, _):
        start = trio.current_time()
        lines = (await port.command("M109 S200")).decode().splitlines()
        took = trio.current_time() - start
        assert lines[-1] == "ok"
        reports = [line for line in lines[:-1] if line != "echo:busy: processing"]
        busy = lines.count("echo:busy: processing")
        assert all(re.fullmatch(r" T:\d+\.\d\d /200\.00 B:21\.00 /0\.00 @:\d+ B@:0 W:(\?|\d)", line)
                   for line in reports), reports
        assert reports[0].endswith(" W:?") and reports[-1][-4:] in (" W:0", " W:1")
        waits = [line.rsplit(":", 1)[1] for line in reports if not line.endswith("?")]
        assert len(waits) >= 9 and waits == sorted(waits, reverse=True)  # 10 s within 1 degree
        assert abs(busy - took / 2) <= 1  # BUSY_WHILE_HEATING: every 2 s, between them


async def test_m108_does_not_end_a_heat_up_wait_without_the_emergency_parser(autojump_clock):
    async with marlin_1_1() as (port, _):
        await port.send("M190 S60")
        await port.read_until(b"W:?\n")
        await port.send("M108")  # read only when M190 is done: it ends no wait
        start = trio.current_time()
        await port.read_until_ok()
        assert trio.current_time() - start > 60
        assert await port.ask("M105") != b""


async def test_unknown_commands_and_those_1_1_9_lacks_are_echoed(autojump_clock):
    async with marlin_1_1() as (port, _):
        assert await port.ask("M9999 S1") == b'echo:Unknown command: "M9999 S1"\nok\n'
        assert await port.ask("M876 S1") == b'echo:Unknown command: "M876 S1"\nok\n'
        assert await port.ask("M154 S1") == b'echo:Unknown command: "M154 S1"\nok\n'
        assert await port.ask(numbered(1, "M524")) == b'echo:Unknown command: "M524"\nok\n'


async def test_line_errors_ask_for_a_resend_and_a_repeat_is_no_exception(autojump_clock):
    async with marlin_1_1() as (port, printer):
        assert await port.command(numbered(1, "G92 X1")) == b"ok\n"
        assert await port.ask("N2 G28*7") == (b"Error:checksum mismatch, Last Line: 1\n"
                                              b"Resend: 2\nok\n")
        assert await port.ask("N2 G28") == (b"Error:No Checksum with line number, Last Line: 1\n"
                                            b"Resend: 2\nok\n")
        assert await port.ask(numbered(1, "G92 X1")) == (
            b"Error:Line Number is not Last Line Number+1, Last Line: 1\nResend: 2\nok\n")
        assert printer.journal.count("G92 X1") == 1 and "G28" not in printer.journal
        # A checksum without a line number is taken (1.1.9 has no such error).
        assert await port.ask("M105*36") == IDLE


async def test_m112_kills_with_one_line_and_nothing_revives_it_but_a_reset(autojump_clock):
    async with marlin_1_1() as (port, printer):
        assert await port.ask("M112", 5) == KILLED  # no echo:M112 Shutdown, no //action:
        assert await port.ask("M105", 5) == b""
        assert await port.ask("M999", 10) == b""  # kill() reads nothing more: no reboot either
        again = RawPort(printer.open())
        assert await again.read_until(b"echo:SD card ok\n") == GREETING
        assert await again.ask("M105") == IDLE


async def test_thermal_runaway_kills(autojump_clock):
    async with marlin_1_1() as (port, printer):
        printer.server.fire_printer_fault(FaultRule(FaultKind.THERMAL_RUNAWAY, Trigger(nth=1),
                                                    heater="B"))
        assert await port.quiet_for(2) == (b"Error:Thermal Runaway, system stopped! Heater_ID: bed\n"
                                           + KILLED)
        assert await port.ask("M105", 5) == b""


async def test_m999_answers_resend_and_two_oks(autojump_clock):
    async with marlin_1_1() as (port, _):
        await port.command(numbered(1, "M105"))
        assert await port.ask("M999") == b"Resend: 2\nok\nok\n"


async def test_busy_lines_every_two_seconds_while_homing_and_m113(autojump_clock):
    async with marlin_1_1() as (port, _):
        await port.command("G92 X200 Y200 Z100")
        start = trio.current_time()
        lines = (await port.command("G28")).decode().splitlines()
        took = trio.current_time() - start
        assert lines[-1] == "ok" and lines[:-1] == ["echo:busy: processing"] * int(took // 2)
        assert await port.ask("M113") == b"echo:M113 S2\nok\n"
        await port.command("M113 S0")
        await port.command("G92 X200 Y200 Z100")
        assert await port.command("G28") == b"ok\n"


async def test_sd_card_says_now_fresh_file_and_sizes_without_long_names(autojump_clock, tmp_path):
    async with marlin_1_1(tmp_path) as (port, printer):
        (tmp_path / "sd" / "TEST.GCO").write_text("G28\nG1 X10\n")
        (tmp_path / "sd" / "a long name.gcode").write_text("G28\n")
        listing = await port.ask("M20")
        assert listing == b"Begin file list\nTEST.GCO 11\nALONGN~1.GCO 4\nEnd file list\nok\n"
        assert await port.ask("M20 L") == listing
        assert await port.ask("M23 TEST.GCO") == (b"echo:Now fresh file: TEST.GCO\n"
                                                  b"File opened: TEST.GCO Size: 11\n"
                                                  b"File selected\nok\n")
        assert await port.ask("M27") == b"Not SD printing\nok\n"
        assert await port.ask("M27 C") == b"Current file: TEST.GCO\nok\n"
        assert await port.ask("M28 new.gco") == (b"echo:Now fresh file: new.gco\n"
                                                 b"Writing to file: new.gco\nok\n")
        assert await port.ask(numbered(1, "G1 X5")) == b"ok\n"
        assert await port.ask("M29") == b"Done saving file.\nok\n"
        assert await port.ask("M30 NEW.GCO") == b"File deleted:NEW.GCO\nok\n"
        assert await port.ask("M22") == b"ok\n"  # release() says nothing
        assert await port.ask("M21") == b"echo:SD card ok\nok\n"


async def test_m503_says_the_settings_in_1_1_9s_words(autojump_clock):
    async with marlin_1_1() as (port, _):
        await port.command("M92 X100")
        report = list(REPORT)
        report[6] = b"echo:  M92 X100.00 Y80.00 Z400.00 E500.00"
        assert await port.ask("M503") == b"\n".join(report) + b"\nok\n"
        assert re.fullmatch(rb"echo:Settings Stored \(621 bytes; crc \d+\)\nok\n",
                            await port.ask("M500"))
        assert await port.ask("M502") == b"echo:Hardcoded Default Settings Loaded\nok\n"


async def test_a_job_of_moves_is_printed_once_each_in_order(autojump_clock):
    job = ["G28", "M104 S0"] + [f"G1 X{10 + n % 7}.5 Y{20 + n % 5}.25 E{n * 0.05:.2f} F3000"
                                for n in range(50)] + ["M400"]
    async with marlin_1_1() as (port, printer):
        await port.command("N0 M110 N0*125")
        for n, line in enumerate(job, start=1):
            answer = await port.command(numbered(n, line))
            assert answer.endswith(b"ok\n") and set(answer.splitlines()[:-1]) <= {
                b"echo:busy: processing"}
        assert printer.journal == ["M110 N0", *job]
