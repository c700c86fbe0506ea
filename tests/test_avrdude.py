"""avrdude flashes the printer through its Arduino Mega bootloader, over a real pty.

The real `fake-marlin` program with its defaults (`--protocol auto`: the bootloader answers a
connection whose first byte is an STK500v2 message) and Debian's avrdude, which `python -m
tests.hosts.install` installs where missing (tests/hosts/apt.py; without it the tests skip).
avrdude is run as the Arduino IDE runs it for a Mega: `-c wiring -p m2560 -b 115200 -D`: the
Mega's bootloader refuses CHIP_ERASE, and without -D avrdude stops there, on the board as here.
"""

import random
import subprocess
from pathlib import Path

import pytest
import serial

from fake_marlin.emulator.protocols.avr_memory import FLASH_SIZE, PAGE_SIZE
from fake_marlin.emulator.protocols.stk500 import encode_message
from tests.hosts import apt
from tests.hosts.install import not_installed

pytestmark = pytest.mark.e2e
IMAGE_SIZE = 12 * 1024
AVRDUDE_TIMEOUT = 120


@pytest.fixture(scope="module")
def avrdude() -> str:
    path = apt.find(apt.AVRDUDE)
    if path is None:
        pytest.skip(not_installed(apt.AVRDUDE.label))
    return path


def image(seed: int, size: int = IMAGE_SIZE) -> bytes:
    """Random bytes, whose last is not 0xFF: avrdude leaves trailing 0xFF out of what it reads."""
    rng = random.Random(seed)
    data = bytearray(rng.randbytes(size))
    data[-1] &= 0x7F
    return bytes(data)


def intel_hex(data: bytes, start: int = 0) -> str:
    """`data` at byte `start`, as Intel hex with extended linear address records."""
    lines, upper = [], None
    for offset in range(0, len(data), 16):
        address = start + offset
        if address >> 16 != upper:
            upper = address >> 16
            lines.append(_record(0, 4, upper.to_bytes(2, "big")))
        lines.append(_record(address & 0xFFFF, 0, data[offset:offset + 16]))
    return "\n".join([*lines, _record(0, 1, b"")]) + "\n"


def _record(address: int, kind: int, payload: bytes) -> str:
    record = bytes((len(payload),)) + address.to_bytes(2, "big") + bytes((kind,)) + payload
    return f":{(record + bytes((-sum(record) & 0xFF,))).hex().upper()}"


def run_avrdude(avrdude: str, port: str, *args: str, programmer: str = "wiring"):
    command = [avrdude, "-c", programmer, "-p", "m2560", "-P", port, "-b", "115200", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=AVRDUDE_TIMEOUT)


def read_flash(avrdude: str, port: str, where: Path) -> bytes:
    """The whole flash as avrdude reads it back (trailing erased bytes left out)."""
    done = run_avrdude(avrdude, port, "-U", f"flash:r:{where}:r")
    assert done.returncode == 0, done.stderr
    return where.read_bytes()


def firmware_lines(port: str, command: str) -> list[str]:
    """The firmware's reply to `command` on a new connection (which resets the board)."""
    with serial.Serial(port, 115200, timeout=10) as line:
        line.write(f"{command}\n".encode())
        lines: list[str] = []
        while not lines or not lines[-1].startswith("ok"):
            raw = line.readline()
            assert raw.endswith(b"\n"), lines
            lines.append(raw.decode("ascii", "replace").strip())
    return lines


def assert_firmware_answers(port: str) -> None:
    lines = firmware_lines(port, "M115")
    assert lines[0] == "start"
    assert any(line.startswith("FIRMWARE_NAME:Marlin") for line in lines), lines
    assert lines[-1] == "ok"


@pytest.mark.parametrize("programmer, form", [("wiring", "ihex"), ("stk500v2", "raw")])
def test_avrdude_writes_verifies_and_reads_back_a_firmware(
    avrdude, fake_printer, tmp_path, programmer, form
):
    data = image(seed=2560)
    source = tmp_path / f"firmware.{'hex' if form == 'ihex' else 'bin'}"
    if form == "ihex":
        source.write_text(intel_hex(data))
    else:
        source.write_bytes(data)
    done = run_avrdude(
        avrdude, fake_printer.port, "-D", "-U", f"flash:w:{source}:{form[0]}", programmer=programmer
    )
    assert done.returncode == 0, done.stderr
    assert "device signature = 0x1e9801" in done.stderr
    assert f"{IMAGE_SIZE} bytes of flash verified" in done.stderr
    assert read_flash(avrdude, fake_printer.port, tmp_path / "back.bin") == data
    assert_firmware_answers(fake_printer.port)


