"""`fake-marlin scenario fuzz`: generated fault mixes are valid and repeatable, a failing case
written out fails again the same way on its own, and the command runs end to end."""

import json
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from fake_marlin.emulator.cli.main import main as cli_main
from fake_marlin.emulator.scenario import campaign, fuzz
from fake_marlin.emulator.scenario.definition import load

FAKE_MARLIN = Path(sys.executable).parent / "fake-marlin"
UNIT_KINDS = {"drop", "duplicate", "truncate"}


def write(directory: Path, table: dict) -> Path:
    path = directory / f"{table['name']}.toml"
    path.write_text(fuzz.scenario_text(table), encoding="utf-8")
    return path


def test_the_same_seed_gives_the_same_files_and_another_seed_others(tmp_path):
    for protocol in fuzz.PROTOCOLS:
        first = [fuzz.scenario_text(case.table) for case in campaign.cases(protocol, 11, 6)]
        again = [fuzz.scenario_text(case.table) for case in campaign.cases(protocol, 11, 6)]
        other = [fuzz.scenario_text(case.table) for case in campaign.cases(protocol, 12, 6)]
        assert first == again
        assert not set(first) & set(other)
        # Case n is case n, however many the campaign runs.
        assert [fuzz.scenario_text(c.table) for c in campaign.cases(protocol, 11, 3)] == first[:3]
    case = campaign.cases("marlin", 11, 1)[0]
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a = campaign.write_case(tmp_path / "a", case, "FAIL: why")
    b = campaign.write_case(tmp_path / "b", case, "FAIL: why")
    assert a.name == "marlin-11-1.toml" and a.read_bytes() == b.read_bytes()


def test_every_generated_scenario_loads_and_keeps_the_rules(tmp_path):
    kinds: dict[str, set[str]] = {protocol: set() for protocol in fuzz.PROTOCOLS}
    clean = 0
    for protocol in fuzz.PROTOCOLS:
        for number in range(1, 81):
            table = fuzz.generate(protocol, 5, number)
            scenario = load(write(tmp_path, table))  # refuses anything invalid
            assert scenario.printer.protocol == scenario.host_protocol == protocol
            assert 200 <= table["job"]["moves"] <= 400
            faults = table.get("fault", [])
            clean += (not faults and set(table["printer"]) == {"protocol"}
                      and set(table["host"]) <= {"protocol", "window"})
            kind = fuzz.case_kind(table)
            kinds[protocol].add(kind)
            for fault in faults:
                kinds[protocol].add(fault["kind"])
                if fault["kind"] in ("bit-errors", "drop-bytes"):
                    assert 0 < fault["rate"] <= 1e-3
                if fault["kind"] in UNIT_KINDS:
                    assert "at" not in fault and 0 < fault["probability"] <= 0.05
            reboots = [f for f in faults if f["kind"] == "reboot"]
            disconnects = [f for f in faults if f["kind"] == "disconnect"]
            if kind == "reset":
                assert len(reboots) == 1 and reboots[0]["nth"] < len(scenario.job)
                assert not disconnects and "disconnect_after" not in table["host"]
                assert table["expect"] == {"outcome": "failed", "error": "PrinterReset"}
            else:
                assert not reboots
                assert table["expect"]["outcome"] == "completed"
            if kind == "reconnect":
                assert disconnects or "disconnect_after" in table["host"]
                assert table["expect"]["missing"] == 0 and "exactly_once" not in table["expect"]
            if kind == "exactly-once":
                assert table["expect"]["exactly_once"] and table["expect"]["allow_undetectable"]
            if protocol == "commstack":
                assert not disconnects
                assert not {"disconnect_after", "reconnect_after"} & set(table["host"])
    assert clean >= 5, "some cases are clean"
    for protocol, seen in kinds.items():
        expected = {"exactly-once", "reset", "bit-errors", "drop-bytes", "drop", "duplicate",
                    "truncate", "garbage", "stall", "reboot"}
        if protocol in fuzz.STREAMING:
            expected |= {"reconnect", "disconnect"}
        assert expected <= seen, (protocol, expected - seen)
    # A fixed number of moves, for short campaigns.
    assert all(fuzz.generate(p, 1, n, moves=15)["job"]["moves"] == 15
               for p in fuzz.PROTOCOLS for n in range(1, 30))


