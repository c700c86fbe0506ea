"""The real command-line programs over a real pty, as a user runs them."""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fake_marlin.wire.gcode import canonical, strip_comment

pytestmark = pytest.mark.e2e
BIN = Path(sys.executable).parent


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


def test_the_pty_path_comes_first_and_ctrl_c_cleans_up(fake_printer_factory, tmp_path):
    link = tmp_path / "printer"
    printer = fake_printer_factory(link=link)
    assert printer.port.startswith("/dev/pts/")
    assert os.path.realpath(link) == printer.port
    printer.stop(check=False)
    code, stderr = printer.returncode, printer.stderr
    assert code == 0 and "Traceback" not in stderr
    assert not os.path.lexists(link)


def test_send_prints_the_response_data(fake_printer_factory, tmp_path):
    link = tmp_path / "printer"
    printer = fake_printer_factory(link=link)
    result = host("send", link, "M105")
    assert result.returncode == 0, result.stderr
    assert result.stdout == "T:21.00 /0.00 B:21.00 /0.00 @:0 B@:0\n"
    assert host("send", printer.port, "M114").stdout.startswith("X:0.00 Y:0.00 Z:0.00 E:0.00 Count")


def test_a_ten_thousand_command_print_is_journaled_exactly(fake_printer_factory, tmp_path):
    link = tmp_path / "printer"
    printer = fake_printer_factory(speed=1000, link=link)
    commands = write_job(tmp_path / "part.gcode", 10_000)
    result = host("print", link, tmp_path / "part.gcode", "--json")
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["commands"] == len(commands)
    assert set(summary) >= {"commands", "packets_sent", "resends", "timeouts", "elapsed"}
    assert printer.journal == commands


@pytest.mark.parametrize("protocol", ["ultimaker", "marlin", "repetier", "commstack"])
def test_each_protocol_prints_a_job_through_auto_detection(fake_printer_factory, tmp_path, protocol):
    """One printer in `--protocol auto`; each host's first bytes choose its protocol."""
    link = tmp_path / "printer"
    printer = fake_printer_factory(protocol="auto", speed=1000, link=link)
    commands = write_job(tmp_path / "part.gcode", 1500)
    result = host("print", link, tmp_path / "part.gcode", "--protocol", protocol, "--json")
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["commands"] == len(commands)
    # Repetier's host asks for M115 itself, CommStack's polls M27 while the stored job prints;
    # a binary command reaches the journal in the firmware's words (`E0` for `E0.00`), which
    # canonical() reads as the same command.
    own = {"repetier": ["M115"], "commstack": ["M27", "M27 C"]}.get(protocol, [])
    journal = [line for line in printer.journal if line not in own]
    assert [canonical(line) for line in journal] == [canonical(command) for command in commands]
    if protocol != "repetier":
        assert journal == commands


