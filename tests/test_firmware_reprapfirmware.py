"""RepRapFirmware 3.5.3 on a Duet 3 MB6HC over native USB, byte for byte
(profiles/reprapfirmware.toml and the reprapfirmware command set): a printer in memory, driven
line by line on trio's autojump clock."""

import json
import re
from contextlib import asynccontextmanager

import trio

from fake_marlin.emulator.printer.failures import Failure, FailureKind, apply
from fake_marlin.testing import memory_printer
from tests.terminal import Terminal as Wire, numbered

COLD = "T:21.0 /0.0 T0:21.0 /0.0 B:21.0 /0.0"  # M105's payload, T0 selected, heaters off
M115 = (b"FIRMWARE_NAME: RepRapFirmware for Duet 3 MB6HC FIRMWARE_VERSION: 3.5.3 "
        b"ELECTRONICS: Duet 3 MB6HC v1.02b or later FIRMWARE_DATE: 2024-09-18 12:00:00\nok\n")
REPORT = re.compile(r"T:\d+\.\d /\d+\.\d T0:\d+\.\d /\d+\.\d B:\d+\.\d /\d+\.\d")


@asynccontextmanager
async def duet(tmp_path=None, **options):
    if tmp_path is not None:
        sd = tmp_path / "gcodes"
        sd.mkdir()
        options["sd_dir"] = sd
    async with memory_printer(firmware="reprapfirmware", **options) as printer:
        yield Wire(printer.open()), printer


# -- connecting and identity ---------------------------------------------------------------
async def test_power_up_and_an_open_say_nothing_and_reset_nothing(autojump_clock):
    async with memory_printer(firmware="reprapfirmware") as printer:
        with trio.move_on_after(5):  # nothing went out at power-up either (DTR was low)
            assert await printer.link.host.receive_some() == b""
        wire = Wire(printer.open())
        assert await wire.quiet_for(10) == []
        boots = printer.server.boots
        assert await wire.exchange("M105") == f"ok {COLD}\n".encode()
        again = Wire(printer.open())
        assert await again.quiet_for(10) == []
        assert printer.server.boots == boots  # native USB: an open is no reset


async def test_m115_names_the_firmware_for_octoprint_with_no_capability_lines(autojump_clock):
    async with duet() as (wire, _):
        assert await wire.exchange("M115") == M115
        assert "reprapfirmware" in M115.decode().split("FIRMWARE_VERSION")[0].lower()


async def test_m105_is_on_the_ok_line_with_one_decimal_and_the_tool_first(autojump_clock):
    async with duet() as (wire, _):
        assert await wire.exchange("M105") == b"ok T:21.0 /0.0 T0:21.0 /0.0 B:21.0 /0.0\n"
        await wire.command("M104 S200")
        await wire.command("M140 S60")
        assert await wire.exchange("m105") == b"ok T:21.0 /200.0 T0:21.0 /200.0 B:21.0 /60.0\n"
    async with duet(extruders=2) as (wire, _):
        assert await wire.exchange("M105") == (
            b"ok T:21.0 /0.0 T0:21.0 /0.0 T1:21.0 /0.0 B:21.0 /0.0\n")


async def test_m114_has_three_decimals_e0_with_one_counts_and_machine_position(autojump_clock):
    async with duet() as (wire, _):
        assert await wire.exchange("M114") == (
            b"X:0.000 Y:0.000 Z:0.000 E:0.000 E0:0.0 Count 0 0 0 Machine 0.000 0.000 0.000 "
            b"Bed comp 0.000\nok\n")
        await wire.command("G92 X10 Y20.5 Z1 E2")
        assert await wire.exchange("M114") == (
            b"X:10.000 Y:20.500 Z:1.000 E:2.000 E0:2.0 Count 800 1640 400 Machine 10.000 20.500 "
            b"1.000 Bed comp 0.000\nok\n")


