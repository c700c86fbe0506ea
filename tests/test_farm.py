"""Many printers in one process: `--printers N`, farm files, and the control channel by number."""

import json
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from fake_marlin.emulator.cli.farm import load_farm
from fake_marlin.emulator.cli.links import Address
from fake_marlin.emulator.scenario.definition import ScenarioError
from fake_marlin.emulator.control.client import ControlClient, ControlRequestError
from fake_marlin.host import open_printer

FAKE_MARLIN = Path(sys.executable).parent / "fake-marlin"
ROOT = Path(__file__).parent.parent


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "farm.toml"
    path.write_text(text)
    return path


def test_a_farm_file_numbers_its_printers_and_gives_each_its_own_paths_ports_and_seed(tmp_path):
    path = write(tmp_path, f"""
[[printer]]
count = 3
protocol = "marlin"
journal = "logs/{{n}}.log"
link = "/tmp/farm-{{n}}"
seed = 7
[[printer.fault]]
kind = "bit-errors"
direction = "to-printer"
rate = 1e-4

[[printer]]
scenario = "{ROOT}/scenarios/um3-noisy-serial.toml"
tcp = "0.0.0.0:9100"
count = 2
""")
    plans = load_farm(path)
    assert [plan.number for plan in plans] == [1, 2, 3, 4, 5]
    assert [plan.setup.protocol for plan in plans] == ["marlin"] * 3 + ["ultimaker"] * 2
    assert [plan.journal for plan in plans[:3]] == [str(tmp_path / f"logs/{n}.log") for n in (1, 2, 3)]
    assert [plan.link for plan in plans[:3]] == ["/tmp/farm-1", "/tmp/farm-2", "/tmp/farm-3"]
    assert [plan.faults.seed for plan in plans[:3]] == [7, 8, 9]  # their noise differs
    assert plans[0].faults.to_printer.bit_error_rate == 1e-4
    assert [plan.tcp for plan in plans[3:]] == [Address("0.0.0.0", 9100), Address("0.0.0.0", 9101)]
    assert plans[3].faults.to_printer == plans[4].faults.to_printer != plans[0].faults.to_printer


def test_a_farm_file_gives_each_printer_the_identity_its_templates_say(tmp_path):
    plans = load_farm(write(tmp_path, """
[[printer]]
count = 2
firmware = "prusa"
serial = "CZPX4720X{number:03d}X{letter}{d:05d}"
machine_name = "Shelf B, MK3S #{number}"
uuid = "00000000-0000-4000-8000-{number:012d}"
"""))
    assert [plan.serial for plan in plans] == ["CZPX4720X{number:03d}X{letter}{d:05d}"] * 2
    assert [plan.uuid for plan in plans] == ["00000000-0000-4000-8000-{number:012d}"] * 2


@pytest.mark.parametrize("text, message", [
    ("", "no [[printer]] tables"),
    ("[[printer]]\ncolour = 1", "[[printer]] #1 colour: is not a key this table knows"),
    ("[[printer]]\ncount = 0", "[[printer]] #1 count: must be at least 1"),
    ("[[printer]]\ncount = 2\njournal = 'same.log'", "printers 1 and 2 would share the journal"),
    ("[[printer]]\ntcp = 9000\n[[printer]]\ntcp = 9000", "printers 1 and 2 would share port 9000"),
    ("[[printer]]\ntcp = 'x:port'", "[[printer]] #1 tcp: the port must be a number"),
    ("[[printer]]\ntcp = 1\nlink = '/tmp/x'", "a printer on TCP has no pty"),
    ("[[printer]]\nscenario = 'nowhere.toml'", "[[printer]] #1 scenario:"),
    ("[[printer]]\nscenario = 'x.toml'\nprotocol = 'marlin'", "protocol: comes from the scenario"),
    ("[[printer]]\nprotocol = 'telepathy'", "[[printer]] #1 protocol: must be one of"),
    ("[[printer]]\n[[printer.fault]]\nkind = 'melt'", "[[printer.fault]] #1: kind: must be one of"),
    ("printer = [", "not valid TOML"),
    ("[[printer]]\nserial = 'SN{bogus}'", "[[printer]] #1 serial: 'SN{bogus}' is not a template"),
    ("[[printer]]\ncount = 2\nmachine_name = 'Same'", "machine_name: 2 printers would share it"),
])
def test_a_bad_farm_file_names_the_printer_the_key_and_the_problem(tmp_path, text, message):
    with pytest.raises(ScenarioError) as refused:  # a FarmError, or the scenario's own
        load_farm(write(tmp_path, text))
    assert str(refused.value).startswith(f"{tmp_path / 'farm.toml'}: ")
    assert message in str(refused.value)


