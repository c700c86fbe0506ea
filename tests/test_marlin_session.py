"""A printer speaking Marlin's ASCII protocol, driven line by line in simulated time."""

from contextlib import asynccontextmanager

import trio

from fake_marlin.emulator.printer.model import Printer, PrinterConfig
from fake_marlin.emulator.server.lifecycle import ServerConfig
from fake_marlin.wire.ultimaker import encode_packet
from tests.conftest import running_printer
from tests.terminal import Terminal, numbered

TEMPERATURES = "T:21.00 /0.00 B:21.00 /0.00 @:0 B@:0"


@asynccontextmanager
async def marlin(tmp_path=None, **config):
    sd_dir = None
    if tmp_path is not None:
        sd_dir = tmp_path / "sd"
        sd_dir.mkdir()
    printer = Printer(PrinterConfig(sd_dir=sd_dir, **config))
    async with running_printer(ServerConfig(protocol="marlin"), printer) as running:
        terminal = Terminal(running.link.open_host())
        greeting = await terminal.quiet_for(1)
        assert greeting[0] == "start"
        yield terminal, running


async def test_boot_greets_once_per_open_and_never_otherwise(autojump_clock):
    async with running_printer(ServerConfig(protocol="marlin")) as running:
        terminal = Terminal(running.link.open_host())
        boot = await terminal.read_until(lambda line: line.startswith("echo:V88"))
        assert boot[0] == "start" and boot[1] == " External Reset"
        assert boot[2].startswith("Marlin 2.")
        await terminal.command("G28")
        later = await terminal.quiet_for(30)
        assert "start" not in later
        again = Terminal(running.link.open_host())
        assert (await again.read_line()) == "start"


async def test_m105_and_m114_answer_in_marlins_format(autojump_clock):
    async with marlin() as (terminal, _):
        assert await terminal.command("M105") == [f"ok {TEMPERATURES}"]
        assert await terminal.command("M114") == ["X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0", "ok"]
        assert await terminal.command("m105") == [f"ok {TEMPERATURES}"]


async def test_unknown_commands_echo_then_ok(autojump_clock):
    async with marlin() as (terminal, _):
        assert await terminal.command("M9999 S1") == ['echo:Unknown command: "M9999 S1"', "ok"]


async def test_a_line_error_arrives_as_one_write(autojump_clock):
    async with marlin() as (terminal, _):
        await terminal.command("N0 M110 N0*125")
        terminal.chunks.clear()
        lines = await terminal.command("N1 G28*99")
        assert lines == ["Error:checksum mismatch, Last Line: 0", "Resend: 1", "ok"]
        assert b"Error:checksum mismatch, Last Line: 0\nResend: 1\nok\n" in terminal.chunks