# -- errors and the line protocol ----------------------------------------------------------
async def test_unknown_codes_warn_and_other_lines_are_bad_commands(autojump_clock):
    async with duet() as (wire, _):
        assert await wire.exchange("M9999 S1") == b"Warning: M9999: Command is not supported\nok\n"
        assert await wire.exchange("G999") == b"Warning: G999: Command is not supported\nok\n"
        # Marlin's codes RRF has no case for: OctoPrint's probes among them
        assert await wire.exchange("M155 S2") == b"Warning: M155: Command is not supported\nok\n"
        assert await wire.exchange("M876 S1") == b"Warning: M876: Command is not supported\nok\n"
        assert await wire.exchange("X10 Y5") == b"Error: Bad command: X10 Y5\nok\n"
        assert await wire.exchange("M") == b"Error: Bad command: M\nok\n"
        assert await wire.exchange("M26") == b"Error: M26: missing parameter 'S'\nok\n"
        assert await wire.exchange('M118 S"hello"') == b"hello\nok\n"
        assert await wire.exchange("M118 Shello") == (
            b"Error:  at column 7: M118: expected a string expression\nok\n")


async def test_a_number_that_is_none_is_stringparsers_error_and_one_too_large_its_limit(
        autojump_clock):
    async with duet() as (wire, _):
        # StrToI32 and SafeStrtof find no number: GCodeException's message, column and code.
        assert await wire.exchange("M20 Sabc") == (
            b"Error:  at column 6: M20: expected number after 'S'\nok\n")
        assert await wire.exchange('M291 P"x" Tnan') == (
            b"Error:  at column 12: M291: expected number after 'T'\nok\n")
        assert await wire.exchange("M555 Pinf") == (
            b"Error:  at column 7: M555: expected number after 'P'\nok\n")
        assert await wire.exchange("M26 S-1") == (  # GetUIValue: no sign
            b"Error:  at column 6: M26: expected number after 'S'\nok\n")
        # An integer is read up to what is not a digit: S1e999 is S1 (Marlin's list).
        assert await wire.exchange("M20 S1e999") == await wire.exchange("M20")
        assert await wire.exchange("M555 P1e999") == b"ok\n"
        assert await wire.exchange("M555") == b"Output mode: RepRapFirmware\nok\n"
        # Too large for 32 bits: the type's limit (and M555 the last compatibility).
        assert await wire.exchange("M555 P" + "9" * 40) == b"ok\n"
        assert await wire.exchange("M555") == b"Output mode: NanoDLP\nok\n"
        assert await wire.exchange('M291 P"x" S0 T1e999') == b"x\nok\n"  # a float: infinite
        assert await wire.exchange("M562 P" + "9" * 40) == b"ok\n"
        assert await wire.exchange("M20 S2 R" + "9" * 40) == (
            b'{"dir":"0:/gcodes/","first":4294967295,"files":[],"next":0,"err":0}\n\nok\n')
        assert (await wire.exchange("M408 S" + "9" * 40)).endswith(b"ok\n")
        assert await wire.exchange("M104 T" + "9" * 40 + " S200") == (
            b"Error: M104: Invalid tool number\nok\n")
        assert await wire.exchange("M104 Tx S200") == (
            b"Error:  at column 7: M104: expected number after 'T'\nok\n")
        assert await wire.exchange("M105") == f"ok {COLD}\n".encode()


async def test_empty_lines_and_comments_get_no_reply(autojump_clock):
    async with duet() as (wire, _):
        for line in ("", "   ", "; a comment", "  ; indented"):
            await wire.send(line)
        assert await wire.quiet_for(5) == []
        assert await wire.exchange("M110 N100") == b"ok\n"  # M110 does nothing


