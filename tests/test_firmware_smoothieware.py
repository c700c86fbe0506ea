"""Smoothieware (edge bb41e99, the 3D-printer build) on its USB serial, byte for byte, in memory
on trio's autojump clock: what a host hears from `--firmware smoothieware`."""

import re
from contextlib import asynccontextmanager
from pathlib import Path

import trio

from fake_marlin.emulator.printer import failures
from fake_marlin.emulator.printer.failures import Failure, FailureKind
from fake_marlin.testing import memory_printer
from tests.terminal import RawPort, numbered

GREETING = b"Smoothie\r\nok\r\n"
IDLE_TEMPERATURES = b"ok T:21.0 /0.0 @0 B:21.0 /0.0 @0 \n"
M115 = (b"FIRMWARE_NAME:Smoothieware, FIRMWARE_URL:http%3A//smoothieware.org, "
        b"X-SOURCE_CODE_URL:https://github.com/Smoothieware/Smoothieware, "
        b"FIRMWARE_VERSION:edge-b23f4f7, PROTOCOL_VERSION:1.0, "
        b"X-FIRMWARE_BUILD_DATE:Jul 31 2023 15:24:13, X-SYSTEM_CLOCK:120MHz, X-AXES:5, "
        b"X-GRBL_MODE:0, X-ARCS:1, X-CNC:0, X-MSD:1\nok\n")
WAITING_LINE = re.compile(rb"T:\d+\.\d /200\.0 @255\n")


@asynccontextmanager
async def smoothie(sd_dir: Path | None = None, **options):
    if sd_dir is not None:
        options["sd_dir"] = sd_dir
    async with memory_printer(firmware="smoothieware", **options) as printer:
        port = RawPort(printer.open(), quiet=5.0)
        assert await port.quiet_for(1) == GREETING
        yield port, printer


# -- connecting ---------------------------------------------------------------------------------
async def test_opening_the_port_says_smoothie_and_ok_and_resets_nothing(autojump_clock):
    async with smoothie() as (port, printer):
        assert await port.ask("G1 X12.5 Y3 F3000") == b"ok\n"
        assert await port.ask(numbered(0, "M105")) == IDLE_TEMPERATURES
        again = RawPort(printer.open(), quiet=5.0)  # a second open: the board runs on
        assert await again.quiet_for(1) == GREETING
        assert await again.ask("M114") == b"ok C: X:12.5000 Y:3.0000 Z:0.0000 E:0.0000 \n"
        # the line counter ran on too: N0 again is not the next line
        assert await again.ask(numbered(0, "M105")) == b"rs N1\n"
        assert printer.server.boots == 1


async def test_m115_is_one_line_without_capabilities(autojump_clock):
    async with smoothie() as (port, _):
        assert await port.ask("M115") == M115


async def test_m105_and_m114_answer_on_the_ok_line_with_a_trailing_space(autojump_clock):
    async with smoothie() as (port, _):
        assert await port.ask("M105") == IDLE_TEMPERATURES
        await port.ask("G92 X1 Y2 Z3 E4")
        assert await port.ask("M114") == b"ok C: X:1.0000 Y:2.0000 Z:3.0000 E:4.0000 \n"
        assert await port.ask("M114.1") == b"ok WCS: X:1.0000 Y:2.0000 Z:3.0000 E:4.0000 \n"
        assert await port.ask("M114.2") == b"ok MCS: X:1.0000 Y:2.0000 Z:3.0000\n"


async def test_m105_says_the_heater_power_as_raw_pwm(autojump_clock):
    async with smoothie() as (port, _):
        assert await port.ask("M140 S60") == b"ok\n"
        answer = await port.ask("M105")
        assert re.fullmatch(rb"ok T:21\.0 /0\.0 @0 B:\d+\.\d /60\.0 @255 \n", answer), answer


# -- temperatures ---------------------------------------------------------------------------------
async def test_m109_says_the_waiting_heater_once_a_second_then_ok(autojump_clock):
    async with smoothie() as (port, _):
        start = trio.current_time()
        await port.send("M109 S200")
        said = await port.read_until(b"ok\n")
        took = trio.current_time() - start
        lines = said.splitlines(keepends=True)
        assert lines[-1] == b"ok\n"
        assert lines[:-1] and all(WAITING_LINE.fullmatch(line) for line in lines[:-1]), lines
        assert int(took) == len(lines) - 1  # one a second, the first after a second
        assert 40 < took < 80  # to 200 C, with no residency
        holding = await port.ask("M105")  # at target: the power that holds it there
        assert re.fullmatch(rb"ok T:200\.0 /200\.0 @(\d+) B:21\.0 /0\.0 @0 \n", holding), holding


