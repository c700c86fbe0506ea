"""A farm over several processes (`--processes K`), its first number (`--first-number N`), and
the machine's limits a big farm meets, said before any printer starts."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fake_marlin.emulator.bench.procs import children_of
from fake_marlin.emulator.cli import limits
from fake_marlin.emulator.cli.farm import read_farm
from fake_marlin.emulator.cli.main import main
from fake_marlin.emulator.cli.processes import split
from fake_marlin.emulator.control.client import ControlClient, ControlRequestError
from fake_marlin.host import open_printer

FAKE_MARLIN = Path(sys.executable).parent / "fake-marlin"


def gone(pids: list[int], within: float) -> bool:
    deadline = time.monotonic() + within
    while time.monotonic() < deadline:
        if all(_state(pid) == "Z" for pid in pids):
            return True
        time.sleep(0.05)
    return False


def _state(pid: int) -> str:
    """A process's state letter; a process that is gone reads as a zombie ("Z")."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "Z"


def test_printers_are_split_into_contiguous_parts_as_even_as_can_be():
    assert split(10, 3) == [(0, 4), (4, 7), (7, 10)]
    assert split(10_000, 4) == [(0, 2500), (2500, 5000), (5000, 7500), (7500, 10_000)]
    assert split(2, 2) == [(0, 1), (1, 2)]


@pytest.mark.e2e
async def test_a_farm_over_processes_is_one_farm_to_its_hosts_and_its_control_channel(
        fake_printer_factory):
    farm = fake_printer_factory(printers=10, processes=3, protocol="marlin", speed=100)
    workers = children_of(farm.process.pid)
    assert len(workers) == 3
    assert len(set(farm.ports)) == 10
    listed = farm.control.printers()
    assert [entry["printer"] for entry in listed] == list(range(1, 11))
    assert [entry["path"] for entry in listed] == farm.ports  # in order, as one process says them
    assert len({entry["uuid"] for entry in listed}) == 10
    assert len({entry["serial"] for entry in listed}) == 10
    # A printer of the first process and one of the last: each hears its own host, and its
    # own UUID, and only the printer streamed to ran the job, once.
    job = [f"G1 X{n} F6000" for n in range(1, 31)]
    uuids = []
    for number in (2, 9):
        async with open_printer(farm.printer(number).port, protocol="marlin") as host:
            reply = await host.send("M115")
            uuids += [line for line in reply if "UUID:" in line]
            await host.print_commands(job)
        assert farm.printer(number).journal[-30:] == job
        assert farm.printer(number).journal.count("M115") == 1
        assert farm.printer(number).control.state()["position"]["X"] == 30
    assert len(uuids) == 2 and uuids[0] != uuids[1]
    assert farm.printer(5).journal == []
    with pytest.raises(ControlRequestError, match="10 printers are served here: say which"):
        farm.control.state()
    with pytest.raises(ControlRequestError, match='"printer" must be a number from 1 to 10'):
        farm.control.request("state", printer=11)
    with pytest.raises(ControlRequestError, match="unknown op 'melt'"):
        farm.control.request("melt", printer=1)
    farm.stop()
    assert farm.returncode == 0
    assert gone(workers, 1.0), "a process of the farm outlived it"


@pytest.mark.e2e
def test_a_farm_is_numbered_as_one_process_would_number_it(tmp_path):
    """Printers 21 to 23 of a farm have the same identities whether one process serves all 23
    or a process (a container) is told to start at 21: no two printers of a farm share one."""
    def identities(*args: str) -> dict[int, tuple[str, str, str]]:
        control = str(tmp_path / f"control-{len(args)}.sock")
        with subprocess.Popen([str(FAKE_MARLIN), *args, "--control", control],
                              stdout=subprocess.PIPE, text=True) as process:
            try:
                count = int(args[args.index("--printers") + 1])
                for _ in range(count):
                    assert process.stdout is not None and process.stdout.readline()
                with ControlClient(control) as client:
                    return {entry["printer"]: (entry["uuid"], entry["serial"], entry["machine_name"])
                            for entry in client.printers()}
            finally:
                process.send_signal(signal.SIGTERM)

    whole = identities("--printers", "23", "--tcp", "0", "--protocol", "marlin")
    part = identities("--printers", "3", "--first-number", "21", "--processes", "3",
                      "--tcp", "0", "--protocol", "marlin")
    assert sorted(part) == [21, 22, 23]
    assert all(part[number] == whole[number] for number in part)
    assert len({value for value in whole.values()}) == 23