async def test_line_numbers_are_not_sequenced_and_a_bad_checksum_is_dropped_silently(
        autojump_clock):
    async with duet() as (wire, printer):
        assert await wire.exchange(numbered(7, "G92 X1")) == b"ok\n"
        assert await wire.exchange(numbered(3, "G92 X2")) == b"ok\n"  # backwards: fine
        assert await wire.exchange("N4 G92 X3") == b"ok\n"  # N without a checksum: fine
        assert await wire.exchange("G92 X4*99") == b"ok\n"  # `*` with no N: no checksum
        wire.take()
        # A wrong checksum: no error, no resend, no ok; the line after it (in the same write)
        # is read as ever, nothing flushed.
        await wire.stream.send_all(f"N5 G92 X5*1\n{numbered(6, 'G92 X6')}\n".encode())
        assert await wire.read_until(lambda line: line == "ok", timeout=10) == ["ok"]
        assert await wire.quiet_for(5) == []
        assert wire.take() == b"ok\n"
        assert "G92 X5" not in printer.journal and "G92 X6" in printer.journal


# -- waits and their reports ---------------------------------------------------------------
async def test_m109_says_nothing_while_it_waits_until_the_host_has_sent_m105(autojump_clock):
    async with duet() as (wire, _):
        start = trio.current_time()
        assert await wire.command("M109 S200") == ["ok"]  # no busy:, no temperatures
        took = trio.current_time() - start
        assert 40 < took < 80  # 21 C to within 1.5 C of 200, no residency
        temperature = float((await wire.command("M105"))[0].split()[1][2:])
        assert 198.5 <= temperature <= 201.5


async def test_after_m105_a_wait_sends_the_m105_line_every_two_seconds(autojump_clock):
    async with duet() as (wire, _):
        await wire.command("M105")
        await wire.send("M109 S200")
        times, lines = [], []
        while not lines or lines[-1] != "ok":
            lines.append(await wire.read_line())
            times.append(trio.current_time())
        reports = lines[:-1]
        assert len(reports) > 15 and all(REPORT.fullmatch(line) for line in reports)
        assert all(abs((later - earlier) - 2.0) < 1e-6 for earlier, later in
                   zip(times, times[1:-1]))
        assert float(reports[0].split()[0][2:]) < float(reports[-1].split()[0][2:])
        assert reports[-1].endswith("/200.0 B:21.0 /0.0")
        # M408 (or M409) takes the reports away from USB (they would go to a PanelDue).
        await wire.command("M408 S0")
        assert await wire.command("G4 S5") == ["ok"]


async def test_dwell_and_m400_report_too_and_nothing_is_ever_busy(autojump_clock):
    async with duet() as (wire, _):
        assert await wire.command("G4 S5") == ["ok"]
        await wire.command("G92 X200 Y200 Z100")
        assert await wire.command("G28") == ["ok"]  # a long homing: no busy: lines
        await wire.command("M105")
        lines = await wire.command("G4 S5")
        assert len(lines) == 3 and all(REPORT.fullmatch(line) for line in lines[:2])
        await wire.command("M105")
        await wire.command("G1 X200 F600")  # 20 s of move; its ok at once (queued)
        lines = await wire.command("M400")
        assert 8 <= len(lines) - 1 <= 10 and all(REPORT.fullmatch(line) for line in lines[:-1])


# -- halts ---------------------------------------------------------------------------------
async def test_m112_halts_with_its_ok_and_refuses_all_but_a_few_until_m999_resets(
        autojump_clock):
    async with duet() as (wire, printer):
        await wire.command("M104 S200")
        assert await wire.exchange("M112") == (
            b"Emergency Stop! Reset the controller to continue.\nok\n")
        assert await wire.exchange("G28") == b"Error: G28: Machine is halted\nok\n"
        assert await wire.exchange("G1 X10 F3000") == b"Error: G1: Machine is halted\nok\n"
        assert await wire.exchange("M104 S210") == b"Error: M104: Machine is halted\nok\n"
        assert await wire.exchange("T0") == b"Error: T0: Machine is halted\nok\n"
        assert await wire.exchange("M105") == f"ok {COLD}\n".encode()  # heaters off
        assert await wire.exchange("M115") == M115
        assert (await wire.command("M122"))[0] == "=== Diagnostics ==="
        assert json.loads((await wire.command("M408 S2"))[0])["status"] == "H"
        assert json.loads((await wire.command('M409 K"state.status"'))[0])["result"] == "halted"
        assert await wire.exchange("M112") == (
            b"Emergency Stop! Reset the controller to continue.\nok\n")
        boots = printer.server.boots
        wire.take()
        await wire.send("M999")
        assert await wire.quiet_for(5) == []  # no reply and no ok: the board resets
        assert printer.server.boots == boots + 1
        assert await wire.exchange("G28") == b"ok\n"
        assert "G28 X" not in printer.journal and printer.journal.count("G28") == 1