async def test_m190_says_the_bed_only_and_m109_never_waits_to_cool(autojump_clock):
    async with smoothie() as (port, _):
        await port.send("M190 S40")
        said = await port.read_until(b"ok\n")
        assert said.startswith(b"B:") and b"/40.0 @255\n" in said and b"T:" not in said
        start = trio.current_time()
        assert await port.ask("M190 S30", seconds=0.5) == b"ok\n"  # hotter already: no wait
        assert trio.current_time() - start < 1


async def test_m104_waits_for_the_moves_before_it(autojump_clock):
    async with smoothie() as (port, printer):
        await port.send("G1 X200 F600")  # 20 s of travel
        assert await port.read_until(b"ok\n") == b"ok\n"
        start = trio.current_time()
        await port.send("M104 S200")
        assert await port.read_until(b"ok\n") == b"ok\n"
        assert trio.current_time() - start > 15  # wait_for_idle first
        assert printer.server.printer.hotends[0].target == 200.0


async def test_there_are_no_busy_lines(autojump_clock):
    async with smoothie() as (port, _):
        await port.ask("G92 X200 Y200 Z100")  # far from the endstops: a long homing
        start = trio.current_time()
        assert await port.ask("G28", seconds=30) == b"ok\n"
        assert trio.current_time() - start > 15


# -- what it does not know -----------------------------------------------------------------------
async def test_unknown_g_and_m_codes_get_ok_stray_words_ok_ignored(autojump_clock):
    async with smoothie() as (port, printer):
        assert await port.ask("M9999 S1") == b"ok\n"
        assert await port.ask("M155 S2") == b"ok\n"
        assert await port.ask("G99") == b"ok\n"
        assert await port.ask("E5") == b"ok - ignored\n"
        assert await port.ask("HELLO") == b"ok - ignored\n"
        assert await port.ask("") == b"ok\n"
        assert await port.ask("; a comment") == b"ok\n"
        assert await port.quiet_for(5) == b""  # M155 reports nothing
        assert "M9999 S1" in printer.journal


async def test_lower_case_lines_are_console_commands_without_ok(autojump_clock):
    async with smoothie() as (port, _):
        assert await port.ask("hello") == b"error:Unsupported command - hello\n"
        assert await port.ask("g28") == b"error:Unsupported command - g28\n"
        assert await port.ask("version") == (
            b"Build version: edge-b23f4f7, Build date: Jul 31 2023 15:24:13, MCU: LPC1769, "
            b"System Clock: 120MHz\r\n5 axis\n")
        assert await port.ask("echo hi there") == b"echo: hi there\r\n"
        assert await port.ask("M1000 VERSION") == (
            b"Build version: edge-b23f4f7, Build date: Jul 31 2023 15:24:13, MCU: LPC1769, "
            b"System Clock: 120MHz\r\n5 axis\nok\n")
        assert await port.ask("M1000 nothing") == b"Command not found: nothing\nok\n"
        assert await port.ask("$Q") == b"error:Invalid statement\n"
        assert await port.ask("$G") == (
            b"[GC:G0 G54 G17 G21 G90 G94 M0 M5 M9 T0 F1500.0 S0.0000]\nok\n")


# -- line numbers and checksums -------------------------------------------------------------------
async def test_the_first_numbered_line_is_n0_and_a_bad_one_draws_rs_alone(autojump_clock):
    async with smoothie() as (port, printer):
        assert await port.ask(numbered(1, "G28")) == b"rs N0\n"
        assert await port.ask(numbered(0, "G28")) == b"ok\n"
        assert await port.ask("N1 G28*99") == b"rs N1\n"  # a wrong checksum: no ok, no Error
        assert await port.ask(numbered(0, "G28")) == b"rs N1\n"  # a repeat is no exception
        assert await port.ask("N1 M105") == IDLE_TEMPERATURES  # no `*`: taken as it is
        assert await port.ask("M105") == IDLE_TEMPERATURES  # no N: never checked
        assert await port.ask(numbered(2, "M105")) == IDLE_TEMPERATURES
        assert printer.journal.count("G28") == 1


