"""The wire trace (docs/trace.md): what a traced run writes, and that tracing changes nothing."""

import gzip
import json
import subprocess
import sys
from pathlib import Path

import pytest

from fake_marlin.emulator.scenario.definition import load
from fake_marlin.emulator.scenario.run import run_scenario

SCENARIOS = Path(__file__).resolve().parent.parent / "scenarios"
KINDS = {"begin", "in", "out", "cmd", "room", "temp", "fault", "reject", "reset", "connect",
         "disconnect", "verdict", "end"}


def records(path: Path) -> list[dict]:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt", encoding="utf-8") as lines:
        return [json.loads(line) for line in lines]


@pytest.mark.parametrize("name", [
    "um3-noisy-serial", "marlin-noisy-serial", "repetier-noisy-serial", "commstack-noisy-link",
    "marlin-thermal-runaway-during-print", "um-cable-unplugged",
])
def test_a_traced_scenario_is_the_same_run(name, scenario_runs):
    """A trace written to reproduce a field bug must show the run that fails, not another."""
    plain = scenario_runs.plain(SCENARIOS / f"{name}.toml")  # test_scenarios' run, if it ran
    traced, _ = scenario_runs.traced(SCENARIOS / f"{name}.toml")
    assert traced.digest == plain.digest
    assert traced.journal == plain.journal


def test_the_trace_of_a_noisy_ultimaker_run(scenario_runs):
    result, path = scenario_runs.traced(SCENARIOS / "um3-noisy-serial.toml")
    trace = records(path)
    assert {record["k"] for record in trace} <= KINDS
    assert trace[0]["k"] == "begin" and trace[0]["version"] == 1
    assert trace[0]["protocol"] == "ultimaker" and trace[0]["scenario"] == "UM3 noisy serial line"
    assert trace[-1]["k"] == "end" and trace[-2]["k"] == "verdict"
    times = [record["t"] for record in trace]
    assert times == sorted(times)  # t never goes back
    # Every executed command, in order: the journal.
    assert [r["c"] for r in trace if r["k"] == "cmd"] == result.journal
    assert trace[-1]["commands"] == len(result.journal)
    # The noise: bit errors fired toward the printer, and the printer refused packets for them.
    faults = [r for r in trace if r["k"] == "fault"]
    assert faults and {r["f"] for r in faults} == {"bit-errors"}
    assert sum(r["n"] for r in faults if r["dir"] == "to-printer") > 0
    rejects = [r for r in trace if r["k"] == "reject"]
    assert rejects and all(isinstance(r["why"], str) and r["why"] for r in rejects)
    # The planner filled (no room) and drained again (all room).
    room = [r["v"] for r in trace if r["k"] == "room"]
    assert 0 in room and room[-1] == trace[0]["planner"] == 15
    verdict = trace[-2]
    assert verdict["passed"] and verdict["exactly_once"]
    assert verdict["job"] == verdict["ran"] == len(result.journal)
    assert verdict["host"]["resends"] == result.summary.resends > 0
    # What the printer said crossed the wire as `out` records: its ProtoError answers.
    said = "".join(r["b"] for r in trace if r["k"] == "out")
    assert "ProtoError" in said


def test_heaters_are_sampled_while_in_use(scenario_runs):
    _, path = scenario_runs.traced(SCENARIOS / "marlin-thermal-runaway-during-print.toml")
    trace = records(path)
    samples = [r for r in trace if r["k"] == "temp" and r["h"] == "T0"]
    targets = {r["s"] for r in samples}
    assert len(samples) > 10 and max(targets) > 0
    heated = [r for r in samples if r["s"] > 0]
    assert heated[-1]["c"] > heated[0]["c"]  # it heated up
    assert any(r["k"] == "fault" and r["dir"] is None for r in trace)  # the runaway itself


def run_cli(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fake_marlin.emulator.cli", *args],
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.e2e
def test_scenario_run_writes_a_trace_per_scenario_by_name(tmp_path):
    pattern = str(tmp_path / "{name}.jsonl")
    done = run_cli("scenario", "run", str(SCENARIOS / "marlin-lost-oks.toml"),
                   str(SCENARIOS / "um-lost-packets.toml"), "--trace", pattern)
    assert done.returncode == 0, done.stderr
    written = sorted(path.name for path in tmp_path.iterdir())
    assert len(written) == 2
    for path in tmp_path.iterdir():
        assert records(path)[-1]["k"] == "end"


@pytest.mark.e2e
@pytest.mark.parametrize("args, complaint", [
    (["scenario", "run", str(SCENARIOS / "marlin-lost-oks.toml"),
      str(SCENARIOS / "um-lost-packets.toml"), "--trace", "/tmp/one.jsonl"], "{name}"),
    (["scenario", "run", str(SCENARIOS / "marlin-lost-oks.toml"), "--trace",
      "/nonexistent/dir/t.jsonl"], "cannot write the trace /nonexistent/dir/t.jsonl"),
    (["--printers", "2", "--trace", "/tmp/t.jsonl"], "{n}"),
    (["--trace", "/nonexistent/dir/t.jsonl"], "cannot write the trace"),
])
def test_a_trace_that_cannot_be_written_is_refused_in_one_line(args, complaint):
    done = run_cli(*args)
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    assert complaint in done.stderr.strip().splitlines()[-1]  # after argparse's usage, if any


def test_a_trace_that_fails_to_write_stops_and_the_printer_runs_on(capsys, scenario_runs):
    """A full disk must cost the trace, not the run."""
    plain = scenario_runs.plain(SCENARIOS / "marlin-lost-oks.toml")
    broken = run_scenario(load(SCENARIOS / "marlin-lost-oks.toml"), "/dev/full")
    assert broken.digest == plain.digest and broken.passed
    said = capsys.readouterr().err.strip().splitlines()
    assert said == ["fake-marlin: cannot write the trace /dev/full: No space left on device; "
                    "tracing stopped, the printer runs on"]