def test_a_host_that_dies_mid_print_and_a_new_one_lose_and_repeat_nothing(fake_printer_factory, tmp_path):
    link = tmp_path / "printer"
    printer = fake_printer_factory(speed=20, link=link)
    first = write_job(tmp_path / "first.gcode", 3000)
    second = write_job(tmp_path / "second.gcode", 200, start=5000)
    killed = subprocess.Popen(
        [BIN / "fake-marlin-host", "print", str(link), str(tmp_path / "first.gcode")],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 30
    while len(printer.journal) < 50 and time.monotonic() < deadline:
        time.sleep(0.05)
    killed.kill()
    killed.wait()
    result = host("print", link, tmp_path / "second.gcode")
    assert result.returncode == 0, result.stderr
    journal = printer.journal
    executed_first = journal[: len(journal) - len(second)]
    assert 50 <= len(executed_first) < len(first)
    assert executed_first == first[: len(executed_first)]
    assert journal[len(executed_first):] == second
    assert f"{len(second)}/{len(second)} commands" in result.stderr


def test_progress_summary_goes_to_stderr(fake_printer_factory, tmp_path):
    link = tmp_path / "printer"
    fake_printer_factory(speed=1000, link=link)
    commands = write_job(tmp_path / "small.gcode", 20)
    result = host("print", link, tmp_path / "small.gcode")
    assert result.returncode == 0
    assert f"{len(commands)}/{len(commands)} commands" in result.stderr
    assert "resends: 0" in result.stderr


def test_a_port_that_does_not_exist_is_a_clear_error(tmp_path):
    result = host("send", tmp_path / "nothing-here", "M105")
    assert result.returncode == 1
    assert "cannot open" in result.stderr and "No such file" in result.stderr
    assert "Traceback" not in result.stderr


def test_a_job_with_an_unsendable_line_is_refused_before_anything_is_sent(fake_printer_factory, tmp_path):
    link = tmp_path / "printer"
    printer = fake_printer_factory(link=link)
    (tmp_path / "bad.gcode").write_text("G28\nM117 " + "x" * 100 + "\n")
    result = host("print", link, tmp_path / "bad.gcode")
    assert result.returncode == 2
    assert "bad.gcode:2" in result.stderr and "Traceback" not in result.stderr
    assert printer.journal == []
    assert host("print", link, tmp_path / "missing.gcode").returncode == 2


def test_the_printer_vanishing_mid_print_is_reported(fake_printer_factory, tmp_path):
    link = tmp_path / "printer"
    printer = fake_printer_factory(speed=1, link=link)
    write_job(tmp_path / "slow.gcode", 500)
    running = subprocess.Popen(
        [BIN / "fake-marlin-host", "print", str(link), str(tmp_path / "slow.gcode")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    time.sleep(1.0)
    printer.process.kill()  # on purpose: no clean stop to check
    printer.stop(check=False)
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


def test_the_control_channel_works_from_another_process(fake_printer_factory, tmp_path):
    link = tmp_path / "printer"
    printer = fake_printer_factory(protocol="marlin", link=link)  # it serves --control
    control = printer.control  # a ControlClient on that socket, from this (another) process
    control.set_temperature("T0", 99.5)
    assert control.state()["temperatures"]["T0"]["actual"] > 99
    result = host("send", link, "M105", "--protocol", "marlin")
    assert result.stdout.startswith("T:9")


def test_an_existing_file_at_the_link_path_is_not_replaced(tmp_path):
    precious = tmp_path / "printer"
    precious.write_text("keep me")
    result = subprocess.run(
        [BIN / "fake-marlin", "--link", str(precious)], capture_output=True, text=True, timeout=10
    )
    assert result.returncode == 2 and "not a symlink" in result.stderr
    assert precious.read_text() == "keep me"


def test_a_line_that_hangs_up_comes_back_on_a_new_pty_behind_the_same_link(fake_printer_factory, tmp_path):
    scenario = tmp_path / "unplug.toml"
    scenario.write_text(
        '[printer]\nprotocol = "marlin"\n'
        '[[fault]]\nkind = "disconnect"\ndirection = "to-host"\nat = 2.0\nseconds = 1.0\n'
    )
    link = tmp_path / "printer"
    printer = fake_printer_factory(scenario=scenario, link=link)
    first = printer.wait_for_port(1)
    write_job(tmp_path / "long.gcode", 3000)
    cut = host("print", link, tmp_path / "long.gcode", "--protocol", "marlin", timeout=60)
    assert cut.returncode == 1 and "lost the connection" in cut.stderr
    second = printer.wait_for_port(2)  # announced on stdout when the line comes back
    assert first.startswith("/dev/pts/") and second.startswith("/dev/pts/")  # may be reused
    assert os.path.realpath(link) == second == printer.port
    again = host("send", link, "M105", "--protocol", "marlin")
    assert again.returncode == 0 and again.stdout.startswith("T:")
    printer.stop(check=False)
    assert printer.returncode == 0 and not os.path.lexists(link)
