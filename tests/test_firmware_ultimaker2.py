"""Ultimaker 2 Marlin (Ultimaker2Marlin 8698fb6a) on its USB serial, byte for byte, in memory on
trio's autojump clock: what a host hears from `--firmware ultimaker2`."""

import re

import trio

from fake_marlin.emulator.faults.rules import FaultKind, FaultRule, Trigger
from fake_marlin.emulator.printer.planner import MAX_MOVES
from fake_marlin.testing import memory_printer
from tests.terminal import RawPort, greeted_printer, numbered

SETTINGS = [
    b"echo:Steps per unit:",
    b"echo:  M92 X80.00 Y80.00 Z400.00 E500.00",
    b"echo:Maximum feedrates (mm/s):",
    b"echo:  M203 X300.00 Y300.00 Z40.00 E45.00",
    b"echo:Maximum Acceleration (mm/s2):",
    b"echo:  M201 X3000 Y3000 Z100 E10000",
    b"echo:Acceleration: S=acceleration, T=retract acceleration",
    b"echo:  M204 S3000.00 T3000.00",
    b"echo:Advanced variables: S=Min feedrate (mm/s), T=Min travel feedrate (mm/s), "
    b"B=minimum segment time (ms), X=maximum XY jerk (mm/s),  Z=maximum Z jerk (mm/s),  "
    b"E=maximum E jerk (mm/s)",
    b"echo:  M205 S0.00 T0.00 B20000 X20.00 Z0.40 E5.00",
    b"echo:Home offset (mm):",
    b"echo:  M206 X0.00 Y0.00 Z0.00",
    b"echo:PID settings:",
    b"echo:   M301 P22.20 I1.08 D114.00",
]
GREETING = b"\n".join([
    b"start",
    b"echo: External Reset",
    b"Marlin 1.0.0",
    b"echo: Last Updated: Jun 20 2018 12:00:00 | Author: Version DEV",
    b"Compiled: Jun 20 2018",
    b"echo: Free Memory: 1873  PlannerBufferBytes: 1232",
    b"echo:Stored settings retrieved",
    *SETTINGS,
    b"echo:SD card ok",
]) + b"\n"
M115 = (b"FIRMWARE_NAME:Marlin Ultimaker2; Sprinter/grbl mashup for gen6 "
        b"FIRMWARE_URL:http://github.com/Ultimaker PROTOCOL_VERSION:1.0 MACHINE_TYPE:Ultimaker "
        b"EXTRUDER_COUNT:1\nok\n")
IDLE = b"ok T:21.0 /0.0 B:21.0 /0.0 @:0 B@:0\n"
STOPPED = (b"Printer stopped due to errors. Fix the error and use M999 to restart. "
           b"(Temperature is reset. Set it after restarting)")


def ultimaker2(tmp_path=None, protocol: str = "marlin"):
    return greeted_printer("ultimaker2", GREETING, tmp_path, protocol)


async def test_the_greeting_is_marlin_1_0s_and_comes_with_every_open(autojump_clock):
    async with memory_printer(firmware="ultimaker2") as printer:  # --protocol auto
        port = RawPort(printer.open())
        # (auto: the board greets once the host's first byte says it speaks Marlin's lines)
        assert await port.ask("M105") == GREETING + IDLE
        assert printer.server.boots == 2  # power-up, then the host's open (DTR)
        again = RawPort(printer.open())
        assert await again.ask("M105") == GREETING + IDLE
        assert printer.server.boots == 3


async def test_m115_names_the_ultimaker2_without_capabilities(autojump_clock):
    async with ultimaker2() as (port, _):
        assert await port.ask("M115") == M115


async def test_m105_says_one_decimal_and_the_power(autojump_clock):
    async with ultimaker2() as (port, _):
        assert await port.ask("M105") == IDLE
        await port.command("M104 S200")
        await port.command("M140 S60")
        await trio.sleep(10)
        answer = await port.ask("M105")
        assert re.fullmatch(rb"ok T:\d+\.\d /200\.0 B:\d+\.\d /60\.0 @:127 B@:127\n", answer)


async def test_m114_has_no_spaces_and_counts_in_mm_where_the_steppers_are(autojump_clock):
    async with ultimaker2() as (port, _):
        assert await port.ask("M114") == b"X:0.00Y:0.00Z:0.00E:0.00 Count X: 0.00Y:0.00Z:0.00\nok\n"
        await port.command("G1 X100 F600")  # 10 s of travel
        await trio.sleep(5)
        moving = await port.command("M114")  # at once: no synchronize
        match = re.fullmatch(rb"X:100\.00Y:0\.00Z:0\.00E:0\.00 Count X: (\d+\.\d\d)Y:0\.00Z:0\.00\nok\n",
                             moving)
        assert match and 20 < float(match[1]) < 80
        await trio.sleep(10)
        assert await port.ask("M114") == (b"X:100.00Y:0.00Z:0.00E:0.00 Count X: 100.00Y:0.00Z:0.00\n"
                                          b"ok\n")