@pytest.mark.e2e
def test_a_failing_case_written_out_fails_again_alone_with_the_same_digest(tmp_path):
    # A harsh Ultimaker case, made to fail by an expectation no run meets.
    case = next(c for c in campaign.cases("ultimaker", 3, 40, moves=40)
                if fuzz.case_kind(c.table) == "exactly-once" and len(c.table.get("fault", [])) >= 3)
    table = {**case.table, "expect": {**case.table["expect"], "resends": [100000, 100000]}}
    case = campaign.Case(case.protocol, case.seed, case.number, table)
    result = campaign.run_case(case.name, case.text)  # in this process, after other runs
    assert not result.passed and result.reason.startswith("host resends within 100000..100000: ")
    path = campaign.write_case(tmp_path, case, "FAIL: " + result.reason)
    assert path.read_text().splitlines()[0] == f"# FAIL: {result.reason}"
    rerun = subprocess.run([FAKE_MARLIN, "scenario", "run", "--json", path],
                           capture_output=True, text=True, timeout=120)
    assert rerun.returncode == 1, rerun.stderr
    row = json.loads(rerun.stdout)
    assert not row["passed"] and row["digest"] == result.digest
    failed = next(c for c in row["checks"] if not c["passed"])
    assert f"{failed['name']}: {failed['detail']}" == result.reason


def test_g2core_cases_are_for_a_g2core_board_and_duplicate_only_its_answers(tmp_path):
    """g2core never checks a line's number, so a line the wire duplicates runs twice on any
    board, as one a host sends again does (fuzz.UNSEQUENCED): only answers are duplicated. One
    line at a time is all a g2core host keeps in flight, so a disconnect may run one twice."""
    assert "g2core" in fuzz.PROTOCOLS and "g2core" in fuzz.STREAMING
    assert fuzz.in_flight("g2core", 300) == 1
    kinds, garbage = set(), 0
    for number in range(1, 81):
        table = fuzz.generate("g2core", 5, number)
        assert table["name"] == f"g2core-5-{number}"
        assert table["printer"]["firmware"] == "g2core"
        assert load(write(tmp_path, table)).printer.firmware == "g2core"
        faults = table.get("fault", [])
        for fault in faults:
            if fault["kind"] == "duplicate":
                assert fault["direction"] == "to-host"
            if fault.get("pattern"):
                assert fault["pattern"] == fuzz.ACK_PATTERNS["g2core"] == '^\\{"r"'
            if fault["kind"] == "garbage" and fault["direction"] == "to-printer":
                # No N word: g2core would take its number for the line's (NUMBERED_BY_ANY_LINE).
                assert "length" not in fault and not re.search(r"[Nn]\s*\d", fault["text"])
                garbage += 1
        kinds.add(fuzz.case_kind(table))
        if fuzz.case_kind(table) == "reconnect":
            assert table["expect"]["duplicated_at_most"] == 1
    assert kinds == {"exactly-once", "reconnect", "reset"} and garbage


def test_another_firmware_meets_the_same_faults_under_a_name_of_its_own(tmp_path):
    marlin = fuzz.generate("marlin", 9, 4)
    prusa = fuzz.generate("marlin", 9, 4, firmware="prusa")
    assert prusa["printer"] == {**marlin["printer"], "firmware": "prusa"}
    assert prusa.get("fault") == marlin.get("fault") and prusa["job"] == marlin["job"]
    assert prusa["name"] == "marlin-prusa-9-4" != marlin["name"]
    assert load(write(tmp_path, prusa)).printer.firmware == "prusa"


def test_a_reason_is_one_line_fit_for_a_comment():
    reason = "FAIL: line one\nline two \x00\x1b 'start' " + "y" * 1000
    text = fuzz.scenario_text({"name": "x"}, reason)
    comment = text.split("\n", 1)[0]
    assert comment.startswith("# FAIL: line one line two \\x00\\x1b 'start' y")
    assert len(comment) < 420
    assert tomllib.loads(text) == {"name": "x"}


