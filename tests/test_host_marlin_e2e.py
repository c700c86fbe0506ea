"""fake-marlin-host --protocol marlin against fake-marlin over a real pty, as a user runs them."""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from fake_marlin.wire.gcode import strip_comment

pytestmark = pytest.mark.e2e
BIN = Path(sys.executable).parent
TEMPERATURES = "T:21.00 /0.00 B:21.00 /0.00 @:0 B@:0"


def host(*args, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [BIN / "fake-marlin-host", *map(str, args)], capture_output=True, text=True, timeout=timeout
    )


def write_job(path: Path, count: int) -> list[str]:
    lines = ["; a job written by the test", "G28", "G1 Z0.3 F600 ; first layer", ""]
    lines += [f"G1 X{(n % 100) / 2:.1f} Y{(n % 37) / 2:.1f} E{n / 100:.2f} F6000" for n in range(count)]
    lines += ["M400", "M114"]
    path.write_text("\n".join(lines) + "\n")
    return [command for line in lines if (command := strip_comment(line))]


def run_bare(journal: list[str], commands: list[str]) -> tuple[list[str], list[str]]:
    """Split the journal into the job's commands and the lines Marlin ran bare: a numbered line
    whose leading N was damaged on the way is no numbered line to Marlin, so it runs unchecked
    (`O1494 G1 X45.5 ...`). No host can prevent that; the printer still ran the real line, once,
    when the host sent it again."""
    ran, bare = [], []
    for line in journal:
        match = re.fullmatch(r"(.)(\d+) (.*)", line)
        damaged_n = match and bin(ord(match[1]) ^ ord("N")).count("1") == 1
        if damaged_n and 0 < int(match[2]) <= len(commands) and commands[int(match[2]) - 1] == match[3]:
            bare.append(line)
        else:
            ran.append(line)
    return ran, bare


def test_a_2000_command_print_over_a_noisy_line_runs_every_command_once(fake_printer_factory, tmp_path):
    printer = fake_printer_factory(
        protocol="auto", speed=1000, seed=7,
        faults=[{"kind": "corrupt-lines", "direction": "to-printer", "rate": 0.02}],
    )
    commands = write_job(tmp_path / "part.gcode", 2000)
    result = host("print", printer.port, tmp_path / "part.gcode", "--protocol", "marlin", "--json")
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["commands"] == len(commands)
    assert summary["rejects"] > 0 and summary["resends"] >= summary["rejects"]
    # What the host adds to the journal: nothing. Opening the port reset the printer, so its
    # line counter was 0 (read with a probe the printer refuses, never runs) and no M110 was
    # needed. Every line in the journal is a job command, in order, once, except what Marlin ran
    # bare from lines the fault damaged in their first character.
    ran, bare = run_bare(printer.journal, commands)
    assert ran == commands
    assert len(bare) <= 5


def test_a_clean_print_adds_nothing_and_resends_nothing(fake_printer_factory, tmp_path):
    printer = fake_printer_factory(protocol="marlin", speed=1000)
    commands = write_job(tmp_path / "part.gcode", 2000)
    result = host("print", printer.port, tmp_path / "part.gcode", "--protocol", "marlin", "--json")
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert (summary["commands"], summary["resends"], summary["timeouts"]) == (len(commands), 0, 0)
    assert printer.journal == commands


def test_send_prints_the_temperatures(fake_printer_factory):
    printer = fake_printer_factory(protocol="auto")
    result = host("send", printer.port, "M105", "--protocol", "marlin")
    assert result.returncode == 0, result.stderr
    assert result.stdout == f"{TEMPERATURES}\n"
    assert printer.journal == ["M105"]


def test_a_job_the_host_cannot_number_is_refused_before_sending(fake_printer_factory, tmp_path):
    printer = fake_printer_factory(protocol="marlin")
    (tmp_path / "bad.gcode").write_text("G28\nM110 N100\n")
    result = host("print", printer.port, tmp_path / "bad.gcode", "--protocol", "marlin")
    assert result.returncode == 2
    assert "bad.gcode:2" in result.stderr and "M110" in result.stderr and "Traceback" not in result.stderr
    assert printer.journal == []