async def test_m109_says_t_e_and_w_each_second_and_waits_three_seconds(autojump_clock):
    async with ultimaker2() as (port, printer):
        start = trio.current_time()
        answer = await port.command("M109 S200")
        took = trio.current_time() - start
        *reports, ok = answer.decode().splitlines()
        assert ok == "ok" and reports
        assert all(re.fullmatch(r"T:\d+\.\d E:0 W:(\?|[0-3])", line) for line in reports), reports
        waits = [line.rsplit(":", 1)[1] for line in reports]
        counting = [wait for wait in waits if wait != "?"]
        # `?` until within TEMP_WINDOW 2, then TEMP_RESIDENCY_TIME 3's seconds left, counting down
        assert waits == ["?"] * (len(waits) - len(counting)) + counting
        assert counting and counting == sorted(counting, reverse=True) and len(counting) <= 3
        assert 50 < took < 70
        assert printer.server.printer.hotends[0].temperature(trio.current_time()) >= 198.0


async def test_m109_waits_for_a_hot_nozzle_to_cool_down_too(autojump_clock):
    async with ultimaker2() as (port, printer):
        await port.command("M109 S200")
        start = trio.current_time()
        answer = await port.command("M109 S150")
        assert trio.current_time() - start > 20
        assert re.fullmatch(rb"(T:\d+\.\d E:0 W:\?\n)+(T:15\d\.\d E:0 W:[0-3]\n)+ok\n", answer)
        assert printer.server.printer.hotends[0].temperature(trio.current_time()) <= 152.0


async def test_m190_says_the_hotend_with_two_decimals_and_stops_two_degrees_short(autojump_clock):
    async with ultimaker2() as (port, printer):
        answer = await port.command("M190 S60")
        *reports, ok = answer.decode().splitlines()
        assert ok == "ok" and len(reports) > 60
        assert all(re.fullmatch(r"T:21\.00 E:0 B:\d+\.\d", line) for line in reports), reports[:3]
        bed = printer.server.printer.bed.temperature(trio.current_time())
        assert 58.0 <= bed < 59.5  # no residency: done once within TEMP_WINDOW 2


async def test_an_unknown_m_code_just_gets_ok_and_a_line_without_g_m_or_t_is_unknown(autojump_clock):
    async with ultimaker2() as (port, _):
        assert await port.ask("M9999 S1") == b"ok\n"
        assert await port.ask("M155 S2") == b"ok\n"  # no autoreport in this firmware
        assert await port.quiet_for(5) == b""
        assert await port.ask("HELLO") == b'echo:Unknown command: "HELLO"\nok\n'


async def test_a_bad_checksum_asks_for_a_resend(autojump_clock):
    async with ultimaker2() as (port, printer):
        assert await port.command(numbered(1, "G28")) == b"ok\n"
        assert await port.ask("N2 G28*7") == (b"Error:checksum mismatch, Last Line: 1\n"
                                              b"Resend: 2\nok\n")
        assert await port.ask("N2 G28") == (b"Error:No Checksum with line number, Last Line: 1\n"
                                            b"Resend: 2\nok\n")
        # A repeat is no resend the firmware let pass: a wrong line number like any other.
        assert await port.ask(numbered(1, "G28")) == (
            b"Error:Line Number is not Last Line Number+1, Last Line: 1\nResend: 2\nok\n")
        assert printer.journal.count("G28") == 1


async def test_a_checksum_without_a_line_number_is_an_error_with_no_resend_and_no_ok(autojump_clock):
    async with ultimaker2() as (port, printer):
        assert await port.ask("M105*36") == b"Error:No Line Number with checksum, Last Line: 0\n"
        assert "M105" not in printer.journal
        assert await port.ask("M105") == IDLE  # the line after it is read as ever


async def test_moves_get_their_ok_before_they_run(autojump_clock):
    async with ultimaker2() as (port, printer):
        waits = []
        for n in range(MAX_MOVES + 2):
            start = trio.current_time()
            assert await port.command(f"G1 X{100 - (n % 2) * 100} F600") == b"ok\n"  # 10 s each
            waits.append(trio.current_time() - start)
        # The planner holds MAX_MOVES: the move after them is answered at once all the same
        # (the firmware's `ok` as it queued the line), and the one after that waits for room.
        assert max(waits[:MAX_MOVES + 1]) < 0.1 and waits[MAX_MOVES + 1] > 5