@pytest.mark.parametrize("args, message", [
    (["--protocol", "klipper"], "invalid choice: 'klipper'"),
    (["--runs", "0"], "--runs must be at least 1"),
    (["--runs", "many"], "invalid int value"),
    (["--seed", "-1"], "--seed must be at least 0"),
    (["--jobs", "0"], "--jobs must be at least 1"),
    (["--moves", "0"], "--moves must be at least 1"),
    (["--out", "FILE"], "cannot make the directory"),
    (["--firmware", "nope"], "no firmware 'nope'"),
    (["--protocol", "ultimaker", "--firmware", "prusa"], "fuzzed with --protocol marlin"),
])
def test_the_cli_refuses_bad_arguments(tmp_path, capsys, args, message):
    (tmp_path / "FILE").write_text("not a directory")
    given = {"--protocol": "marlin", "--runs": "1", "--seed": "1", "--out": str(tmp_path / "out")}
    for flag, value in zip(args[::2], args[1::2]):
        given[flag] = str(tmp_path / value) if value == "FILE" else value
    with pytest.raises(SystemExit) as exited:
        cli_main(["scenario", "fuzz", *[item for pair in given.items() for item in pair]])
    assert exited.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.e2e
def test_the_cli_needs_its_arguments():
    refused = subprocess.run([FAKE_MARLIN, "scenario", "fuzz", "--protocol", "all"],
                             capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2 and "required" in refused.stderr
    assert "Traceback" not in refused.stderr


@pytest.mark.e2e
def test_a_short_campaign_runs_end_to_end(tmp_path):
    out = tmp_path / "out"
    ran = subprocess.run(
        [FAKE_MARLIN, "scenario", "fuzz", "--protocol", "all", "--runs", "3", "--seed", "2",
         "--out", out, "--moves", "30", "--jobs", "2", "--json"],
        capture_output=True, text=True, timeout=300,
    )
    assert ran.returncode in (0, 1), ran.stderr
    assert ran.stderr == ""  # no progress line when stderr is no terminal
    summaries = [json.loads(line) for line in ran.stdout.splitlines()]
    assert [s["protocol"] for s in summaries] == list(fuzz.PROTOCOLS)
    failures = []
    for summary in summaries:
        assert summary["runs"] == 3 and summary["passed"] + summary["failed"] == 3
        assert summary["mean_simulated_seconds"] > 0 and summary["wall_seconds"] > 0
        assert len(summary["failures"]) == summary["failed"]
        failures += summary["failures"]
    assert ran.returncode == (1 if failures else 0)
    written = sorted(p.name for p in out.glob("*.toml"))
    assert written == sorted(Path(f["file"]).name for f in failures)
    for failure in failures:
        path = Path(failure["file"])
        assert path.read_text().startswith("# FAIL: " + failure["reason"][:50])
        load(path)
    # The same campaign, written in full and read by a person.
    again = subprocess.run(
        [FAKE_MARLIN, "scenario", "fuzz", "--protocol", "marlin", "--runs", "3", "--seed", "2",
         "--out", tmp_path / "all", "--moves", "30", "--jobs", "1", "--keep-all"],
        capture_output=True, text=True, timeout=300,
    )
    marlin = summaries[1]
    assert again.returncode == (1 if marlin["failed"] else 0)
    assert again.stdout.splitlines()[-1].startswith(
        f"marlin: 3 runs, {marlin['passed']} passed, {marlin['failed']} failed, ")
    written = sorted((tmp_path / "all").glob("*.toml"))
    assert [p.name for p in written] == ["marlin-2-1.toml", "marlin-2-2.toml", "marlin-2-3.toml"]
    for path in written:
        assert path.read_text().startswith(("# PASS: ", "# FAIL: "))


@pytest.mark.e2e
def test_progress_shows_on_a_terminal(tmp_path):
    controller, terminal = os.openpty()
    try:
        ran = subprocess.run(
            [FAKE_MARLIN, "scenario", "fuzz", "--protocol", "marlin", "--runs", "2", "--seed", "1",
             "--out", tmp_path, "--moves", "10", "--jobs", "1"],
            stdout=subprocess.PIPE, stderr=terminal, text=True, timeout=120,
        )
        os.close(terminal)
        terminal = -1
        shown = b""
        while True:
            try:
                chunk = os.read(controller, 4096)
            except OSError:
                break
            if not chunk:
                break
            shown += chunk
    finally:
        if terminal >= 0:
            os.close(terminal)
        os.close(controller)
    assert ran.returncode in (0, 1)
    assert b"\rfuzz marlin: 1/2 done, " in shown and b"\rfuzz marlin: 2/2 done, " in shown
    assert "marlin: 2 runs" in ran.stdout
