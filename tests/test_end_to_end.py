"""The real command-line programs over a real pty, as a user runs them."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fake_marlin.wire.gcode import canonical, strip_comment

pytestmark = pytest.mark.e2e
BIN = Path(sys.executable).parent


class Emulator:
    def __init__(self, tmp_path: Path, *args: str) -> None:
        self.journal = tmp_path / "journal.log"
        self.link = tmp_path / "printer"
        self.process = subprocess.Popen(
            [BIN / "fake-marlin", "--link", str(self.link), "--journal", str(self.journal), *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.pty = self.process.stdout.readline().strip()

    def journal_lines(self) -> list[str]:
        return self.journal.read_text().splitlines() if self.journal.exists() else []

    def stop(self) -> tuple[int, str]:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            raise
        return self.process.returncode, self.process.stderr.read()


@pytest.fixture
def emulator(tmp_path):
    started = []

    def start(*args: str) -> Emulator:
        started.append(Emulator(tmp_path, *args))
        return started[-1]

    yield start
    for running in started:
        running.stop()


def host(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [BIN / "fake-marlin-host", *map(str, args)], capture_output=True, text=True, timeout=timeout
    )


def write_job(path: Path, count: int, start: int = 0) -> list[str]:
    lines = ["; a job written by the test", "G28", "G1 Z0.3 F600 ; first layer", ""]
    lines += [f"G1 X{(n % 100) / 2:.1f} Y{(n % 37) / 2:.1f} E{n / 100:.2f} F6000" for n in range(start, start + count)]
    lines += ["M400", "M114"]
    path.write_text("\n".join(lines) + "\n")
    return [command for line in lines if (command := strip_comment(line))]


def test_the_pty_path_comes_first_and_ctrl_c_cleans_up(emulator, tmp_path):
    printer = emulator()
    assert printer.pty.startswith("/dev/pts/")
    assert os.path.realpath(printer.link) == printer.pty
    code, stderr = printer.stop()
    assert code == 0 and "Traceback" not in stderr
    assert not os.path.lexists(printer.link)


def test_send_prints_the_response_data(emulator):
    printer = emulator()
    result = host("send", printer.link, "M105")
    assert result.returncode == 0, result.stderr
    assert result.stdout == "T:21.00 /0.00 B:21.00 /0.00 @:0 B@:0\n"
    assert host("send", printer.pty, "M114").stdout.startswith("X:0.00 Y:0.00 Z:0.00 E:0.00 Count")


def test_a_ten_thousand_command_print_is_journaled_exactly(emulator, tmp_path):
    printer = emulator("--speed", "1000")
    commands = write_job(tmp_path / "part.gcode", 10_000)
    result = host("print", printer.link, tmp_path / "part.gcode", "--json")
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["commands"] == len(commands)
    assert set(summary) >= {"commands", "packets_sent", "resends", "timeouts", "elapsed"}
    assert printer.journal_lines() == commands


@pytest.mark.parametrize("protocol", ["ultimaker", "marlin", "repetier", "commstack"])
def test_each_protocol_prints_a_job_through_auto_detection(emulator, tmp_path, protocol):
    """One printer in `--protocol auto`; each host's first bytes choose its protocol."""
    printer = emulator("--speed", "1000")
    commands = write_job(tmp_path / "part.gcode", 1500)
    result = host("print", printer.link, tmp_path / "part.gcode", "--protocol", protocol, "--json")
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["commands"] == len(commands)
    # Repetier's host asks for M115 itself, CommStack's polls M27 while the stored job prints;
    # a binary command reaches the journal in the firmware's words (`E0` for `E0.00`), which
    # canonical() reads as the same command.
    own = {"repetier": ["M115"], "commstack": ["M27", "M27 C"]}.get(protocol, [])
    journal = [line for line in printer.journal_lines() if line not in own]
    assert [canonical(line) for line in journal] == [canonical(command) for command in commands]
    if protocol != "repetier":
        assert journal == commands