async def test_m110_counts_only_on_a_numbered_line_and_before_any_check(autojump_clock):
    async with smoothie() as (port, printer):
        assert await port.ask("N5 M110 N5*0") == b"ok\n"  # the checksum is never looked at
        assert await port.ask(numbered(6, "M105")) == IDLE_TEMPERATURES
        assert await port.ask("M110 N0") == b"ok\n"  # without a number: the counter stays
        assert await port.ask(numbered(1, "M105")) == b"rs N7\n"
        assert await port.ask("N-1 M110 N-1*125") == b"ok\n"  # printcore's reset
        assert await port.ask(numbered(0, "M105")) == IDLE_TEMPERATURES
        # OctoPrint's hello: N0, then N1 is next
        assert await port.ask("N0 M110 N0*125") == b"ok\n"
        assert await port.ask(numbered(1, "M105")) == IDLE_TEMPERATURES
        assert "M110 N5" not in printer.journal  # it runs nothing


async def test_lines_after_a_bad_one_are_each_asked_again(autojump_clock):
    async with smoothie() as (port, printer):
        await port.ask(numbered(0, "M105"))
        await port.send(f"N1 G1 X5*0\n{numbered(2, 'G1 X6')}\n{numbered(3, 'G1 X7')}\n".encode())
        assert await port.quiet_for(5) == b"rs N1\nrs N1\nrs N1\n"
        assert not any(line.startswith("G1") for line in printer.journal)


async def test_crlf_is_one_line_end(autojump_clock):
    async with smoothie() as (port, _):
        assert await port.ask(b"M105\r\n") == IDLE_TEMPERATURES
        assert await port.ask(b"\n\n") == b"ok\nok\n"  # two blank lines
        assert await port.ask(b"M105\r") == IDLE_TEMPERATURES
        assert await port.ask(b"\nM105\n") == IDLE_TEMPERATURES  # the \n of that \r\n


async def test_a_job_is_printed_exactly_once_through_a_resend(autojump_clock):
    job = ["G28", "M104 S0"] + [f"G1 X{n % 50}.5 Y{n % 7}.25 E{n * 0.1:.2f} F3000"
                                 for n in range(60)] + ["M400"]
    async with smoothie() as (port, printer):
        assert await port.ask("N0 M110 N0*125") == b"ok\n"
        number = 1
        index = 0
        corrupted = False
        while index < len(job):
            line = numbered(number, job[index])
            if index == 30 and not corrupted:  # one line damaged on the way
                corrupted = True
                line = line.replace("G1", "G2", 1)
            await port.send(line)
            answer = await port.read_until(b"\n")
            if answer.startswith(b"rs N"):
                assert answer == f"rs N{number}\n".encode()
                continue
            assert answer == b"ok\n", answer
            number += 1
            index += 1
        assert printer.journal == job


# -- ok before G1 runs ----------------------------------------------------------------------------
async def test_g1_is_acknowledged_before_the_planner_has_room(autojump_clock):
    async with smoothie() as (port, printer):
        room = printer.server.printer.room(trio.current_time())
        moves = [f"G1 X{100 * (n % 2)} F600" for n in range(room + 3)]  # 10 s each
        at_once = 0
        for move in moves:
            start = trio.current_time()
            await port.send(move)
            assert await port.read_until(b"ok\n") == b"ok\n"
            if trio.current_time() - start > 1:
                break
            at_once += 1
            assert printer.journal[-1] == move  # in the journal as its `ok` goes
        # The planner takes the move it runs and `room` more (Marlin acknowledges those at once);
        # the one after them is acknowledged at once too, and waits for room: the line after
        # it is not read until it has.
        assert at_once == room + 2
        assert printer.journal == moves[:room + 3]


# -- halts ----------------------------------------------------------------------------------------
async def test_m112_halts_until_m999_and_answers_most_commands_with_bangs(autojump_clock):
    async with smoothie() as (port, printer):
        await port.ask("M104 S200")
        assert await port.ask("M112") == (
            b"ok Emergency Stop Requested - reset or M999 required to exit HALT state\n")
        assert printer.server.printer.hotends[0].target == 0.0
        assert await port.ask("G28") == b"!!\n"  # no ok
        assert await port.ask("M104 S200") == b"!!\n"
        assert re.fullmatch(rb"ok T:\d+\.\d /0\.0 @0 B:21\.0 /0\.0 @0 \n",
                            await port.ask("M105"))  # on the allow-list
        assert await port.ask("M115") == M115
        assert await port.ask("E5") == b"ok - ignored\n"
        assert await port.ask("version") != b"!!\n"
        assert await port.ask("M999") == (
            b"WARNING: After HALT you should HOME as position is currently unknown\nok\n")
        assert await port.ask("G28") == b"ok\n"
        assert await port.ask("M999") == b"ok\n"  # not halted: only ok
        assert printer.server.boots == 1


