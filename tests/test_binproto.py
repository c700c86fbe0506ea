"""Marlin's own binary transfer client, binproto2 (PyPI marlin-binary-protocol, as
OctoPrint-FirmwareUpdater's `marlinbft` uses it), unchanged, against `fake-marlin --protocol
marlin` on its pty: a 100 KiB job lands on the SD card byte for byte, plain and heatshrink
compressed, also through bit errors on the way to the printer, and the printer speaks ASCII
again afterwards.

binproto2 runs in a venv of its own (tests/hosts/venvs.py), installed `--no-deps` beside
heatshrink2 and pyserial (it also asks for `heatshrink`, which it only falls back from) by
`python -m tests.hosts.install`; without it the tests skip and name that command.
"""

import json
import subprocess
from pathlib import Path

import pytest

from tests.hosts import venvs
from tests.test_real_hosts import EMULATOR, host_python

pytestmark = pytest.mark.e2e
DRIVER = Path(__file__).parent / "hosts" / "binproto_driver.py"
DRIVER_TIMEOUT = 120
JOB_SIZE = 100 * 1024
BIT_ERRORS = "to-printer:bit-errors=1e-4"  # one packet in a dozen damaged


@pytest.fixture(scope="session")
def binproto_python():
    return host_python(venvs.BINPROTO)


def write_job(path: Path) -> bytes:
    """A deterministic job of moves, cut to JOB_SIZE bytes at a line end."""
    lines, size, n = [], 0, 0
    while size < JOB_SIZE:
        line = f"G1 X{10 + n % 40}.{n % 10} Y{10 + n % 23}.5 E{n / 50:.3f} F3000\n"
        lines.append(line)
        size += len(line)
        n += 1
    data = "".join(lines).encode()[:JOB_SIZE]
    data = data[:data.rindex(b"\n") + 1]
    path.write_bytes(data)
    return data


def upload(python: Path, port: str, job: Path, name: str, compress: bool) -> dict:
    command = [python, DRIVER, port, job, name, "--timeout", str(DRIVER_TIMEOUT)]
    try:
        done = subprocess.run([*command, *(["--compress"] if compress else [])],
                              capture_output=True, text=True, timeout=DRIVER_TIMEOUT + 30)
    except subprocess.TimeoutExpired as timeout:
        pytest.fail(f"binproto_driver.py ignored its own timeout: {timeout.stderr!r}")
    try:
        report = json.loads(done.stdout.strip().splitlines()[-1])
    except (IndexError, ValueError):
        pytest.fail(f"binproto_driver.py exited {done.returncode} without a report:\n"
                    f"{done.stdout}\n{done.stderr}")
    logged = report["logged"]
    brief = {**report, "logged": [line for line in logged if "PROGRESS" not in line][-40:]}
    assert done.returncode == 0 and not report["errors"], json.dumps(brief, indent=1)
    report["packets"] = sum("PROGRESS" in line for line in logged) - 1  # its 100% line is extra
    report["resend_requests"] = sum("Resend request" in line for line in logged)
    return report


def printer_options(sd: Path, *extra: str) -> dict:
    """An instant boot: binproto2 sends M28B1 straight away, and its reader thread flushes the
    port once more as it starts, which resets nothing (only an open does, link/opens.py)."""
    sd.mkdir()
    return {"program": EMULATOR, "protocol": "marlin", "sd_dir": sd, "extra_args": list(extra)}


def assert_on_the_card_and_listed(sd: Path, name: str, data: bytes, report: dict) -> None:
    assert (sd / name).read_bytes() == data
    assert f"{name.upper()} {len(data)}" in report["listing"]
    assert "Cap:BINARY_FILE_TRANSFER:1" in report["capabilities"]


def test_a_job_uploaded_plain_and_compressed_lands_on_the_card_byte_for_byte(
        fake_printer_factory, binproto_python, tmp_path):
    sd = tmp_path / "sd"
    printer = fake_printer_factory(**printer_options(sd))
    data = write_job(tmp_path / "job.gcode")
    plain = upload(binproto_python, printer.port, tmp_path / "job.gcode", "job.gco", compress=False)
    packed = upload(binproto_python, printer.port, tmp_path / "job.gcode", "jobz.gco", compress=True)
    for name, report in (("job.gco", plain), ("jobz.gco", packed)):
        assert_on_the_card_and_listed(sd, name, data, report)
        assert report["resend_requests"] == 0
        assert "INFO: Connection synced [0], binary protocol version 0.1.0, 96 byte payload buffer" in (
            report["logged"])
        assert "INFO: File Transfer version: 0.1.0, compression: heatshrink" in report["logged"]
        assert f"INFO: Opened file: {name}" in report["logged"]
    assert plain["packets"] == -(-len(data) // 96)
    assert packed["packets"] < plain["packets"] / 2  # heatshrink (8, 4) as negotiated did its work


def test_bit_errors_to_the_printer_cost_resends_never_a_byte(
        fake_printer_factory, binproto_python, tmp_path):
    sd = tmp_path / "sd"
    printer = fake_printer_factory(**printer_options(sd, "--fault", BIT_ERRORS), seed=3)
    data = write_job(tmp_path / "job.gcode")
    for name, compress in (("job.gco", False), ("jobz.gco", True)):
        report = upload(binproto_python, printer.port, tmp_path / "job.gcode", name, compress)
        assert_on_the_card_and_listed(sd, name, data, report)
        assert report["resend_requests"] > 5, "the fault layer provoked too few errors to prove anything"
        assert report["protocol_errors"] > 0  # what binproto2 counted, rs and timeouts