def test_an_image_past_64_kib_goes_where_its_extended_addresses_say(
    avrdude, fake_printer, tmp_path
):
    """avrdude marks flash addresses with bit 31 and counts words past 0xFFFF: the board's
    RAMPZ pages, across the 128 KiB line here."""
    data, start = image(seed=1), 0x20000 - 8 * PAGE_SIZE
    (tmp_path / "high.hex").write_text(intel_hex(data, start))
    done = run_avrdude(avrdude, fake_printer.port, "-D", "-U", f"flash:w:{tmp_path / 'high.hex'}:i")
    assert done.returncode == 0, done.stderr
    assert f"{IMAGE_SIZE} bytes of flash verified" in done.stderr
    back = read_flash(avrdude, fake_printer.port, tmp_path / "back.bin")
    assert back == b"\xff" * start + data


def test_a_page_lost_on_the_way_fails_the_verify_and_flashing_again_mends_it(
    avrdude, fake_printer_factory, tmp_path
):
    """Faults act on the bootloader's messages: the sixth page message is dropped. avrdude
    resyncs after its 5 s and goes on without that page, and the bootloader's erase count now
    runs a page behind the pages written: as on a Mega, the verify fails."""
    page_message = "(?s)^\\x1b.\\x01\\x0a\\x0e\\x13"  # PROGRAM_FLASH_ISP of 256 bytes
    lost = {"kind": "drop", "direction": "to-printer", "nth": 6, "pattern": page_message}
    printer = fake_printer_factory(faults=[lost])
    data = image(seed=6)
    (tmp_path / "firmware.bin").write_bytes(data)
    write = ("-D", "-U", f"flash:w:{tmp_path / 'firmware.bin'}:r")
    done = run_avrdude(avrdude, printer.port, *write)
    assert done.returncode != 0
    assert "timeout" in done.stderr and "verification mismatch" in done.stderr
    done = run_avrdude(avrdude, printer.port, *write)  # a new connection: a new count
    assert done.returncode == 0, done.stderr
    assert f"{IMAGE_SIZE} bytes of flash verified" in done.stderr


def test_without_d_avrdude_stops_at_the_chip_erase_the_mega_refuses(
    avrdude, fake_printer, tmp_path
):
    (tmp_path / "firmware.bin").write_bytes(image(seed=3))
    done = run_avrdude(avrdude, fake_printer.port, "-U", f"flash:w:{tmp_path / 'firmware.bin'}:r")
    assert done.returncode != 0
    assert "erasing chip" in done.stderr and "command failed" in done.stderr
    assert read_flash(avrdude, fake_printer.port, tmp_path / "back.bin") == b""  # untouched
    assert_firmware_answers(fake_printer.port)


def test_a_flash_cut_short_keeps_the_pages_written_and_the_firmware_runs(
    avrdude, fake_printer, tmp_path
):
    """A host that closes the port after two of its pages (avrdude killed, a cable pulled).

    (A message cut in half is tests/test_stk500.py's: on a pty, bytes still unread when the
    host closes can reach the printer after the next open's reset, which the kernel reports
    first; a real board reads them before.)"""
    data = image(seed=4)
    with serial.Serial(fake_printer.port, 115200, timeout=10) as line:
        messages = [bytes((0x10, 200, 100, 25, 32, 0, 0x53, 3, 0xAC, 0x53, 0, 0)),  # ENTER
                    bytes((0x06, 0x80, 0, 0, 0))]  # LOAD_ADDRESS 0, extended
        for page in range(2):
            chunk = data[page * PAGE_SIZE:(page + 1) * PAGE_SIZE]
            messages.append(bytes((0x13, 1, 0, 0xC1, 10, 0x40, 0x4C, 0x20, 0, 0)) + chunk)
        for seq, body in enumerate(messages, start=1):
            line.write(encode_message(seq, body))
            reply = line.read(8)
            assert reply == encode_message(seq, bytes((body[0], 0))), reply
    assert_firmware_answers(fake_printer.port)
    assert read_flash(avrdude, fake_printer.port, tmp_path / "back.bin") == data[:2 * PAGE_SIZE]


def test_a_flash_file_keeps_the_firmware_across_runs(avrdude, fake_printer_factory, tmp_path):
    flash_file, data = tmp_path / "mega.bin", image(seed=5)
    (tmp_path / "firmware.hex").write_text(intel_hex(data))
    first = fake_printer_factory(extra_args=["--flash-file", str(flash_file)])
    assert flash_file.read_bytes() == b"\xff" * FLASH_SIZE  # created erased
    done = run_avrdude(avrdude, first.port, "-D", "-U", f"flash:w:{tmp_path / 'firmware.hex'}:i")
    assert done.returncode == 0, done.stderr
    first.process.kill()  # no clean exit: each page went to the file as it was written
    first.process.wait()
    first.stop(check=False)
    assert flash_file.read_bytes() == data + b"\xff" * (FLASH_SIZE - len(data))
    second = fake_printer_factory(extra_args=["--flash-file", str(flash_file)])
    assert read_flash(avrdude, second.port, tmp_path / "back.bin") == data
    assert_firmware_answers(second.port)
