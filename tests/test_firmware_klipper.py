"""Klipper v0.13.0's G-code pseudo-terminal, byte for byte (profiles/klipper.toml and the
klipper command set): a printer in memory, driven line by line on trio's autojump clock."""

from contextlib import asynccontextmanager

import trio

from fake_marlin.testing import memory_printer
from tests.terminal import Terminal, numbered

COLD = "B:21.0 /0.0 T0:21.0 /0.0"  # M105's payload, heaters at ambient and off
SHUTDOWN = [
    "// Shutdown due to M112 command",
    "// Once the underlying issue is corrected, use the",
    '// "FIRMWARE_RESTART" command to reset the firmware, reload the',
    "// config, and restart the host software.",
    "// Printer is shutdown",
    "!! Shutdown due to M112 command",
]


@asynccontextmanager
async def klipper(tmp_path=None, **options):
    if tmp_path is not None:
        sd = tmp_path / "gcodes"
        sd.mkdir()
        options["sd_dir"] = sd
    async with memory_printer(firmware="klipper", **options) as printer:
        yield Terminal(printer.open()), printer


async def test_power_up_says_ready_to_nobody_and_an_open_says_nothing(autojump_clock):
    async with memory_printer(firmware="klipper") as printer:
        # What klippy wrote before any host had the pty open: a host that flushes never sees it.
        with trio.fail_after(1):
            assert await printer.link.host.receive_some() == b"// Klipper state: Ready\n"
        terminal = Terminal(printer.open())
        assert await terminal.quiet_for(10) == []  # no greeting, no reset on open
        assert await terminal.command("M105") == [f"ok {COLD}"]
        boots = printer.server.boots
        again = Terminal(printer.open())
        assert await again.quiet_for(10) == []
        assert printer.server.boots == boots  # the pty's open resets nothing


async def test_m115_is_one_line_on_the_ok_without_capabilities(autojump_clock):
    async with klipper() as (terminal, _):
        terminal.chunks.clear()
        assert await terminal.command("M115") == [
            "ok FIRMWARE_NAME:Klipper FIRMWARE_VERSION:v0.13.0-0-g61c0c8d2e"]
        assert b"".join(terminal.chunks) == (
            b"ok FIRMWARE_NAME:Klipper FIRMWARE_VERSION:v0.13.0-0-g61c0c8d2e\n")


async def test_m105_sorts_heaters_by_id_with_one_decimal_and_no_t_or_power(autojump_clock):
    async with klipper() as (terminal, _):
        assert await terminal.command("M105") == ["ok B:21.0 /0.0 T0:21.0 /0.0"]
        assert await terminal.command("M105 T0") == ["ok B:21.0 /0.0 T0:21.0 /0.0"]
        assert await terminal.command("m105") == [f"ok {COLD}"]  # read case-blind
    async with klipper(extruders=2) as (terminal, _):
        assert await terminal.command("M104 T1 S0") == ["ok"]
        assert await terminal.command("M105") == ["ok B:21.0 /0.0 T0:21.0 /0.0 T1:21.0 /0.0"]
        assert await terminal.command("M104 T2 S200") == ["!! Extruder not configured", "ok"]
        assert await terminal.command("M104 T2 S0") == ["ok"]  # nothing to turn off


async def test_m114_is_the_gcode_position_with_three_decimals(autojump_clock):
    async with klipper() as (terminal, _):
        await terminal.command("G28")
        await terminal.command("G1 X10 Y20.5 E1.25 F3000")
        assert await terminal.command("M114") == ["X:10.000 Y:20.500 Z:0.000 E:1.250", "ok"]


async def test_m109_prints_the_m105_payload_at_once_and_each_second_until_within_a_degree(
        autojump_clock):
    async with klipper() as (terminal, _):
        start = trio.current_time()
        await terminal.send("M109 S200")
        first = await terminal.read_line()
        assert first == "B:21.0 /0.0 T0:21.0 /200.0" and trio.current_time() == start
        lines = [first, *await terminal.read_until(lambda line: line == "ok")]
        took = trio.current_time() - start
        reports = lines[:-1]
        assert all(line.startswith("B:21.0 /0.0 T0:") and line.endswith(" /200.0")
                   for line in reports)
        assert len(reports) == round(took)  # one a second, the first at once
        assert 50 < took < 70  # within a degree, and no residency time after it
        assert abs(float(reports[-1].split("T0:")[1].split()[0]) - 200) > 1.0
        (line,) = await terminal.command("M105")
        assert line.startswith("ok B:21.0 /0.0 T0:19") or line.startswith("ok B:21.0 /0.0 T0:20")
        assert await terminal.command("M109 S0") == ["ok"]  # no wait for 0
        assert await terminal.command("M104 S300") == [
            "!! Requested temperature (300.0) out of range (0.0:285.0)", "ok"]