async def test_no_busy_lines_while_homing(autojump_clock):
    async with ultimaker2() as (port, _):
        await port.command("G92 X200 Y200 Z100")
        start = trio.current_time()
        assert await port.command("G28") == b"ok\n"
        assert trio.current_time() - start > 10


async def test_m112_is_no_emergency_stop(autojump_clock):
    async with ultimaker2() as (port, printer):
        assert await port.ask("M112") == b"ok\n"
        assert not printer.server.printer.halted
        assert await port.ask("M105") == IDLE


async def test_maxtemp_stops_the_printer_until_m999(autojump_clock):
    async with ultimaker2() as (port, printer):
        await port.command("M104 S200")
        await port.command(numbered(1, "G28"))
        printer.server.fire_printer_fault(FaultRule(FaultKind.MAXTEMP, Trigger(nth=1)))
        assert await port.quiet_for(2) == (b"Error:0\n: Extruder switched off. MAXTEMP triggered !\n"
                                           b"Error:" + STOPPED + b"\n")
        # It reads on: a move is refused with the text (no Error:) and `ok`, the rest runs.
        assert await port.ask(numbered(2, "G1 X10")) == STOPPED + b"\nok\n"
        assert re.fullmatch(rb"ok T:\d+\.\d /0\.0 B:21\.0 /0\.0 @:0 B@:0\n", await port.ask("M105"))
        assert await port.ask("M114") == b"X:0.00Y:0.00Z:0.00E:0.00 Count X: 0.00Y:0.00Z:0.00\nok\n"
        assert await port.quiet_for(10) == b""  # no watchdog reboot: Stop() is no kill()
        # M999: Resend (FlushSerialRequestResend) and its `ok`, then the command's.
        assert await port.ask("M999") == b"Resend: 3\nok\nok\n"
        assert await port.ask(numbered(3, "G1 X10")) == b"ok\n"
        assert printer.journal.count("G1 X10") == 1


async def test_sd_card_lists_dos_names_opens_and_saves(autojump_clock, tmp_path):
    async with ultimaker2(tmp_path) as (port, printer):
        (tmp_path / "sd" / "TEST.GCO").write_text("G28\nG1 X10\n")
        (tmp_path / "sd" / "a long name.gcode").write_text("G28\n")
        listing = await port.ask("M20")
        assert listing == b"Begin file list\nTEST.GCO\nALONGN~1.GCO\nEnd file list\nok\n"
        assert await port.ask("M20 L") == listing  # no long names in this firmware
        assert await port.ask("M23 TEST.GCO") == b"File opened: TEST.GCO Size: 11\nFile selected\nok\n"
        assert await port.ask("M28 new.gco") == b"Writing to file: new.gco\nok\n"
        assert await port.ask("G1 X5") == b"ok\n"  # written, not run
        assert await port.ask("M29") == b"Done saving file.\n"  # and no `ok`
        assert (tmp_path / "sd" / "new.gco").read_bytes() == b"G1 X5\r\n"
        assert "G1 X5" not in printer.journal
        assert await port.ask("M30 NEW.GCO") == b"File deleted:NEW.GCO\nok\n"
        assert not (tmp_path / "sd" / "new.gco").exists()
        assert await port.ask("M30 NONE.GCO") == b"Deletion failed, File: NONE.GCO.\nok\n"


async def test_m503_says_the_settings_as_marlin_1_0(autojump_clock):
    async with ultimaker2() as (port, _):
        await port.command("M92 X100")
        settings = list(SETTINGS)
        settings[1] = b"echo:  M92 X100.00 Y80.00 Z400.00 E500.00"
        assert await port.ask("M503") == b"\n".join(settings) + b"\nok\n"


async def test_a_job_of_moves_is_printed_once_each_in_order(autojump_clock):
    job = ["G28", "M104 S0"] + [f"G1 X{10 + n % 7}.5 Y{20 + n % 5}.25 E{n * 0.05:.2f} F3000"
                                for n in range(50)] + ["M400"]
    async with ultimaker2() as (port, printer):
        await port.command("N0 M110 N0*125")
        for n, line in enumerate(job, start=1):
            assert await port.command(numbered(n, line)) == b"ok\n"
        assert [line for line in printer.journal if line != "M110 N0"] == job