def test_a_host_that_dies_mid_print_and_a_new_one_lose_and_repeat_nothing(emulator, tmp_path):
    printer = emulator("--speed", "20")
    first = write_job(tmp_path / "first.gcode", 3000)
    second = write_job(tmp_path / "second.gcode", 200, start=5000)
    killed = subprocess.Popen(
        [BIN / "fake-marlin-host", "print", str(printer.link), str(tmp_path / "first.gcode")],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 30
    while len(printer.journal_lines()) < 50 and time.monotonic() < deadline:
        time.sleep(0.05)
    killed.kill()
    killed.wait()
    result = host("print", printer.link, tmp_path / "second.gcode")
    assert result.returncode == 0, result.stderr
    journal = printer.journal_lines()
    executed_first = journal[: len(journal) - len(second)]
    assert 50 <= len(executed_first) < len(first)
    assert executed_first == first[: len(executed_first)]
    assert journal[len(executed_first):] == second
    assert f"{len(second)}/{len(second)} commands" in result.stderr


def test_progress_summary_goes_to_stderr(emulator, tmp_path):
    printer = emulator("--speed", "1000")
    commands = write_job(tmp_path / "small.gcode", 20)
    result = host("print", printer.link, tmp_path / "small.gcode")
    assert result.returncode == 0
    assert f"{len(commands)}/{len(commands)} commands" in result.stderr
    assert "resends: 0" in result.stderr


def test_a_port_that_does_not_exist_is_a_clear_error(tmp_path):
    result = host("send", tmp_path / "nothing-here", "M105")
    assert result.returncode == 1
    assert "cannot open" in result.stderr and "No such file" in result.stderr
    assert "Traceback" not in result.stderr


def test_a_job_with_an_unsendable_line_is_refused_before_anything_is_sent(emulator, tmp_path):
    printer = emulator()
    (tmp_path / "bad.gcode").write_text("G28\nM117 " + "x" * 100 + "\n")
    result = host("print", printer.link, tmp_path / "bad.gcode")
    assert result.returncode == 2
    assert "bad.gcode:2" in result.stderr and "Traceback" not in result.stderr
    assert printer.journal_lines() == []
    assert host("print", printer.link, tmp_path / "missing.gcode").returncode == 2


def test_the_printer_vanishing_mid_print_is_reported(emulator, tmp_path):
    printer = emulator("--speed", "1")
    write_job(tmp_path / "slow.gcode", 500)
    running = subprocess.Popen(
        [BIN / "fake-marlin-host", "print", str(printer.link), str(tmp_path / "slow.gcode")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    time.sleep(1.0)
    printer.process.kill()
    _, stderr = running.communicate(timeout=30)
    assert running.returncode == 1
    assert "lost the connection" in stderr and "Traceback" not in stderr


@pytest.mark.parametrize(
    "args, message",
    [
        (["--speed", "0"], "must be a positive number"),
        (["--protocol", "nope"], "invalid choice"),
        (["--extruders", "x"], "whole number"),
    ],
)
def test_bad_flags_get_usage_errors(args, message):
    result = subprocess.run([BIN / "fake-marlin", *args], capture_output=True, text=True, timeout=10)
    assert result.returncode == 2 and message in result.stderr


def test_bad_paths_for_the_sd_card_and_the_control_socket_are_refused(tmp_path):
    precious = tmp_path / "notes.txt"
    precious.write_text("keep me")
    for args, message in [
        (["--sd-dir", str(tmp_path / "nowhere")], "--sd-dir: no directory"),
        (["--control", str(precious)], "is not a socket; refusing to replace it"),
        (["--control", str(tmp_path / "no" / "such.sock")], "--control: no directory"),
    ]:
        result = subprocess.run([BIN / "fake-marlin", *args], capture_output=True, text=True, timeout=10)
        assert result.returncode == 2 and message in result.stderr, result.stderr
        assert "Traceback" not in result.stderr
    assert precious.read_text() == "keep me"


def test_the_control_channel_works_from_another_process(emulator, tmp_path):
    from fake_marlin.emulator.control.client import ControlClient

    printer = emulator("--protocol", "marlin", "--control", str(tmp_path / "printer.control"))
    with ControlClient(str(tmp_path / "printer.control")) as control:
        control.set_temperature("T0", 99.5)
        assert control.state()["temperatures"]["T0"]["actual"] > 99
    result = host("send", printer.link, "M105", "--protocol", "marlin")
    assert result.stdout.startswith("T:9")


def test_an_existing_file_at_the_link_path_is_not_replaced(tmp_path):
    precious = tmp_path / "printer"
    precious.write_text("keep me")
    result = subprocess.run(
        [BIN / "fake-marlin", "--link", str(precious)], capture_output=True, text=True, timeout=10
    )
    assert result.returncode == 2 and "not a symlink" in result.stderr
    assert precious.read_text() == "keep me"


def test_a_line_that_hangs_up_comes_back_on_a_new_pty_behind_the_same_link(tmp_path):
    scenario = tmp_path / "unplug.toml"
    scenario.write_text(
        '[printer]\nprotocol = "marlin"\n'
        '[[fault]]\nkind = "disconnect"\ndirection = "to-host"\nat = 2.0\nseconds = 1.0\n'
    )
    link = tmp_path / "printer"
    printer = subprocess.Popen(
        [BIN / "fake-marlin", "--scenario", scenario, "--link", link],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        first = printer.stdout.readline().strip()
        write_job(tmp_path / "long.gcode", 3000)
        cut = host("print", link, tmp_path / "long.gcode", "--protocol", "marlin", timeout=60)
        assert cut.returncode == 1 and "lost the connection" in cut.stderr
        second = printer.stdout.readline().strip()  # announced when the line comes back
        assert first.startswith("/dev/pts/") and second.startswith("/dev/pts/")  # may be reused
        assert os.path.realpath(link) == second
        again = host("send", link, "M105", "--protocol", "marlin")
        assert again.returncode == 0 and again.stdout.startswith("T:")
    finally:
        printer.send_signal(signal.SIGINT)
        printer.wait(timeout=10)
    assert printer.returncode == 0 and not os.path.lexists(link)