async def test_unknown_commands_are_an_info_line_with_the_upper_case_name(autojump_clock):
    async with klipper() as (terminal, _):
        assert await terminal.command("M155 S2") == ['// Unknown command:"M155"', "ok"]
        assert await terminal.command("m113 s0") == ['// Unknown command:"M113"', "ok"]
        assert await terminal.command("M999") == ['// Unknown command:"M999"', "ok"]
        assert await terminal.command("T0") == ['// Unknown command:"T0"', "ok"]
        assert await terminal.command("foo bar=1") == ['// Unknown command:"FOO"', "ok"]
        assert await terminal.command("M9999 S1") == ['// Unknown command:"M9999"', "ok"]


async def test_line_numbers_and_checksums_are_never_checked_and_nothing_is_resent(
        autojump_clock):
    async with klipper() as (terminal, printer):
        assert await terminal.command("N0 M110 N0*125") == ["ok"]
        assert await terminal.command("N7 G28*1") == ["ok"]  # out of turn, a wrong checksum
        assert await terminal.command("N3 G1 X5") == ["ok"]  # no checksum at all
        assert await terminal.command(numbered(4, "M105")) == [f"ok {COLD}"]
        assert await terminal.command("N5 M117 Hello*99") == ["ok"]
        assert await terminal.quiet_for(5) == []  # no Resend: ever
        assert printer.journal[-4:] == ["G28", "G1 X5", "M105", "M117 Hello"]


async def test_blank_and_comment_lines_get_an_ok_each_in_their_turn(autojump_clock):
    async with klipper() as (terminal, _):
        start = trio.current_time()
        terminal.chunks.clear()
        await terminal.stream.send_all(b"G4 P2000\n\n; just a comment\nM105\n")
        lines = await terminal.read_until(lambda line: line.startswith("ok B:"))
        assert lines == ["ok", "ok", "ok", f"ok {COLD}"]
        assert trio.current_time() - start >= 2  # the blank lines' oks wait behind G4's
        assert b"".join(terminal.chunks) == f"ok\nok\nok\nok {COLD}\n".encode()


async def test_no_busy_lines_while_a_command_waits(autojump_clock):
    async with klipper() as (terminal, _):
        await terminal.command("G92 X200 Y200 Z100")  # far from the endstops: a long homing
        start = trio.current_time()
        assert await terminal.command("G28") == ["ok"]
        assert trio.current_time() - start > 10
        assert await terminal.command("G4 P5000") == ["ok"]
        assert await terminal.command("G4 S5") == ["ok"]  # no S in Klipper: no dwell
        assert await terminal.command("G4 P-1") == [
            "!! Error on 'G4 P-1': P must have minimum of 0.0", "ok"]


async def test_m112_shuts_down_at_once_every_line_keeps_its_ok_and_firmware_restart_revives(
        autojump_clock):
    async with klipper() as (terminal, printer):
        await terminal.send("M109 S200")
        await terminal.read_line()  # waiting
        await terminal.stream.send_all(b"M105\nM112\n")  # M112 acts ahead of the M105
        lines = [await terminal.read_line() for _ in range(4)]
        assert lines[0] == "// Klipper state: Shutdown"
        assert lines[1] == "ok"  # M109's wait ended by the shutdown
        assert lines[2].startswith("ok B:") and lines[3] == "ok"  # M105, then M112's own ok
        assert "M112" in printer.journal and "M109 S200" not in printer.journal
        assert await terminal.command("G28") == [*SHUTDOWN, "ok"]
        assert await terminal.command("") == [*SHUTDOWN, "ok"]  # a blank line too
        assert await terminal.command("M999") == [*SHUTDOWN, "ok"]  # no way out but a restart
        assert (await terminal.command("M105"))[0].startswith("ok B:")
        assert await terminal.command("M115") == [
            "ok FIRMWARE_NAME:Klipper FIRMWARE_VERSION:v0.13.0-0-g61c0c8d2e"]
        assert await terminal.command("STATUS") == [
            *SHUTDOWN[:5], "// Klipper state: Not ready", SHUTDOWN[5], "ok"]
        assert await terminal.command("HELP") == [
            "// Printer is not ready - not all commands available.",
            "// Available extended commands:",
            "// FIRMWARE_RESTART: Restart firmware, host, and reload config",
            "// GET_POSITION: Return information on the current location of the toolhead",
            "// HELP      : Report the list of available extended G-Code commands",
            "// RESPOND   : Echo the message prepended with a prefix",
            "// RESTART   : Reload config file and restart host software",
            "// STATUS    : Report the printer status",
            "ok",
        ]
        boots = printer.server.boots
        assert await terminal.command("FIRMWARE_RESTART") == ["ok"]
        assert await terminal.read_until(lambda line: "Ready" in line) == [
            "// Klipper state: Disconnect", "// Klipper state: Ready"]
        assert printer.server.boots == boots + 1
        assert await terminal.command("G28") == ["ok"]
        assert await terminal.command("STATUS") == ["// Klipper state: Ready", "ok"]


