"""The protocol lab's variants end to end: the real programs over a real pty, as a user runs
them (`fake-marlin --variant`, `fake-marlin-host --variant`, `fake-marlin verify`), and the
library's host against the pytest fixture's printer."""

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from fake_marlin.host import ClientOptions, open_printer
from fake_marlin.wire.gcode import strip_comment

pytestmark = pytest.mark.e2e
BIN = Path(sys.executable).parent


def write_job(path: Path, count: int) -> list[str]:
    lines = ["; a job for the protocol lab", "G28", "M105", "G1 Z0.3 F600 ; first layer", ""]
    lines += [f"G1 X{(n % 100) / 2:.1f} Y{(n % 37) / 2:.1f} E{n / 100:.2f} F6000"
              for n in range(count)]
    lines += ["M400", "M114"]
    path.write_text("\n".join(lines) + "\n")
    return [command for line in lines if (command := strip_comment(line))]


class Printer:
    """`fake-marlin` started as a user starts it; the pty path is its first line on stdout."""

    def __init__(self, *args: str) -> None:
        self.process = subprocess.Popen([BIN / "fake-marlin", *args], stdout=subprocess.PIPE,
                                        stderr=subprocess.PIPE, text=True)
        assert self.process.stdout is not None
        self.port = self.process.stdout.readline().strip()
        if not self.port.startswith("/dev/"):
            self.process.kill()
            raise AssertionError(f"no pty announced: {self.process.communicate()[1]}")

    def stop(self) -> str:
        self.process.send_signal(signal.SIGINT)  # as Ctrl-C
        _, stderr = self.process.communicate(timeout=20)
        assert self.process.returncode == 0 and "Traceback" not in stderr, stderr
        return stderr

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.communicate()


def run(program: str, *args: object, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([BIN / program, *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def test_the_programs_print_a_job_with_ack_and_compact_oob_each_command_once(tmp_path):
    journal = tmp_path / "journal.log"
    job = tmp_path / "job.gcode"
    commands = write_job(job, 1500)
    printer = Printer("--protocol", "ultimaker", "--variant", "ack,compact-oob", "--journal",
                      str(journal), "--speed", "200", "--sd-dir", str(tmp_path))
    try:
        printed = run("fake-marlin-host", "print", "--variant", "ack,compact-oob", printer.port,
                      job)
        assert printed.returncode == 0, printed.stderr
        assert f"{len(commands)}/{len(commands)} commands" in printed.stderr
        assert "resends: 0" in printed.stderr
    except BaseException:
        printer.kill()
        raise
    printer.stop()
    verified = run("fake-marlin", "verify", job, journal)
    assert verified.returncode == 0, verified.stdout + verified.stderr
    assert verified.stdout.startswith(f"OK: each of the {len(commands)} job commands ran once")
    assert journal.read_text().splitlines() == commands


async def test_the_library_host_prints_on_the_fixtures_crc8_7bit_printer(fake_printer_factory):
    printer = fake_printer_factory(protocol="ultimaker", variants="crc8,7bit", speed=200)
    job = ["G28", *(f"G1 X{n % 50} Y{n % 30} F6000" for n in range(400)), "M400"]
    options = ClientOptions(variants="crc8,7bit")
    async with open_printer(printer.port, protocol="ultimaker", options=options) as host:
        summary = await host.print_commands(job)
        reply = await host.send("M105")
    assert summary.commands == len(job) and summary.resends == 0
    assert any(line.startswith("T:") for line in reply)
    assert printer.journal == [*job, "M105"]


def test_a_plain_host_against_a_variant_printer_stops_with_exit_1_and_runs_nothing(
        fake_printer_factory, tmp_path):
    printer = fake_printer_factory(protocol="ultimaker", variants="ack,crc8")
    job = tmp_path / "job.gcode"
    write_job(job, 20)
    result = run("fake-marlin-host", "print", printer.port, job, timeout=60)
    assert result.returncode == 1
    assert result.stderr.strip().splitlines()[-1] == (
        "fake-marlin-host: the printer does not speak this host's protocol (plain v3): it "
        "speaks variants ack,crc8; give both sides the same --variant")
    assert "Traceback" not in result.stderr
    assert printer.journal == []
    # and the same host, told the printer's variants, prints on the same printer
    again = run("fake-marlin-host", "send", "--variant", "crc8,ack", printer.port, "M114",
                timeout=60)
    assert again.returncode == 0, again.stderr
    assert again.stdout.startswith("X:0.00 Y:0.00")
    assert printer.journal == ["M114"]


def test_a_7bit_host_opens_the_same_pty_again_and_again(tmp_path):
    # Linux refuses CS7 (EINVAL) on a pty once a rate such as 250000 has been set on it: the
    # second `fake-marlin-host` on the same printer died with a termios traceback.
    printer = Printer("--protocol", "ultimaker", "--variant", "crc8,7bit")
    try:
        for _ in range(3):
            done = run("fake-marlin-host", "send", "--variant", "crc8,7bit", printer.port, "M105",
                       timeout=30)
            assert done.returncode == 0 and done.stdout.startswith("T:"), done.stderr
    finally:
        printer.stop()


def test_a_port_that_refuses_its_settings_is_one_line_not_a_traceback(tmp_path):
    done = run("fake-marlin-host", "send", "/dev/null", "M105", timeout=30)
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.startswith("fake-marlin-host: cannot open /dev/null"), done.stderr