async def test_dollar_x_clears_a_halt_and_says_nothing_otherwise(autojump_clock):
    async with smoothie() as (port, printer):
        assert await port.ask("$X") == b""  # not halted: not even ok
        await port.ask("M112")
        assert await port.ask("$X") == b"[Caution: Unlocked]\nok\n"
        assert not printer.server.printer.halted
        await port.ask("M112")
        await port.ask("G92 X100")
        start = trio.current_time()
        assert await port.ask("$H") == b"ok\n"  # cleared, then homed, then ok
        assert trio.current_time() - start > 1
        assert await port.ask("M114") == b"ok C: X:0.0000 Y:0.0000 Z:0.0000 E:0.0000 \n"


async def test_ctrl_x_halts_at_once_even_while_a_command_waits(autojump_clock):
    async with smoothie() as (port, printer):
        await port.send("M109 S200")
        await port.read_until(b"@255\n")
        await port.send(b"\x18")
        assert await port.read_until(b"\r\n") == b"HALTED, M999 or $X to exit HALT state\r\n"
        assert printer.server.printer.halted
        assert await port.read_until(b"\n") == b"ok\n"  # the wait it cut short ends with ok
        assert "M109 S200" not in printer.journal
        assert await port.ask("G28") == b"!!\n"
        assert await port.ask("$X") == b"[Caution: Unlocked]\nok\n"


async def test_a_thermal_fault_halts_with_smoothies_words(autojump_clock):
    async with smoothie() as (port, printer):
        server = printer.server
        now = trio.current_time()
        server.announce(failures.apply(server.printer, Failure(FailureKind.MAXTEMP, "B"), now))
        assert await port.quiet_for(1) == (
            b"ERROR: MINTEMP or MAXTEMP triggered on B. Check your temperature sensors!\n"
            b"HALT asserted - reset or M999 required\n")
        assert await port.ask("G28") == b"!!\n"


# -- the status query -----------------------------------------------------------------------------
async def test_a_question_mark_is_answered_at_once_wherever_it_is(autojump_clock):
    async with smoothie() as (port, _):
        await port.send(b"?")  # no line end: it is no line
        assert await port.quiet_for(1) == (
            b"<Idle|MPos:0.0000,0.0000,0.0000,0.0000|WPos:0.0000,0.0000,0.0000|F:1500.0,100.0"
            b"|S:0.00|T:21.0,0.0|B:21.0,0.0>\n")
        await port.send("M109 S200")
        await port.read_until(b"@255\n")
        start = trio.current_time()
        await port.send("M1?05")  # while M109 holds the line: `?` now, M105 in its turn
        report = await port.read_until(b">\n")
        assert trio.current_time() - start < 0.5
        assert report.startswith(b"<Idle|") and b"|T:" in report and b",200.0|B:" in report
        rest = await port.read_until(b"B:21.0 /0.0 @0 \n")
        assert re.search(rb"@255\nok\nok T:200\.0 /200\.0 @\d+ B:21\.0 /0\.0 @0 \n$", rest), rest


