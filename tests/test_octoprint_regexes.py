"""Every line a host parses matches the regexes OctoPrint 1.11 uses (docs/hosts.md)."""

import re

from fake_marlin.emulator.printer.model import Printer, PrinterConfig
from fake_marlin.emulator.server.lifecycle import ServerConfig
from tests.conftest import running_printer
from tests.terminal import Terminal

FLOAT = r"[-+]?[0-9]*\.?[0-9]+"
TEMPERATURE = re.compile(
    rf"(^|\s)(?P<sensor>B|C|T(?P<toolnum>\d*)|([\w]+)):\s*(?P<actual>{FLOAT})(\s*\/?\s*(?P<target>{FLOAT}))?"
)
POSITION = re.compile(
    rf"X:\s*(?P<x>{FLOAT})\s*Y:\s*(?P<y>{FLOAT})\s*Z:\s*(?P<z>{FLOAT})\s*"
    rf"((E:\s*(?P<e>{FLOAT}))|(?P<es>(E\d+:\s*{FLOAT}\s*)+))"
)
SD_PROGRESS = re.compile(r"(?P<current>[0-9]+)/(?P<total>[0-9]+)")
FILE_OPENED = re.compile(r"File opened:\s*(?P<name>.*?)\s+Size:\s*(?P<size>\d+)")
FIRMWARE_FIELDS = re.compile(r"(^|\s+)([A-Z][A-Z0-9_]*):")
CAPABILITY = re.compile(r"Cap:([A-Z0-9_]+):([01])")


def temperatures(line: str) -> dict[str, tuple[float, float | None]]:
    found = {}
    for match in TEMPERATURE.finditer(line):
        target = match["target"]
        found[match["sensor"]] = (float(match["actual"]), None if target is None else float(target))
    return found


async def session(tmp_path, extruders=1):
    sd = tmp_path / "sd"
    sd.mkdir(exist_ok=True)
    (sd / "part.gcode").write_text("G1 X1\nG1 X2\nG4 S30\nG1 X3\n")
    return Printer(PrinterConfig(extruders=extruders, sd_dir=sd))


async def test_temperature_lines(tmp_path, autojump_clock):
    printer = await session(tmp_path, extruders=2)
    async with running_printer(ServerConfig(protocol="marlin"), printer) as running:
        terminal = Terminal(running.link.open_host())
        await terminal.quiet_for(1)
        await terminal.command("M104 T1 S210")
        await terminal.command("M140 S60")
        (m105,) = await terminal.command("M105")
        seen = temperatures(m105)
        assert seen["T"] == (21.0, 0.0) and seen["B"][1] == 60.0
        assert seen["T0"] == (21.0, 0.0) and seen["T1"][1] == 210.0
        await terminal.command("M155 S1")
        auto = (await terminal.quiet_for(1.5))[0]
        assert auto.startswith(" T:") and temperatures(auto)["B"][1] == 60.0
        await terminal.command("M155 S0")
        m109 = await terminal.command("M109 T0 S30")
        assert all(temperatures(line)["T"][1] == 30.0 for line in m109[:-1])


async def test_position_and_firmware_lines(tmp_path, autojump_clock):
    async with running_printer(ServerConfig(protocol="marlin"), await session(tmp_path)) as running:
        terminal = Terminal(running.link.open_host())
        await terminal.quiet_for(1)
        await terminal.command("G1 X12.5 Y-3 Z0.2 E1.5")
        position = POSITION.search((await terminal.command("M114"))[0])
        assert (position["x"], position["y"], position["z"], position["e"]) == ("12.50", "-3.00", "0.20", "1.50")
        m115 = await terminal.command("M115")
        fields = [m[2] for m in FIRMWARE_FIELDS.finditer(m115[0])]
        assert fields[:2] == ["FIRMWARE_NAME", "SOURCE_CODE_URL"] and "EXTRUDER_COUNT" in fields
        capabilities = dict(CAPABILITY.fullmatch(line).groups() for line in m115[1:-1])
        assert capabilities["AUTOREPORT_TEMP"] == "1" and capabilities["EMERGENCY_PARSER"] == "1"


async def test_sd_lines(tmp_path, autojump_clock):
    async with running_printer(ServerConfig(protocol="marlin"), await session(tmp_path)) as running:
        terminal = Terminal(running.link.open_host())
        await terminal.quiet_for(1)
        size = (tmp_path / "sd" / "part.gcode").stat().st_size
        opened = FILE_OPENED.search((await terminal.command("M23 part.gcode"))[0])
        assert opened["name"] == "PART~1.GCO" and int(opened["size"]) == size
        await terminal.command("M24")
        await terminal.quiet_for(0.5)  # into the dwell
        (status,) = [line for line in await terminal.command("M27") if line.startswith("SD printing")]
        progress = SD_PROGRESS.search(status)
        assert 0 < int(progress["current"]) < int(progress["total"]) == size