async def test_lines_sent_with_m112_are_refused_in_order(autojump_clock):
    async with duet() as (wire, printer):
        await wire.stream.send_all(b"M112\nG28\nM105\n")
        lines = await wire.read_until(lambda line: line.startswith("ok T:"))
        assert lines == ["Emergency Stop! Reset the controller to continue.", "ok",
                         "Error: G28: Machine is halted", "ok", f"ok {COLD}"]
        assert "G28" not in printer.journal


async def test_m999_resets_a_running_printer_after_a_second(autojump_clock):
    async with duet() as (wire, printer):
        await wire.command("G28")
        boots = printer.server.boots
        start = trio.current_time()
        await wire.send("M999")
        while printer.server.boots == boots:
            await trio.sleep(0.01)
        assert 0.99 < trio.current_time() - start < 1.1
        assert await wire.quiet_for(5) == []
        assert json.loads((await wire.command('M409 K"move.axes[0].homed"'))[0])[
            "result"] is False


async def test_m999_as_the_first_command_is_a_software_reset_for_the_next_m122(autojump_clock):
    async with duet() as (wire, printer):
        boots = printer.server.boots
        await wire.send("M999")  # before anything else of RRF's: the power-up boot is still this
        while printer.server.boots == boots:
            await trio.sleep(0.01)
        lines = await wire.command("M122")
        assert lines[5].endswith("cause: software")
        assert lines[6].startswith("Last software reset at ")


async def test_m122s_board_id_is_the_machine_names_in_every_process(autojump_clock):
    # (str's hash() is salted per process: the ID was drawn from it.)
    async with duet() as (wire, _):
        lines = await wire.command("M122")
        assert lines[2] == "Board ID: 19220-30C91-B9864-BDCC3-2DEE6-596F7"


async def test_a_heater_fault_is_an_alert_not_a_halt(autojump_clock):
    async with duet() as (wire, printer):
        await wire.command("M104 S200")
        await wire.quiet_for(60)
        wire.take()
        server = printer.server
        server.announce(apply(server.printer, Failure(FailureKind.THERMAL_RUNAWAY, "T0"),
                              trio.current_time()))
        lines = await wire.read_until(lambda line: "fault" in line)
        assert lines[0] == "- Event notification -"
        assert re.fullmatch(r"Heater 1 fault: exceeded allowed temperature excursion: "
                            r"target 200\.0°C actual \d+\.\d°C", lines[1])
        assert "°C".encode() in wire.take()  # UTF-8: C2 B0
        assert await wire.exchange("G28") == b"ok\n"  # not halted
        assert (await wire.command("M105"))[0].startswith("ok T:") and "/0.0 T0:" in (
            await wire.command("M105"))[0]
        await wire.command("M104 S200")  # a faulted heater stays off until M562
        assert (await wire.command("M105"))[0].split()[2] == "/0.0"
        await wire.command("M562 P1")
        await wire.command("M104 S200")
        assert (await wire.command("M105"))[0].split()[2] == "/200.0"


