"""Every shipped scenario is a test: the printer with its faults, our host, the expectations."""

import subprocess
import sys
from pathlib import Path

import pytest

from fake_marlin.emulator.scenario.definition import ScenarioError, load
from fake_marlin.emulator.scenario.run import report, run_scenario

SHIPPED = Path(__file__).parent.parent / "scenarios"
# Campaign failures, once fixed, stay as scenarios of their own (scenarios/regressions/).
SCENARIOS = sorted(SHIPPED.glob("*.toml")) + sorted(SHIPPED.glob("regressions/*.toml"))
# Long simulated runs, e2e for their time alone: about a second each here, where most take a
# tenth or two (latency on every byte of a 300-move print; the campaign's two heaviest cases,
# 15 minutes simulated through a dozen faults, where commstack-2027-272 stays as their kind).
SLOW = {"um-usb-latency-30ms", "marlin-usb-latency-30ms", "regressions/commstack-2027-479",
        "regressions/commstack-2030-880"}


def name(path: Path) -> str:
    return str(path.relative_to(SHIPPED).with_suffix(""))


def test_at_least_twelve_scenarios_ship():
    assert len(SCENARIOS) >= 12
    assert SLOW <= {name(path) for path in SCENARIOS}


@pytest.mark.parametrize("path", [
    pytest.param(path, id=name(path), marks=[pytest.mark.e2e] if name(path) in SLOW else [])
    for path in SCENARIOS
])
def test_shipped_scenario(path, scenario_runs):
    scenario = load(path)
    assert scenario.expect != type(scenario.expect)(), "a scenario must expect something"
    result = scenario_runs.plain(path)  # test_trace compares its traced runs with these
    assert result.passed, report(result)


@pytest.mark.parametrize(
    "text, message",
    [
        ('[[fault]]\nkind = "melt"', "[[fault]] #1: kind: must be one of"),
        ('[printer]\nprotocol = "x"', "[printer] protocol: must be one of"),
        ('[printer]\nprotocol = "marlin"\n[expect]\nresends = [3, 1]', "[expect] resends: must be [least, most]"),
        ('[printer]\nprotocol = "marlin"\nlatency_ms = -1', "[printer] latency_ms: must be at least 0"),
        ('[printer]\nprotocol = "marlin"\n[[fault]]\nkind = "drop"\nevery = 3',
         "[[fault]] #1: direction: is missing"),
        ('[printer]\nprotocol = "marlin"\ncolour = 1', "[printer] colour: is not a key this table knows"),
        ('[job]\nfile = "missing.gcode"\n[host]\nprotocol = "marlin"', "[job] file: cannot read"),
        ("name = [", "not valid TOML"),
        ('[printer]\nextruders = "two"', "[printer] extruders: must be a whole number"),
        ('[printer]\nprotocol = "marlin"\n[[fault]]\nkind = "drop"\ndirection = "to-host"\nat = 3',
         "[[fault]] #1: at: a drop fault acts on a unit"),
    ],
)
def test_bad_scenario_files_name_the_key_and_the_problem(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as refused:
        load(path)
    assert str(refused.value).startswith(f"{path}: ") and message in str(refused.value)


@pytest.mark.e2e
def test_the_cli_runs_a_scenario_and_refuses_a_bad_one(tmp_path):
    fake_marlin = Path(sys.executable).parent / "fake-marlin"
    good = subprocess.run([fake_marlin, "scenario", "run", SCENARIOS[0]], capture_output=True, text=True, timeout=120)
    assert good.returncode == 0, good.stdout + good.stderr
    assert good.stdout.startswith("PASS") and good.stdout.rstrip().endswith("scenarios: 1 passed, 0 failed")
    (tmp_path / "bad.toml").write_text('[printer]\nprotocol = "nope"')
    bad = subprocess.run([fake_marlin, "scenario", "run", tmp_path], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "[printer] protocol: must be one of" in bad.stderr
    assert "Traceback" not in bad.stderr


def test_a_failing_expectation_fails_the_run(tmp_path):
    path = tmp_path / "wrong.toml"
    path.write_text('[printer]\nprotocol = "ultimaker"\n[job]\nmoves = 20\n[expect]\nresends = [5, 9]\n')
    result = run_scenario(load(path))
    assert not result.passed
    assert "[FAIL] host resends within 5..9: 0" in report(result)
