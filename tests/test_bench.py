"""`fake-marlin bench`: its report, its bare ok-responder, its command line.

No test here asserts a speed: the machine's speed drifts several-fold within a day, which is why
the bench reports ratios against references measured in the same run. What is tested is what a
user relies on: the numbers come from complete runs, the reference peer really answers like a
printer, and the program never leaves a traceback, a process or a temporary file behind.
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import serial

from fake_marlin.emulator.bench.responder import M105_OK, Responder
from fake_marlin.host.codecs.marlin import PROBE, encode_line, encode_sync

pytestmark = pytest.mark.e2e
BIN = Path(sys.executable).parent
ROW_KEYS = {"figure", "measured", "reference", "ratio", "goal", "met"}


def bench(*args: str, tmp_path: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    # TMPDIR under the test's own folder, so that anything the bench leaves is seen.
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    return subprocess.run([BIN / "fake-marlin", "bench", *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


def test_quick_hosts_bench_reports_complete_runs_and_cleans_up(tmp_path):
    done = bench("--quick", "--only", "hosts", "--json", tmp_path=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    report = json.loads(done.stdout)
    assert {"version", "quick", "moves", "rounds", "cpus", "load_average", "goals",
            "sections"} <= report.keys()
    assert report["quick"] is True and list(report["sections"]) == ["hosts"]
    section = report["sections"]["hosts"]
    assert {"title", "rows", "notes", "seconds"} <= section.keys()
    rows = {row["host"]: row for row in section["rows"]
            if row.get("printer", "fake-marlin") == "fake-marlin"}
    assert {"ours-marlin", "octoprint", "printcore", "ours-ultimaker"} == rows.keys()
    # Beside each host, fake-marlin without its direct waits (link/direct_wait.py), side by side.
    trio_waits = {row["host"]: row for row in section["rows"]
                  if row.get("printer") == "fake-marlin, trio's own waits"}
    assert {row["host"] for row in rows.values() if row["installed"]} - {"ours-ultimaker"} == (
        trio_waits.keys())
    for row in trio_waits.values():
        assert row["fake_marlin"]["complete"] and row["met"] is None
        assert row["fake_marlin"]["acknowledged"] == report["moves"]
    # Beside each host with a goal, the same host against the bare responder on trio: the floor.
    floors = {row["host"]: row for row in section["rows"] if "bare_on_trio" in row}
    assert "ours-marlin" in floors
    for row in floors.values():
        assert row["bare_on_trio"]["complete"] and row["bare"]["complete"]
        assert row["bare_on_trio"]["acknowledged"] == report["moves"]
    for row in section["rows"]:
        assert ROW_KEYS <= row.keys()
    # Our hosts are always there; the others only where their venvs were built.
    measured = [row for row in rows.values() if row["installed"]]
    assert {"ours-marlin", "ours-ultimaker"} <= {row["host"] for row in measured}
    for row in measured:
        for side in ("fake_marlin", "bare"):
            if row[side] is None:  # Ultimaker has no bare peer
                continue
            figures = row[side]
            assert figures["complete"], (row["host"], side, figures)
            assert figures["acknowledged"] == figures["job"] == report["moves"]
            assert all(run["acknowledged"] == run["job"] for run in figures["runs"])
            assert figures["cmd_per_s"] > 0
    for row in rows.values():
        if not row["installed"]:
            assert row["measured"].startswith("not installed") and row["met"] is None
    # Every process stopped, every file removed (the printers' SD card folders included).
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(("fake-marlin", "octoprint"))]


def test_the_markdown_table_names_each_goal(tmp_path):
    done = bench("--quick", "--only", "simhour", tmp_path=tmp_path)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert any(line.startswith("### One simulated hour") for line in lines)
    assert "| printer | wall s per simulated hour | ideal | ratio | goal | met |" in lines
    assert lines[-1].startswith("Goals: ")


@pytest.mark.parametrize("args, complaint", [
    (["--only", "nosuch"], "unknown section 'nosuch'"),
    (["--only", ","], "unknown section"),
    (["--moves", "0"], "--moves"),
    (["--moves", "many"], "--moves"),
    (["--rounds", "-1"], "--rounds"),
    (["--frobnicate"], "unrecognized arguments"),
])
def test_a_bad_option_exits_2_in_one_line(tmp_path, args, complaint):
    done = bench(*args, tmp_path=tmp_path, timeout=60)
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    assert complaint in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    assert done.stdout == ""


@pytest.mark.parametrize("variant", [[], ["--trio"]], ids=["select", "trio"])
def test_the_bare_responder_answers_ok_over_a_real_pty(variant):
    responder = subprocess.Popen(
        [sys.executable, "-m", "fake_marlin.emulator.bench.responder", *variant],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        path = responder.stdout.readline().strip()
        assert path.startswith("/dev/pts/")
        # pyserial flushes the port as it opens it, as hosts do: the responder's "reset".
        with serial.Serial(path, 250000, timeout=10) as port:
            assert port.readline() == b"start\n"
            port.write(b"G28\n")
            assert port.readline() == b"ok\n"
            port.write(encode_line(1, "G1 X10 F6000"))
            assert port.readline() == b"ok\n"
            port.write(b"M105\n")
            assert port.readline() == M105_OK
            # Our Marlin host's probe is refused, stating the counter: the last line was 1.
            port.write(PROBE)
            assert [port.readline() for _ in range(3)] == [
                b"Error:checksum mismatch, Last Line: 1\n", b"Resend: 2\n", b"ok\n"]
    finally:
        responder.send_signal(signal.SIGTERM)
        _, stderr = responder.communicate(timeout=10)
    assert responder.returncode == 0 and stderr == ""


def test_the_responder_logic_follows_marlins_line_counter():
    responder = Responder()
    assert responder.reset() == b"start\n"
    assert responder.receive(b"\n\r\n") == b""  # blank lines: no answer, as in Marlin
    assert responder.receive(encode_sync("M110 N0")) == b"ok\n"
    assert responder.receive(encode_line(1, "G28")[:-3]) == b""  # half a line: not yet
    assert responder.receive(encode_line(1, "G28")[-3:]) == b"ok\n"
    assert responder.receive(b"N2 G1 X1\n").startswith(b"Error:No Checksum")
    assert responder.receive(b"N7 M110 N41*0\n").startswith(b"Error:checksum mismatch")
    assert responder.receive(encode_line(7, "M110 N41")) == b"ok\n"
    assert responder.last_line == 41
    assert responder.receive(b"M115\n").startswith(b"FIRMWARE_NAME:")
    assert responder.reset() == b"start\n" and responder.last_line == 0


def test_an_interrupted_bench_stops_its_printers(tmp_path):
    bench_process = subprocess.Popen(
        [BIN / "fake-marlin", "bench", "--only", "simhour"], stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True, env={**os.environ, "TMPDIR": str(tmp_path)},
    )
    children: set[int] = set()
    deadline = time.monotonic() + 60
    while not children and time.monotonic() < deadline:
        children = _children(bench_process.pid)
        time.sleep(0.05)
    assert children, "the bench started no printer"
    bench_process.send_signal(signal.SIGTERM)
    _, stderr = bench_process.communicate(timeout=60)
    assert bench_process.returncode == 130
    assert "Traceback" not in stderr and "interrupted" in stderr
    for pid in children:
        assert not Path(f"/proc/{pid}").exists() or _zombie(pid), f"process {pid} outlived it"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith("fake-marlin")]


def _children(pid: int) -> set[int]:
    """The processes whose parent is `pid` (from each /proc/N/stat: portable across kernels)."""
    found = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.add(int(entry.name))
    return found


def _zombie(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except OSError:
        return True