async def test_restart_when_ready_turns_the_heaters_off_then_goes_down_and_up(autojump_clock):
    async with klipper() as (terminal, printer):
        await terminal.command("M104 S200")
        await terminal.command("G1 X50 F600")  # a move still under way
        start = trio.current_time()
        assert await terminal.command("RESTART") == ["ok"]
        assert trio.current_time() - start > 4  # the moves done and half a second's dwell
        assert await terminal.read_until(lambda line: "Ready" in line) == [
            "// Klipper state: Disconnect", "// Klipper state: Ready"]
        (line,) = await terminal.command("M105")
        assert line.endswith("/0.0") and " /0.0 T0:" in line
        assert await terminal.command("M114") == ["X:0.000 Y:0.000 Z:0.000 E:0.000", "ok"]
        assert await terminal.command("RESTART now") == ["!! Malformed command 'RESTART now'",
                                                         "ok"]
        assert await terminal.quiet_for(3) == []  # no restart for that one


async def test_extended_commands_hosts_send(autojump_clock):
    async with klipper() as (terminal, _):
        assert await terminal.command("status") == ["// Klipper state: Ready", "ok"]
        help_lines = await terminal.command("HELP")
        assert help_lines[0] == "// Available extended commands:"
        assert "// PAUSE     : Pauses the current print" in help_lines
        names = [line[3:].split(":")[0].strip() for line in help_lines[1:-1]]
        assert names == sorted(names) and "SET_GCODE_OFFSET" in names and help_lines[-1] == "ok"
        assert await terminal.command("SET_HEATER_TEMPERATURE HEATER=extruder TARGET=200") == ["ok"]
        assert await terminal.command("SET_HEATER_TEMPERATURE HEATER=heater_bed TARGET=60") == ["ok"]
        assert await terminal.command("M105") == ["ok B:21.0 /60.0 T0:21.0 /200.0"]
        assert await terminal.command("SET_HEATER_TEMPERATURE HEATER=chamber TARGET=40") == [
            "!! The value 'chamber' is not valid for HEATER", "ok"]
        assert await terminal.command("SET_HEATER_TEMPERATURE TARGET=40") == [
            "!! Error on 'SET_HEATER_TEMPERATURE TARGET=40': missing HEATER", "ok"]
        assert await terminal.command("TURN_OFF_HEATERS") == ["ok"]
        assert await terminal.command("M105") == [f"ok {COLD}"]
        await terminal.command("G28")
        assert await terminal.command("set_gcode_offset z=0.2") == ["ok"]
        assert await terminal.command("M114") == ["X:0.000 Y:0.000 Z:-0.200 E:0.000", "ok"]
        position = await terminal.command("GET_POSITION")
        assert position == [
            "// mcu: stepper_x:0 stepper_y:0 stepper_z:0",
            "// stepper: stepper_x:0.000000 stepper_y:0.000000 stepper_z:0.000000",
            "// kinematic: X:0.000000 Y:0.000000 Z:0.000000",
            "// toolhead: X:0.000000 Y:0.000000 Z:0.000000 E:0.000000",
            "// gcode: X:0.000000 Y:0.000000 Z:0.000000 E:0.000000",
            "// gcode base: X:0.000000 Y:0.000000 Z:0.200000 E:0.000000",
            "// gcode homing: X:0.000000 Y:0.000000 Z:0.200000",
            "ok",
        ]
        await terminal.command("G1 Z1")
        assert await terminal.command("M114") == ["X:0.000 Y:0.000 Z:1.000 E:0.000", "ok"]
        assert await terminal.command("PAUSE") == ["// action:paused", "ok"]
        assert await terminal.command("PAUSE") == ["// Print already paused", "ok"]
        assert await terminal.command("RESUME") == ["// action:resumed", "ok"]
        assert await terminal.command("RESUME") == [
            "// Print is not paused, resume aborted", "ok"]
        assert await terminal.command("CANCEL_PRINT") == ["// action:cancel", "ok"]
        assert await terminal.command("M117 Printing layer 1") == ["ok"]
        assert await terminal.command("M118 hello there") == ["echo: hello there", "ok"]
        assert await terminal.command('RESPOND TYPE=error MSG="no good"') == ["!! no good", "ok"]
        assert await terminal.command("ECHO MSG=hi") == ["// ECHO MSG=hi", "ok"]
        assert await terminal.command("ECHO hi") == ["!! Malformed command 'ECHO hi'", "ok"]
        assert await terminal.command("M220 S0") == [
            "!! Error on 'M220 S0': S must be above 0.0", "ok"]
        assert await terminal.command("G20") == [
            "!! Machine does not support G20 (inches) command", "ok"]
        assert await terminal.command("M119") == ["x:open y:open z:open", "ok"]