@pytest.mark.e2e
def test_a_farm_stops_when_one_of_its_processes_dies_saying_which(tmp_path):
    process = subprocess.Popen([str(FAKE_MARLIN), "--printers", "4", "--processes", "2"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert process.stdout is not None and process.stderr is not None
    for _ in range(4):
        assert process.stdout.readline().startswith("/dev/")
    workers = children_of(process.pid)
    os.kill(workers[1], signal.SIGKILL)
    assert process.wait(timeout=15) == 1
    assert "the process serving printers 3 to 4 stopped (exit code -9); stopping the others" \
        in process.stderr.read()
    assert gone(workers, 1.0)


@pytest.mark.e2e
def test_a_farm_that_vanishes_takes_its_processes_with_it():
    """A first process killed outright (no signal it can catch) leaves no printer running."""
    process = subprocess.Popen([str(FAKE_MARLIN), "--printers", "4", "--processes", "2"],
                               stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None
    for _ in range(4):
        process.stdout.readline()
    workers = children_of(process.pid)
    process.kill()
    process.wait()
    assert gone(workers, 10.0)


@pytest.mark.e2e
def test_a_process_that_cannot_start_stops_the_farm_with_its_reason():
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = subprocess.run(
            [str(FAKE_MARLIN), "--printers", "4", "--processes", "2", "--tcp", str(port - 3)],
            capture_output=True, text=True, timeout=30)
    assert result.returncode == 2
    assert result.stdout == ""  # no paths: not every printer is up
    assert f"cannot listen on 127.0.0.1:{port}: Address already in use" in result.stderr


def test_a_farm_file_says_over_how_many_processes(tmp_path):
    path = tmp_path / "farm.toml"
    path.write_text("processes = 2\nfirst_number = 101\n[[printer]]\ncount = 4\n")
    farm = read_farm(path)
    assert farm.processes == 2
    assert [plan.number for plan in farm.plans] == [101, 102, 103, 104]
    assert [plan.number for plan in read_farm(path, first_number=5).plans] == [5, 6, 7, 8]
    path.write_text("processes = 5\n[[printer]]\ncount = 4\n")
    with pytest.raises(Exception, match="processes = 5, but the farm has 4 printer"):
        read_farm(path)


@pytest.mark.parametrize("args, message", [
    (["--printers", "3", "--processes", "4"], "4 processes for 3 printer(s)"),
    (["--processes", "0"], "must be a whole number from 1 to 64"),
    (["--first-number", "x"], "must be a whole number from 1 to 1,000,000"),
])
def test_bad_process_flags_are_refused_with_the_reason(args, message, capsys):
    with pytest.raises(SystemExit) as stopped:
        main(args)
    assert stopped.value.code == 2
    assert message in capsys.readouterr().err


def test_more_ptys_than_the_kernel_has_is_refused_before_any_printer_starts(monkeypatch, capsys):
    monkeypatch.setattr(limits, "pty_room", lambda: (4096, 100))
    assert main(["--printers", "4000", "--processes", "2"]) == 2
    err = capsys.readouterr().err
    assert "4,000 printers on ptys need 4,000 ptys, but the kernel has room for 3,996 more" in err
    assert "sysctl kernel.pty.max = 4,096" in err and "--tcp PORT" in err


def test_more_open_files_than_allowed_is_refused_naming_the_limit(monkeypatch, capsys):
    import resource

    monkeypatch.setattr(resource, "getrlimit", lambda which: (1024, 2048))
    assert main(["--printers", "1000", "--tcp", "0"]) == 2
    err = capsys.readouterr().err
    assert "need about 2,064 open files, but a process here may open at most 2,048" in err
    assert "--processes K" in err


@pytest.mark.e2e
@pytest.mark.parametrize("extra", [[], ["--printers", "4", "--processes", "2"]])
def test_a_live_view_port_in_use_is_said_and_nothing_is_left_running(extra):
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = subprocess.run([str(FAKE_MARLIN), "--web", f"127.0.0.1:{port}", *extra],
                                capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert result.stderr == (f"fake-marlin: cannot serve the live view on 127.0.0.1:{port}: "
                             "Address already in use\n")


@pytest.mark.e2e
def test_the_live_view_of_a_farm_over_processes_shows_every_printer(fake_printer_factory):
    import json
    import re
    import urllib.request

    farm = fake_printer_factory(printers=4, processes=2, protocol="marlin",
                                extra_args=["--web", "127.0.0.1:0"])
    url = re.search(r"live view at (http://\S+)", farm.stderr)
    assert url, farm.stderr
    with urllib.request.urlopen(url[1] + "api/farm", timeout=10) as response:
        rows = json.load(response)["rows"]
    assert [row["number"] for row in rows] == [1, 2, 3, 4]
    assert [row["path"] for row in rows] == farm.ports
    with urllib.request.urlopen(url[1] + "api/printer/3", timeout=10) as response:
        detail = json.load(response)  # from the second process, over its control channel
    assert detail["row"]["number"] == 3 and detail["watching"] is not None
