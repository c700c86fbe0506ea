"""The test surface other projects use (fake_marlin.testing and the pytest plugin), as they use it:
threaded hosts from plain tests, trio hosts from trio tests, faults and the control channel."""

import signal
import time

import pytest
import serial

from fake_marlin.host import open_printer
from fake_marlin.testing import PrinterCrashed, running_printer

pytestmark = pytest.mark.e2e
pytest_plugins = ["pytester"]


def exchange(port: str, *lines: str, until: bytes = b"ok", timeout: float = 5.0) -> bytes:
    """Send lines the way a pyserial script does; read until `until` has come once per line."""
    with serial.Serial(port, 250000, timeout=0.1) as link:
        link.reset_input_buffer()
        link.write("".join(line + "\n" for line in lines).encode())
        received = b""
        deadline = time.monotonic() + timeout
        while received.count(until) < len(lines) and time.monotonic() < deadline:
            received += link.read(4096)
        return received


def test_a_plain_test_drives_the_default_printer_with_pyserial(fake_printer):
    assert fake_printer.port.startswith("/dev/pts/")
    reply = exchange(fake_printer.port, "M105", "M114")
    assert b"T:" in reply and b"X:0.00" in reply
    assert fake_printer.journal == ["M105", "M114"]


async def test_a_trio_test_drives_a_printer_with_our_host(fake_printer_factory):
    printer = fake_printer_factory(protocol="ultimaker", speed=100)
    async with open_printer(printer.port, protocol="ultimaker") as host:
        summary = await host.print_commands(["G28", "G1 X10 Y10 F3000", "M400"])
        assert summary.commands == 3
        assert any(line.startswith("T:") for line in await host.send("M105"))
    assert printer.journal == ["G28", "G1 X10 Y10 F3000", "M400", "M105"]


def test_the_control_channel_scripts_the_printer_while_a_host_is_on_it(fake_printer_factory):
    printer = fake_printer_factory(protocol="marlin")
    printer.control.set_target("B", 60)
    printer.control.set_temperature("T0", 215)
    state = printer.control.state()
    assert state["protocol"] is None or state["protocol"] == "marlin"
    printer.control.inject(kind="thermal-runaway", heater="T0")
    assert printer.control.state()["halted"]


def test_faults_are_given_as_scenario_tables(fake_printer_factory):
    printer = fake_printer_factory(
        protocol="marlin", faults=[{"kind": "firmware-error", "text": "Injected", "nth": 2}]
    )
    reply = exchange(printer.port, "M105", "M114")
    assert b"Error:Injected" in reply


def test_more_printers_each_on_its_own_pty(fake_printer_factory):
    printers = [fake_printer_factory(protocol="marlin", speed=10) for _ in range(3)]
    assert len({printer.port for printer in printers}) == 3
    for number, printer in enumerate(printers):
        exchange(printer.port, f"M117 printer {number}")
    assert [printer.journal for printer in printers] == [[f"M117 printer {n}"] for n in range(3)]


def test_running_printer_serves_scripts_without_pytest():
    with running_printer(protocol="marlin", speed=100) as printer:
        exchange(printer.port, "M115")
        assert printer.journal == ["M115"]
    assert printer.returncode == 0 and "Traceback" not in printer.stderr
    assert printer.journal == ["M115"]  # still there once it has stopped


def test_a_printer_that_dies_is_reported_with_its_exit():
    with pytest.raises(PrinterCrashed, match="exited with code -9"):
        with running_printer() as printer:
            printer.process.send_signal(signal.SIGKILL)
            printer.process.wait()
            printer.journal  # noqa: B018 - reading it after the crash is what raises


def test_a_bad_option_is_reported_with_what_the_printer_said():
    with pytest.raises(PrinterCrashed, match="(?s)did not start.*kind: must be one of"):
        with running_printer(faults=[{"kind": "no-such-fault"}]):
            pass


def test_the_plugin_fails_a_test_whose_printer_crashed(pytester):
    pytester.makepyfile(
        """
        import signal

        def test_host(fake_printer):
            fake_printer.process.send_signal(signal.SIGKILL)
            fake_printer.process.wait()
        """
    )
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(passed=1, errors=1)
    result.stdout.fnmatch_lines(["*fake_printer on /dev/pts/*the printer exited with code -9*"])


def test_opening_the_port_resets_the_printer_and_a_flush_does_not(fake_printer):
    """A board resets on DTR when a host opens its port, not when the host flushes its input:
    binproto2, for one, flushes again right after opening."""
    boots = fake_printer.control.state()["boots"]
    with serial.Serial(fake_printer.port, 250000, timeout=0.1) as link:
        deadline = time.monotonic() + 5
        while fake_printer.control.state()["boots"] == boots and time.monotonic() < deadline:
            time.sleep(0.01)
        opened = fake_printer.control.state()["boots"]
        assert opened == boots + 1
        for _ in range(3):
            link.reset_input_buffer()
            link.write(b"M105\n")
            received = b""
            while b"ok" not in received and time.monotonic() < deadline:
                received += link.read(4096)
            assert b"T:" in received
        assert fake_printer.control.state()["boots"] == opened
    with serial.Serial(fake_printer.port, 250000, timeout=0.1):
        deadline = time.monotonic() + 5
        while fake_printer.control.state()["boots"] == opened and time.monotonic() < deadline:
            time.sleep(0.01)
        assert fake_printer.control.state()["boots"] == opened + 1