class Farm:
    """A `fake-marlin` process serving several printers, its paths read from stdout."""

    def __init__(self, args: list[str], count: int) -> None:
        self.process = subprocess.Popen(
            [FAKE_MARLIN, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        assert self.process.stdout is not None
        self.paths = [self.process.stdout.readline().strip() for _ in range(count)]

    def stop(self) -> str:
        self.process.terminate()
        _, stderr = self.process.communicate(timeout=10)
        assert self.process.returncode == 0, stderr
        return stderr


@pytest.mark.e2e
async def test_printers_share_a_process_and_nothing_else(fake_printer_factory, tmp_path):
    job = [f"G1 X{n} F6000" for n in range(1, 41)]
    farm = fake_printer_factory(printers=3, protocol="marlin", speed=100,
                                link=tmp_path / "printer-{n}")
    assert len(set(farm.ports)) == 3 and all(p.startswith("/dev/") for p in farm.ports)
    for n in (1, 2, 3):
        assert (tmp_path / f"printer-{n}").resolve() == Path(farm.printer(n).port)
    async with open_printer(str(tmp_path / "printer-2"), protocol="marlin") as host:
        await host.print_commands(job)
    assert farm.printer(2).journal[-40:] == job
    assert farm.printer(1).journal == farm.printer(3).journal == []
    listed = farm.control.printers()
    assert [(p["printer"], p["path"]) for p in listed] == list(enumerate(farm.ports, 1))
    assert [p["boots"] for p in listed] == [1, 2, 1]  # only the port opened reset
    with pytest.raises(ControlRequestError, match="3 printers are served here: say which"):
        farm.control.state()
    assert farm.printer(2).control.state()["position"]["X"] == 40
    with pytest.raises(IndexError):
        farm.printer(4)
    farm.stop()
    assert farm.printer(2).journal[-40:] == job  # kept after the stop
    assert not any((tmp_path / f"printer-{n}").exists() for n in (1, 2, 3))  # links removed


@pytest.mark.e2e
async def test_a_farm_file_serves_each_printer_its_own_protocol(tmp_path):
    path = write(tmp_path, """
[[printer]]
protocol = "marlin"
journal = "marlin.log"
[[printer]]
count = 2
protocol = "ultimaker"
journal = "um-{n}.log"
""")
    farm = Farm(["--farm", str(path), "--speed", "100"], 3)
    try:
        for path, protocol in zip(farm.paths, ("marlin", "ultimaker", "ultimaker")):
            async with open_printer(path, protocol=protocol) as host:
                await host.print_commands(["G28", "M105"])
    finally:
        farm.stop()
    assert (tmp_path / "marlin.log").read_text().split("\n")[-3:-1] == ["G28", "M105"]
    assert (tmp_path / "um-3.log").read_text() == "G28\nM105\n"


@pytest.mark.e2e
@pytest.mark.parametrize("args, message", [
    (["--printers", "3", "--journal", "run.log"], "--journal: with --printers, put {n} in it"),
    (["--printers", "0"], "--printers: must be a whole number from 1"),
    (["--farm", "f.toml", "--printers", "2"], "--farm: --printers goes in the farm file"),
    (["--farm", "nowhere.toml"], "--farm: nowhere.toml: cannot read"),
])
def test_bad_farm_flags_are_refused_with_the_reason(tmp_path, args, message):
    result = subprocess.run([FAKE_MARLIN, *args], capture_output=True, text=True, timeout=30,
                            cwd=tmp_path)
    assert result.returncode == 2 and message in result.stderr, result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.e2e
def test_the_control_channel_of_one_printer_needs_no_number(tmp_path):
    farm = Farm(["--control", str(tmp_path / "control")], 1)
    try:
        with socket.socket(socket.AF_UNIX) as sock:
            sock.settimeout(10)
            sock.connect(str(tmp_path / "control"))
            sock.sendall(b'{"op": "state"}\n{"op": "state", "printer": 1}\n')
            reader = sock.makefile()
            replies = [json.loads(reader.readline()) for _ in range(2)]
        assert [reply["ok"] for reply in replies] == [True, True]
    finally:
        farm.stop()