async def test_integers_are_pythons_int_of_the_text_as_klippy_reads_them(autojump_clock):
    async with klipper() as (terminal, _):
        # get_int(): MOVE=inf and MOVE=1.5 cannot be parsed (get_float() would take them).
        assert await terminal.command("SET_GCODE_OFFSET Z=1 MOVE=inf") == [
            "!! Error on 'SET_GCODE_OFFSET Z=1 MOVE=inf': unable to parse inf", "ok"]
        assert await terminal.command("SAVE_GCODE_STATE") == ["ok"]
        assert await terminal.command("RESTORE_GCODE_STATE MOVE=nan") == [
            "!! Error on 'RESTORE_GCODE_STATE MOVE=nan': unable to parse nan", "ok"]
        # A traditional command's letter is the text klippy split the line into.
        assert await terminal.command("M26 S1.5") == [
            "!! Error on 'M26 S1.5': unable to parse 1.5", "ok"]
        assert await terminal.command("M26 S-1") == [
            "!! Error on 'M26 S-1': S must have minimum of 0", "ok"]
        assert await terminal.command("M26 S" + "9" * 400) == ["ok"]  # Python's int: any size
        assert await terminal.command("M104 T" + "9" * 400 + " S200") == [
            "!! Extruder not configured", "ok"]
        assert await terminal.command("M104 T1e999 S200") == [  # T is `1`, E `999`
            "!! Extruder not configured", "ok"]
        assert await terminal.command("M104 T0 S0") == ["ok"]


async def test_virtual_sdcard_lists_selects_prints_and_refuses_to_write(tmp_path, autojump_clock):
    async with klipper(tmp_path) as (terminal, printer):
        cube = tmp_path / "gcodes" / "Cube.gcode"
        cube.write_text("G28\nG1 X10 F3000 ; go\n\nM400\n")
        size = cube.stat().st_size
        (tmp_path / "gcodes" / "a_long_name_for_a_part.gco").write_text("G28\n")
        (tmp_path / "gcodes" / ".hidden").write_text("x")
        assert await terminal.command("M21") == ["SD card ok", "ok"]
        assert await terminal.command("M20") == [
            "Begin file list", "a_long_name_for_a_part.gco 4", f"Cube.gcode {size}",
            "End file list", "ok"]
        assert await terminal.command("M27") == ["Not SD printing.", "ok"]
        assert await terminal.command("M23 /cube.GCODE") == [
            f"File opened:cube.GCODE Size:{size}", "File selected", "ok"]
        assert await terminal.command("M27") == [f"SD printing byte 0/{size}", "ok"]
        assert await terminal.command("M23 nothing.gcode") == ["!! Unable to open file", "ok"]
        await terminal.command("M23 Cube.gcode")
        assert await terminal.command("M24") == ["ok"]
        assert await terminal.command("M24") == ["!! SD busy", "ok"]
        done = await terminal.read_until(lambda line: line == "Done printing file")
        assert "ok" not in done  # the card's lines get no ok
        card = [line for line in printer.journal if line != "M24"]
        assert card[-4:] == ["M23 Cube.gcode", "G28", "G1 X10 F3000", "M400"]
        assert await terminal.command("M27") == ["Not SD printing.", "ok"]  # the file is closed
        assert await terminal.command("M28 up.gcode") == ["!! SD write not supported", "ok"]
        assert await terminal.command("M30 Cube.gcode") == ["!! SD write not supported", "ok"]
        assert cube.exists()


async def test_a_job_is_printed_once_in_order_as_octoprint_sends_it(autojump_clock):
    job = ["G28", "M104 S0"] + [f"G1 X{10 + i % 7}.5 Y{20 + i % 5} E{i * 0.1:.1f} F3000"
                                for i in range(50)] + ["M400"]
    async with klipper() as (terminal, printer):
        assert await terminal.command("N0 M110 N0*125") == ["ok"]
        for number, line in enumerate(job, start=1):
            assert await terminal.command(numbered(number, line)) == ["ok"]
        assert printer.journal == ["M110 N0", *job]
        assert await terminal.command("M114") == ["X:10.500 Y:24.000 Z:0.000 E:4.900", "ok"]
