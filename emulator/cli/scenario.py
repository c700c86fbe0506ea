"""`fake-marlin scenario run PATH...`: run scenarios with our host client and check them."""

import argparse
import json
import sys
from pathlib import Path

from fake_marlin.emulator.scenario.definition import ScenarioError, load
from fake_marlin.emulator.scenario.run import report, run_scenario


def scenario_files(paths: list[str]) -> list[Path]:
    files = []
    for name in paths:
        path = Path(name)
        if path.is_dir():
            found = sorted(path.glob("*.toml"))
            if not found:
                raise ScenarioError(f"{path}: no *.toml scenario files in this directory")
            files += found
        else:
            files.append(path)
    return files


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="fake-marlin scenario",
        description="Run scenarios: the printer with its faults, and a host printing the job.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    run = commands.add_parser("run", help="run scenario files (or every *.toml in a directory)")
    run.add_argument("paths", nargs="+", metavar="PATH")
    run.add_argument(
        "--host", choices=["builtin"], default="builtin",
        help="the host that prints the job: fake-marlin's own client (builtin)",
    )
    run.add_argument("--json", action="store_true", help="one JSON object per scenario instead")
    args = parser.parse_args(argv)
    try:
        scenarios = [load(path) for path in scenario_files(args.paths)]
    except ScenarioError as error:
        print(f"fake-marlin scenario: {error}", file=sys.stderr)
        return 2
    passed = failed = 0
    for scenario in scenarios:
        result = run_scenario(scenario)
        passed += result.passed
        failed += not result.passed
        if args.json:
            print(json.dumps({
                "scenario": str(scenario.path), "name": scenario.name, "passed": result.passed,
                "outcome": result.outcome, "error": result.error,
                "commands": len(scenario.job), "executed": len(result.journal),
                "simulated_seconds": round(result.simulated_seconds, 3),
                "resends": result.summary.resends if result.summary else None,
                "digest": result.digest,
                "checks": [{"name": c.name, "passed": c.passed, "detail": c.detail} for c in result.checks],
            }))
        else:
            print(report(result), flush=True)
    if not args.json:
        print(f"scenarios: {passed} passed, {failed} failed")
    return 0 if failed == 0 else 1