# -- its own commands ----------------------------------------------------------------------
async def test_m550_m552_m555_and_m122(autojump_clock):
    async with duet() as (wire, _):
        assert await wire.exchange("M550") == b"RepRap name: My Duet 1\nok\n"
        assert await wire.exchange('M550 P"Shelf ""A"""') == b"ok\n"
        assert await wire.exchange("M550") == b'RepRap name: Shelf "A"\nok\n'
        assert await wire.exchange("M555") == b"Output mode: Marlin\nok\n"
        assert await wire.exchange("M552") == (
            b"Ethernet is enabled, configured IP address: 0.0.0.0, actual IP address: "
            b"192.168.1.50\nok\n")
        lines = await wire.command("M122")
        assert lines[:2] == [
            "=== Diagnostics ===",
            "RepRapFirmware for Duet 3 MB6HC version 3.5.3 (2024-09-18 12:00:00) running on "
            "Duet 3 MB6HC v1.02b or later (standalone mode)"]
        assert "cause: power up" in lines[5] and lines[-1] == "ok"
        assert await wire.exchange("T") == b"Tool 0 is selected\nok\n"
        assert await wire.exchange("M0") == (
            b"Error: M0: Pause the print before attempting to cancel it\nok\n")
        assert await wire.exchange("M600") == (
            b"Error: M600: use M226 and M601 only within a file being printed\nok\n")
    async with memory_printer(firmware="reprapfirmware", seed=3) as printer:
        wire = Wire(printer.open())
        assert await wire.exchange("M550") == b"RepRap name: My Duet 1\nok\n"  # its identity


async def test_m408_answers_real_json_with_rrfs_empty_lines_before_ok(autojump_clock):
    async with duet() as (wire, _):
        data = await wire.exchange("M408 S0")
        assert data.endswith(b"}\n\n\nok\n")  # the legacy response's own newline and one more
        legacy = json.loads(data.split(b"\n")[0])
        assert list(legacy)[:6] == ["status", "heaters", "active", "standby", "hstat", "pos"]
        assert legacy["status"] == "I" and legacy["heaters"] == [21.0, 21.0]
        assert legacy["msgBox.mode"] == -1 and "myName" not in legacy
        assert json.loads((await wire.command("M408 S1"))[0])["myName"] == "My Duet 1"
        for kind in (2, 3, 4, 5):
            data = await wire.exchange(f"M408 S{kind}")
            assert data.endswith(b"}\n\nok\n")
            body = json.loads(data.split(b"\n")[0])
            if kind < 5:
                assert body["status"] == "I" and body["coords"]["xyz"] == [0.0, 0.0, 0.0]
        assert b'"xyz":[0.000,0.000,0.000]' in await wire.exchange("M408 S2")
        assert b',"firmwareVersion":"3.5.3"' in await wire.exchange("M408 S3")
        assert b'"fractionPrinted":0.0' in await wire.exchange("M408 S4")
        assert b', "sysdir":"0:/sys/"' in await wire.exchange("M408 S5")


async def test_m409_queries_the_object_model(autojump_clock):
    async with duet() as (wire, _):
        data = await wire.exchange("M409")
        assert data.startswith(b'{"key":"","flags":"","result":{"boards":[{}],') and data.endswith(
            b"}}\n\nok\n")
        root = json.loads(data.split(b"\n")[0])
        assert list(root) == ["key", "flags", "result"]
        assert list(root["result"]) == sorted(root["result"])  # alphabetical, as RRF's table
        assert root["result"]["heat"] == {} and root["result"]["state"] == {}
        assert await wire.exchange('M409 K"state.status"') == (
            b'{"key":"state.status","flags":"","result":"idle"}\n\nok\n')
        state = json.loads((await wire.command('M409 K"state"'))[0])["result"]
        assert state["status"] == "idle" and state["currentTool"] == 0
        await wire.command("M140 S60")
        heat = json.loads((await wire.command('M409 K"heat"'))[0])["result"]
        assert heat["heaters"][0]["active"] == 60.0 and heat["heaters"][1]["state"] == "active"
        move = json.loads((await wire.command('M409 K"move" F"d2"'))[0])
        assert move["flags"] == "d2" and move["result"]["axes"] == [{}, {}, {}]
        job = json.loads((await wire.command('M409 K"job"'))[0])["result"]
        assert job["filePosition"] == 0 and "fileName" not in job["file"]
        assert json.loads((await wire.command('M409 K"#tools"'))[0])["result"] == 1
        assert json.loads((await wire.command('M409 K"nothing.here"'))[0])["result"] is None
        assert await wire.exchange("echo state.status") == b"idle\nok\n"