# -- the SD card ----------------------------------------------------------------------------------
async def test_the_card_lists_lower_case_names_and_prints_a_file(autojump_clock, tmp_path):
    card = tmp_path / "sd"
    card.mkdir()
    (card / "Part One.GCODE").write_text("G28\nG1 X10 F3000\n")
    (card / "folder").mkdir()
    (card / "folder" / "inner.gcode").write_text("G28\n")
    async with smoothie(card) as (port, printer):
        assert await port.ask("M21") == b"SD card ok\r\nok\n"
        assert await port.ask("M20") == (
            b"Begin file list\r\nfolder/\r\npart one.gcode\r\nEnd file list\r\nok\n")
        assert await port.ask("M27") == b"Not currently playing\nok\n"
        assert await port.ask("M23 part one.gcode") == (
            b"File opened:/sd/part one.gcode Size:17\r\nFile selected\r\nok\n")
        assert await port.ask("M27") == b"SD printing byte 0/17\r\nok\n"
        await port.send("M24")
        assert await port.read_until(b"Done printing file\r\n") == b"ok\nDone printing file\r\n"
        assert printer.journal[-2:] == ["G28", "G1 X10 F3000"]
        assert await port.ask("M27") == b"Not currently playing\nok\n"
        assert await port.ask("M23 nothing.gcode") == b"file.open failed: /sd/nothing.gcode\r\nok\n"
        assert await port.ask("M30 nothing.gcode") == b"Could not delete /sd/nothing.gcode \r\nok\n"
        assert await port.ask("M30 part one.gcode") == b"ok\n"
        assert not (card / "Part One.GCODE").exists()
        assert await port.ask("ls -s /sd") == b"folder/\r\n"


async def test_a_broken_link_or_a_link_loop_on_the_card_is_a_file_not_there(
        autojump_clock, tmp_path):
    card = tmp_path / "sd"
    card.mkdir()
    (card / "part.gcode").write_text("G28\n")
    (card / "gone.gcode").symlink_to(card / "nowhere.gcode")
    (card / "loop.gcode").symlink_to(card / "loop.gcode")
    async with smoothie(card) as (port, _):
        assert await port.ask("ls -s /sd") == b"part.gcode 4\r\n"
        assert await port.ask("M20") == b"Begin file list\r\npart.gcode\r\nEnd file list\r\nok\n"
        for name in ("gone.gcode", "loop.gcode"):
            assert await port.ask(f"M23 {name}") == f"file.open failed: /sd/{name}\r\nok\n".encode()
            assert await port.ask(f"M30 {name}") == f"Could not delete /sd/{name} \r\nok\n".encode()


async def test_m28_writes_the_lines_that_follow_to_the_card(autojump_clock, tmp_path):
    card = tmp_path / "sd"
    card.mkdir()
    async with smoothie(card) as (port, printer):
        assert await port.ask("M28 new.gcode") == b"Writing to file: /sd/new.gcode\nok\n"
        assert await port.ask("G28") == b"ok\n"  # stored, not run (no line number needed)
        assert await port.ask("M29") == b"Done saving file.\nok\n"
        assert "G28" not in printer.journal
        assert (card / "new.gcode").read_text().split() == ["G28"]


# -- host actions ---------------------------------------------------------------------------------
async def test_m600_suspends_with_an_action_and_m601_resumes(autojump_clock):
    async with smoothie() as (port, printer):
        await port.ask("M104 S200")
        await port.send("M600")
        said = await port.quiet_for(2)
        assert said == (b"// Suspending print, waiting for queue to empty...\n"
                        b"// action:pause\r\nok\n"
                        b"// Waiting for queue to empty (Host must stop sending)...\n"
                        b"// Saving current state...\n"
                        b"// Print Suspended, enter resume to continue printing\n")
        assert printer.server.printer.hotends[0].target == 0.0  # saved and turned off
        assert await port.ask("M600") == b"Already suspended\nok\n"
        await port.send("M601")
        resumed = await port.read_until(b"ok\n")
        assert resumed.startswith(b"// resuming print...\n// Waiting for heaters...\n")
        assert resumed.endswith(b"// Restoring saved XYZ positions and state...\n"
                                b"// Resuming print\n// action:resume\r\nok\n")
        assert printer.server.printer.hotends[0].target == 200.0
        assert await port.ask("M601") == b"Not suspended\nok\n"


async def test_m220_and_m221_say_their_factors(autojump_clock):
    async with smoothie() as (port, _):
        assert await port.ask("M220") == b"Speed factor at 100.00 %\nok\n"
        assert await port.ask("M221") == b"Flow rate at 100.00 %\nok\n"