async def test_busy_lines_every_two_seconds_while_homing_and_m113_changes_it(autojump_clock):
    async with marlin() as (terminal, _):
        await terminal.command("G92 X200 Y200 Z100")  # far from the endstops: a long homing
        await terminal.send("G28")
        start = trio.current_time()
        lines = await terminal.read_until(lambda line: line == "ok")
        took = trio.current_time() - start
        busy = lines.count("echo:busy: processing")
        assert took > 15 and lines[:-1] == ["echo:busy: processing"] * busy
        assert busy == int(took // 2)  # the first once it has been busy 2 s, as host_keepalive()
        await terminal.command("M113 S0")
        assert await terminal.command("G28") == ["ok"]
        assert await terminal.command("M113") == ["echo:M113 S0", "ok"]


async def test_m109_reports_every_second_without_busy_and_waits_for_residency(autojump_clock):
    async with marlin() as (terminal, _):
        start = trio.current_time()
        lines = await terminal.command("M109 S200")
        took = trio.current_time() - start
        assert "echo:busy: processing" not in lines
        reports = lines[:-1]
        assert all(line.startswith(" T:") and " W:" in line for line in reports)
        assert reports[0].endswith(" W:?") and reports[-1].endswith(" W:0")
        assert abs(len(reports) - took) <= 2
        assert 60 < took < 80  # about a minute to 200 C, then 10 s of residency
        assert (await terminal.command("M105"))[0].startswith("ok T:200.00 /200.00")


async def test_m108_cancels_a_heat_up_wait(autojump_clock):
    async with marlin() as (terminal, _):
        await terminal.send("M190 S100")
        await terminal.read_until(lambda line: "W:" in line)
        await terminal.send("M108")
        lines = await terminal.read_until(lambda line: line == "ok")
        assert len(lines) < 4
        assert await terminal.command("M105")


async def test_m155_reports_temperatures_on_its_own(autojump_clock):
    async with marlin() as (terminal, _):
        await terminal.command("M155 S2")
        lines = await terminal.quiet_for(9)
        assert lines == [f" {TEMPERATURES}"] * 5
        await terminal.command("M155 S0")
        assert await terminal.quiet_for(9) == []


async def test_m112_halts_until_the_port_is_reopened(autojump_clock):
    async with marlin() as (terminal, running):
        await terminal.send("M112")
        lines = await terminal.read_until(lambda line: "kill() called" in line)
        assert lines == ["echo:M112 Shutdown", "Error:Printer halted. kill() called!"]
        assert await terminal.read_line() == "//action:poweroff"
        await terminal.send("M105")
        assert await terminal.quiet_for(5) == []
        fresh = Terminal(running.link.open_host())
        await fresh.read_until(lambda line: line == "//action:prompt_end")  # the greeting's end
        assert await fresh.command("M105") == [f"ok {TEMPERATURES}"]


async def test_m115_lists_firmware_and_capabilities(autojump_clock):
    async with marlin(capabilities=(("AUTOREPORT_TEMP", True), ("EXTENDED_M20", False))) as (terminal, _):
        lines = await terminal.command("M115")
        assert lines[0].startswith("FIRMWARE_NAME:Marlin 2.1")
        assert lines[1:] == ["Cap:AUTOREPORT_TEMP:1", "Cap:EXTENDED_M20:0", "ok"]


async def test_tools_and_invalid_extruders(autojump_clock):
    async with marlin(extruders=2) as (terminal, _):
        assert await terminal.command("T1") == ["echo:Active Extruder: 1", "ok"]
        assert await terminal.command("T2") == ["echo:T2 Invalid extruder", "ok"]
        assert await terminal.command("M104 T5 S200") == ["echo:M104 Invalid extruder 5", "ok"]
        (line,) = await terminal.command("M105")
        assert line.startswith("ok T:21.00 /0.00 B:21.00 /0.00 T0:21.00 /0.00 T1:21.00 /0.00 @:0")


async def test_sd_card_listing_printing_uploading_and_deleting(tmp_path, autojump_clock):
    async with marlin(tmp_path) as (terminal, running):
        cube = tmp_path / "sd" / "cube.gcode"
        cube.write_text("G28 ; home\nG1 X10 F3000\n\nM400\n")
        size = cube.stat().st_size
        assert await terminal.command("M21") == ["echo:SD card ok", "ok"]
        listing = await terminal.command("M20 L")
        assert listing == ["Begin file list", f"CUBE~1.GCO {size} cube.gcode", "End file list", "ok"]
        assert await terminal.command("M23 CUBE~1.GCO") == [
            f"File opened: CUBE~1.GCO Size: {size}", "File selected", "ok"
        ]
        assert await terminal.command("M27") == ["Not SD printing", "ok"]
        await terminal.command("M24")
        done = await terminal.read_until(lambda line: line == "Done printing file")
        assert running.journal[-3:] == ["G28", "G1 X10 F3000", "M400"]
        assert "ok" not in done  # SD lines are not acknowledged to the host
        assert await terminal.command("M23 nothing.gco") == ["open failed, File: nothing.gco.", "ok"]

        assert await terminal.command("N0 M110 N0*125")
        assert await terminal.command(numbered(1, "M28 up.gco")) == ["Writing to file: up.gco", "ok"]
        assert await terminal.command(numbered(2, "G1 X5")) == ["ok"]
        assert await terminal.command("M29") == ["Done saving file.", "ok"]
        assert (tmp_path / "sd" / "up.gco").read_bytes() == b"G1 X5\r\n"
        assert "G1 X5" not in running.journal  # stored, not executed
        assert await terminal.command("M30 UP.GCO") == ["File deleted:UP.GCO", "ok"]
        assert await terminal.command("M28 ../escape.gco") == ["open failed, File: ../escape.gco.", "ok"]
        assert not (tmp_path / "escape.gco").exists()


async def test_m27_s_reports_sd_status_every_interval_with_or_without_a_file(autojump_clock):
    """Marlin's AutoReporter calls report_status() at each interval whatever is selected, so a
    host that turned it on (OctoPrint sends M27 S1) hears `Not SD printing` while idle."""
    async with marlin() as (terminal, _):
        assert await terminal.command("M27 S1") == ["ok"]
        heard = await terminal.quiet_for(3.5)
        assert heard == ["Not SD printing"] * 4  # at once, then every second
        assert await terminal.command("M27 S0") == ["ok"]
        assert await terminal.quiet_for(3) == []


async def test_auto_detection_follows_the_first_bytes_on_every_open(autojump_clock):
    async with running_printer(ServerConfig(protocol="auto")) as running:
        text_host = Terminal(running.link.open_host())
        assert await text_host.quiet_for(5) == []  # no greeting before the host speaks
        await text_host.send("M105")
        lines = await text_host.read_until(lambda line: line.startswith("ok"))
        assert lines[0] == "start" and lines[-1] == f"ok {TEMPERATURES}"

        binary_host = running.link.open_host()
        await binary_host.send_all(encode_packet(0, b"M105"))
        with trio.fail_after(5):
            received = b""
            while b"\no00" not in received:
                received += await binary_host.receive_some(4096)
        assert f"\n{TEMPERATURES}\n".encode() in received
        assert received.startswith(b"LOG:Marlin started\n\nq000F98\n")


async def test_curas_probe_finds_ok_and_t_on_one_line(autojump_clock):
    async with running_printer(ServerConfig(protocol="auto")) as running:
        cura = running.link.open_host()
        await cura.send_all(b"\nM105\n")  # Cura's AutoDetectBaudJob probe
        terminal = Terminal(cura)
        lines = await terminal.read_until(lambda line: "ok" in line and "T:" in line, timeout=5)
        assert lines[0] == "start" and len([line for line in lines if line.startswith("ok")]) == 1


async def test_a_move_answered_before_planning_is_the_move_of_the_general_path(autojump_clock):
    """`G1 X..` with room in the planner gets its `ok` before it is planned; `G1X..` takes the
    general path. The host sees the same: each `ok` at the same moment (a full planner holds
    both back alike), the same position, the same time to drain, the same journal."""
    moves = [f"X{10 + 5 * (i % 7)} Y{20 + 3 * (i % 5)} E{i} F{600 + 600 * (i % 4)}"
             for i in range(40)]

    async def print_moves(word: str) -> tuple[list, list[str], float, list[str]]:
        async with marlin() as (terminal, running):
            start = trio.current_time()
            oks = []
            for move in moves:
                said = await terminal.command(f"{word}{move}")
                oks.append((round(trio.current_time() - start, 9), said))
            position = await terminal.command("M114")
            await terminal.command("M400")
            journal = [line.replace(word, "G1 ", 1) for line in running.journal]
            return oks, position, round(trio.current_time() - start, 9), journal

    fast, general = await print_moves("G1 "), await print_moves("G1")
    assert fast == general
    times = [at for at, _ in fast[0]]
    assert times[-1] > times[0] + 10  # the planner filled: later moves waited for room
    assert fast[2] > times[-1] + 5 and len(fast[3]) == len(moves) + 2