async def test_m291_prints_its_message_and_does_not_block_usb(autojump_clock):
    async with duet() as (wire, _):
        assert await wire.exchange('M291 P"Check the bed" R"Attention" S2') == (
            b"- Attention -\nCheck the bed\nSend M292 to continue\nok\n")
        assert await wire.exchange('M291 P"Go on?" S3') == (
            b"Go on?\nSend M292 to continue or M292 P1 to cancel\nok\n")
        assert await wire.exchange('M291 P"Note" R"Info"') == b"- Info -\nNote\nok\n"
        # S0 has a 10 s timeout unless T says otherwise (GCodes7.cpp:31)
        assert await wire.exchange('M291 P"Gone soon" S0') == b"Gone soon\nok\n"
        assert await wire.exchange('M291 P"Stuck" S0 T0') == (
            b"Error: M291: Attempt to create a message box that cannot be dismissed\nok\n")
        assert await wire.exchange("M292") == b"ok\n"
        assert await wire.exchange("M105") == f"ok {COLD}\n".encode()


# -- the SD card ---------------------------------------------------------------------------
async def test_m20_lists_the_gcodes_folder_plain_and_as_json(autojump_clock, tmp_path):
    async with duet(tmp_path) as (wire, _):
        assert await wire.exchange("M20") == b"Begin file list\nNONE\nEnd file list\nok\n"
        sd = tmp_path / "gcodes"
        (sd / "cube.gcode").write_text("G28\n")
        (sd / "Benchy Long Name.gcode").write_text("G28\n")
        (sd / "parts").mkdir()
        (sd / "parts" / "inner.gcode").write_text("G28\n")
        assert await wire.exchange("M20") == (
            b"Begin file list\nBenchy Long Name.gcode\ncube.gcode\nparts\nEnd file list\nok\n")
        data = await wire.exchange("M20 S2")
        assert data == (b'{"dir":"0:/gcodes/","first":0,"files":["Benchy Long Name.gcode",'
                        b'"cube.gcode","*parts"],"next":0,"err":0}\n\nok\n')
        assert json.loads(data.split(b"\n")[0])["err"] == 0
        assert await wire.exchange('M20 S2 P"0:/gcodes/parts"') == (
            b'{"dir":"0:/gcodes/parts","first":0,"files":["inner.gcode"],"next":0,"err":0}'
            b"\n\nok\n")
        assert await wire.exchange('M20 S2 P"0:/macros/"') == (
            b'{"dir":"0:/macros/","first":0,"files":[],"err":2}\n\nok\n')
        listing = json.loads((await wire.command("M20 S3"))[0])
        assert [(f["type"], f["name"]) for f in listing["files"]] == [
            ("f", "Benchy Long Name.gcode"), ("f", "cube.gcode"), ("d", "parts")]
        assert await wire.exchange("M21") == b"SDHC card mounted in slot 0, capacity 31.91Gb\nok\n"
        assert await wire.exchange("M22") == b"SD card 0 may now be removed\nok\n"
        assert json.loads((await wire.command("M20 S2"))[0])["err"] == 1


async def test_a_broken_link_or_a_link_loop_on_the_card_is_a_file_not_there(
        autojump_clock, tmp_path):
    async with duet(tmp_path) as (wire, _):
        sd = tmp_path / "gcodes"
        (sd / "cube.gcode").write_text("G28\n")
        (sd / "gone.gcode").symlink_to(sd / "nowhere.gcode")
        (sd / "loop.gcode").symlink_to(sd / "loop.gcode")
        listing = json.loads((await wire.command("M20 S3"))[0])
        assert [entry["name"] for entry in listing["files"]] == ["cube.gcode"]
        assert await wire.exchange("M20") == b"Begin file list\ncube.gcode\nEnd file list\nok\n"
        for name in ("gone.gcode", "loop.gcode"):
            assert await wire.exchange(f"M23 {name}") == (
                f'Error: M23: GCode file "{name}" not found\n\nok\n'.encode())
            assert await wire.exchange(f"M36 {name}") == (
                f'{{"err":1,"fileName":"{name}"}}\nok\n'.encode())
            assert await wire.exchange(f"M30 {name}") == b"Error: M30: delete failed\nok\n"