async def test_m503_and_m500_m501_keep_the_settings_in_config_override(autojump_clock, tmp_path):
    card = tmp_path / "sd"
    card.mkdir()
    async with smoothie(card) as (port, printer):
        shown = await port.ask("M503")
        assert shown.startswith(b"; No config override\n;Steps per unit:\nM92 X80.00000 Y80.00000 ")
        assert shown.endswith(b"M665 S0.00000 U0.00000\n\nok\n")  # add_nl: an empty line, then ok
        assert await port.ask("M501") == b"File not found: /sd/config-override\nok\n"
        await port.ask("M92 X100")
        assert await port.ask("M500") == b"Settings Stored to /sd/config-override\nok\n"
        assert (card / "config-override").read_text().startswith("; DO NOT EDIT THIS FILE\n")
        await port.ask("M92 X80")
        loaded = await port.ask("M501")
        assert loaded.startswith(b"Loading config override file: /sd/config-override...\n"
                                 b"  ; DO NOT EDIT THIS FILE\n")
        assert loaded.endswith(b"config override file executed\nok\n")
        assert printer.server.printer.limits.steps_per_mm[0] == 100.0  # its M92 ran
        assert (await port.ask("M503")).startswith(
            b"; config override present: /sd/config-override\n")
        assert await port.ask("M502") == (
            b"config override file deleted /sd/config-override, reboot needed\nok\n")
        assert not (card / "config-override").exists()


async def test_m119_ends_with_an_empty_line(autojump_clock):
    async with smoothie() as (port, _):
        assert await port.ask("M119") == (
            b"X_min:0 Y_min:0 Z_min:0 pins- (X)P1.24:0 (Y)P1.26:0 (Z)P1.28:0 \n\nok\n")


async def test_a_halt_aborts_the_cards_print(autojump_clock, tmp_path):
    card = tmp_path / "sd"
    card.mkdir()
    (card / "long.gcode").write_text("".join(f"G1 X{100 * (n % 2)} F600\n" for n in range(40)))
    async with smoothie(card) as (port, printer):
        await port.ask("M23 long.gcode")
        assert await port.ask("M24") == b"ok\n"
        status = await port.ask(b"?")
        assert status.startswith(b"<Run|") and b"|SD:" in status, status
        # (read once the card's move it waits behind has room: 10 s moves)
        assert await port.ask("M112", seconds=15) == (
            b"ok Emergency Stop Requested - reset or M999 required to exit HALT state\n")
        assert (await port.ask(b"?")).startswith(b"<Alarm|")
        assert await port.ask("M27") == b"!!\n"
        ran = len(printer.journal)
        await port.ask("M999")
        assert await port.ask("M27", seconds=30) == b"Not currently playing\nok\n"
        assert printer.journal[ran:] == ["M999", "M27"]  # the card's print is over


async def test_thermal_runaway_says_the_heater_and_how_far_off_it_was(autojump_clock):
    async with smoothie() as (port, printer):
        server = printer.server
        now = trio.current_time()
        server.announce(failures.apply(server.printer, Failure(FailureKind.THERMAL_RUNAWAY), now))
        assert await port.quiet_for(1) == (
            b"ERROR: Temperature runaway on T (delta temp 21.000000), HALT asserted, TURN POWER "
            b"OFF IMMEDIATELY - reset or M999 required\n")
        assert await port.ask("M105") == IDLE_TEMPERATURES


async def test_m600_while_printing_from_the_card_pauses_it_without_an_action(autojump_clock,
                                                                             tmp_path):
    card = tmp_path / "sd"
    card.mkdir()
    (card / "job.gcode").write_text("G4 S5\nG1 X10 F3000\n")
    async with smoothie(card) as (port, printer):
        await port.ask("M23 job.gcode")
        await port.send("M24")
        await port.read_until(b"ok\n")
        said = await port.ask("M600", seconds=10)
        assert b"action" not in said and said.startswith(b"// Suspending print")
        assert printer.journal[-1] == "M600"  # the card's G1 waits for the resume
        resumed = await port.ask("M601", seconds=10)
        assert resumed.endswith(b"// Resuming print\nok\nDone printing file\r\n")
        assert printer.journal[-2:] == ["M601", "G1 X10 F3000"]


async def test_a_halt_while_g1_waits_for_room_sends_no_second_ok(autojump_clock):
    async with smoothie() as (port, printer):
        room = printer.server.printer.room(trio.current_time())
        for n in range(room + 1):  # the one moving and `room` more
            await port.ask(f"G1 X{100 * (n % 2)} F600", seconds=0.5)
        await port.send("G1 X50 F600")
        assert await port.read_until(b"ok\n", timeout=1) == b"ok\n"  # before it has room
        await port.send(b"\x18")
        assert await port.quiet_for(20) == b"HALTED, M999 or $X to exit HALT state\r\n"
        assert await port.ask("M105") == IDLE_TEMPERATURES