async def test_a_file_printed_from_the_card(autojump_clock, tmp_path):
    async with duet(tmp_path) as (wire, printer):
        job = "; generated by PrusaSlicer 2.8.1\nG28\nG1 Z0.2 F600\nG1 X10 Y10 E1.5 F3000\nM400\n"
        (tmp_path / "gcodes" / "part.gcode").write_text(job)
        assert await wire.exchange("M23 missing.gcode") == (
            b'Error: M23: GCode file "missing.gcode" not found\n\nok\n')
        assert await wire.exchange("M23 /part.gcode") == (  # the card's root, not 0:/gcodes/
            b'Error: M23: GCode file "/part.gcode" not found\n\nok\n')
        assert await wire.exchange("M24") == (
            b"Error: M24: Cannot print, because no file is selected!\nok\n")
        assert await wire.exchange("M27") == b"Not SD printing.\nok\n"
        assert await wire.exchange("M25") == (
            b"Error: M25: Cannot pause print, because no file is being printed!\nok\n")
        assert await wire.exchange("M23 part.gcode") == b"File opened\nFile selected\nok\n"
        info = json.loads((await wire.command("M36 part.gcode"))[0])
        assert info["err"] == 0 and info["size"] == len(job) and info["height"] == 0.2
        assert info["filament"] == [1.5] and info["generatedBy"] == "PrusaSlicer 2.8.1"
        assert await wire.exchange("M36 none.gcode") == b'{"err":1,"fileName":"none.gcode"}\nok\n'
        await wire.command("M24")
        lines = await wire.read_until(lambda line: line == "Done printing file")
        assert lines == ["Done printing file"]
        assert printer.journal[-4:] == ["G28", "G1 Z0.2 F600", "G1 X10 Y10 E1.5 F3000", "M400"]
        assert await wire.exchange("M30 part.gcode") == b"ok\n"
        assert await wire.exchange("M30 part.gcode") == b"Error: M30: delete failed\nok\n"


async def test_m28_writes_a_file_without_an_ok_per_line(autojump_clock, tmp_path):
    async with duet(tmp_path) as (wire, printer):
        await wire.send("M28 up.gcode")
        assert await wire.read_until(lambda line: line.startswith("Writing")) == [
            "ok", "Writing to file: up.gcode"]
        wire.take()
        for line in ("G28", numbered(1, "G1 X5 F3000"), "M104 S0"):
            await wire.send(line)
        assert await wire.quiet_for(5) == []  # each line written, none answered
        assert await wire.exchange("M29") == b"Done saving file.\nok\n"
        assert (tmp_path / "gcodes" / "up.gcode").read_bytes() == (
            b"G28\nG1 X5 F3000\nM104 S0\n")  # StringParser::WriteToFile
        assert "G28" not in printer.journal  # written, not run
        assert await wire.exchange("M29") == b"GCode end-of-file being interpreted.\nok\n"


async def test_m28_sends_its_ok_before_its_reply(autojump_clock, tmp_path):
    async with duet(tmp_path) as (wire, _):
        await wire.send("M28 up.gcode")
        assert [await wire.read_line(), await wire.read_line()] == [
            "ok", "Writing to file: up.gcode"]
        await wire.send("M29")
        assert await wire.read_until(lambda line: line == "ok") == ["Done saving file.", "ok"]


# -- a job ---------------------------------------------------------------------------------
async def test_a_job_of_moves_is_run_once_each_in_order(autojump_clock):
    job = ["G28", "M104 S0"] + [f"G1 X{10 + i % 7 * 5} Y{10 + i % 11 * 4} E{0.1 * (i + 1):.1f} "
                                f"F3000" for i in range(50)] + ["M400"]
    async with duet() as (wire, printer):
        for number, line in enumerate(job, start=1):
            assert await wire.command(numbered(number, line)) == ["ok"]
        assert printer.journal == job
