"""`fake-marlin scenario run PATH...`: run scenarios with our host client and check them;
`fake-marlin scenario fuzz`: run random fault mixes (emulator/scenario/fuzz.py, campaign.py)."""

import argparse
import json
import sys
from pathlib import Path

from fake_marlin.emulator.cli.parsing import Commands
from fake_marlin.wire.ultimaker_variants import NAMES, PLAIN, VariantError, Variants, parse_variants

# scenario.fuzz.PROTOCOLS (tests/test_cli.py checks): written out here, as the imports of the
# scenarios and their runner are kept inside the functions that run them, so that building the
# parser, which every `fake-marlin` does, imports neither.
FUZZ_PROTOCOLS = ("ultimaker", "marlin", "repetier", "commstack", "g2core")


def scenario_files(paths: list[str]) -> list[Path]:
    from fake_marlin.emulator.scenario.definition import ScenarioError

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


def configure(commands: Commands) -> None:
    """Add `scenario` and its own commands, `run` and `fuzz`, to fake-marlin's (main.py)."""
    parser = commands.add_parser(
        "scenario", help="run scenario files (run) or random fault mixes (fuzz)",
        description="Run scenarios: the printer with its faults, and a host printing the job.",
    )
    scenario_commands = parser.add_subparsers(dest="scenario_command", required=True,
                                              metavar="COMMAND")
    assert isinstance(scenario_commands, Commands)
    run = scenario_commands.add_parser(
        "run", help="run scenario files (or every *.toml in a directory)")
    run.add_argument("paths", nargs="+", metavar="PATH")
    run.add_argument(
        "--host", choices=["builtin"], default="builtin",
        help="the host that prints the job: fake-marlin's own client (builtin)",
    )
    run.add_argument("--json", action="store_true", help="one JSON object per scenario instead")
    run.add_argument(
        "--trace", metavar="FILE",
        help="write each run's wire trace (JSON lines, docs/trace.md; gzip if FILE ends in .gz); "
        "with several scenarios FILE must contain {name}, the scenario's name",
    )
    run.add_argument(
        "--report", metavar="OUTDIR",
        help="write a report page per scenario (as `fake-marlin report` does) and "
        "OUTDIR/index.html linking them with their verdicts; each run is traced to "
        "OUTDIR/<file name>.trace.jsonl.gz unless --trace says where (needs fake-marlin[report])",
    )
    run.set_defaults(run=run_scenarios)
    fuzz = _add_fuzz_parser(scenario_commands)
    fuzz.set_defaults(run=lambda args: fuzz_main(args, fuzz))


def main(argv: list[str]) -> int:
    """`fake-marlin scenario ARGV...`."""
    from fake_marlin.emulator.cli.main import main

    return main(["scenario", *argv])


def run_scenarios(args: argparse.Namespace) -> int:
    """`fake-marlin scenario run`."""
    from fake_marlin.emulator.scenario.definition import ScenarioError, load
    from fake_marlin.emulator.scenario.run import report, run_scenario
    from fake_marlin.emulator.trace.writer import TraceError

    try:
        scenarios = [load(path) for path in scenario_files(args.paths)]
    except ScenarioError as error:
        print(f"fake-marlin scenario: {error}", file=sys.stderr)
        return 2
    if args.trace is not None and len(scenarios) > 1 and "{name}" not in args.trace:
        print(f"fake-marlin scenario: --trace {args.trace}: {len(scenarios)} scenarios would "
              "write one file; put {name} in it", file=sys.stderr)
        return 2
    if args.report is not None and (problem := _report_problem(Path(args.report))):
        print(f"fake-marlin scenario: --report {args.report}: {problem}", file=sys.stderr)
        return 2
    passed = failed = 0
    traces = []
    for scenario in scenarios:
        trace = args.trace.replace("{name}", scenario.name) if args.trace else None
        if trace is None and args.report is not None:
            trace = str(Path(args.report) / f"{scenario.path.stem}.trace.jsonl.gz")
        if trace is not None:
            traces.append(Path(trace))
        try:
            result = run_scenario(scenario, trace)
        except TraceError as error:
            print(f"fake-marlin scenario: {error}", file=sys.stderr)
            return 2
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
    if args.report is not None:
        from fake_marlin.emulator.report.build import write_reports

        index = write_reports(traces, Path(args.report))
        print(f"reports: {index}", file=sys.stderr if args.json else sys.stdout)
    if not args.json:
        print(f"scenarios: {passed} passed, {failed} failed")
    return 0 if failed == 0 else 1


def _report_problem(outdir: Path) -> str | None:
    """Why reports cannot be written to `outdir` (made here if missing), or None."""
    from fake_marlin.emulator.report.build import MissingPlotting, require_plotting

    try:
        require_plotting()
        outdir.mkdir(parents=True, exist_ok=True)
    except MissingPlotting as error:
        return str(error)
    except OSError as error:
        return f"cannot make the directory: {error.strerror or error}"
    return None



def _add_fuzz_parser(commands: Commands) -> argparse.ArgumentParser:
    fuzz = commands.add_parser(
        "fuzz", help="run random fault mixes with the built-in host; write the failing ones out",
        description="Generate RUNS random fault mixes per protocol (seeded: the same seed gives "
        "the same cases), run each with the built-in host, and write every failing case to "
        "DIR/<protocol>-<seed>-<n>.toml, whose first line says why it failed; "
        "`fake-marlin scenario run` on that file fails the same way. Exit 1 if any case failed. "
        "Files of earlier campaigns in DIR are overwritten by the same names, never removed.",
    )
    fuzz.add_argument("--protocol", required=True, choices=[*FUZZ_PROTOCOLS, "all"],
                      help="the protocol to fuzz, or all of them")
    fuzz.add_argument("--firmware", default="marlin", metavar="NAME",
                      help="with --protocol marlin: the printer's firmware (default marlin); the "
                      "same faults for every firmware of one seed")
    fuzz.add_argument("--variant", action="append", default=[], metavar="NAME[,NAME]|each",
                      help="with --protocol ultimaker: run the cases with these protocol lab "
                      "variants (repeatable: one campaign each; `each`: every variant alone, "
                      "then all together; `v3`: plain); the same faults for every variant")
    fuzz.add_argument("--runs", type=int, required=True, help="cases per protocol")
    fuzz.add_argument("--seed", type=int, required=True, help="the campaign's seed (0 or more)")
    fuzz.add_argument("--out", required=True, metavar="DIR", help="where failing cases are written")
    fuzz.add_argument("--jobs", type=int, default=None,
                      help="worker processes (default: one per CPU)")
    fuzz.add_argument("--moves", type=int, default=None,
                      help="moves in every job (default: 200 to 400, drawn per case)")
    fuzz.add_argument("--keep-all", action="store_true",
                      help="write passing cases too (their first line: PASS)")
    fuzz.add_argument("--json", action="store_true", help="one JSON object per protocol summary")
    return fuzz


def fuzz_main(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """`fake-marlin scenario fuzz`; `parser` (fuzz's) reports what is wrong with `args`."""
    from fake_marlin.emulator.scenario.campaign import default_jobs, run_campaign

    for name, least in (("runs", 1), ("seed", 0), ("jobs", 1), ("moves", 1)):
        value = getattr(args, name)
        if value is not None and value < least:
            parser.error(f"--{name} must be at least {least}, not {value}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        parser.error(f"--out {out}: cannot make the directory: a file of that name is in the way")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        parser.error(f"--out {out}: cannot make the directory: {error.strerror or error}")
    protocols = FUZZ_PROTOCOLS if args.protocol == "all" else (args.protocol,)
    if args.firmware != "marlin":
        from fake_marlin.emulator.firmware import ProfileError, load_profile

        try:
            profile = load_profile(args.firmware)
        except ProfileError as error:
            parser.error(f"--firmware: {error}")
        if args.protocol != "marlin" or "marlin" not in profile.protocols:
            parser.error("--firmware: a firmware other than marlin is fuzzed with --protocol "
                         "marlin, and must speak it")
    variant_sets = _variant_sets(args.variant, parser)
    if args.variant and args.protocol != "ultimaker":
        parser.error("--variant: the protocol lab's variants are Ultimaker's; give --protocol "
                     "ultimaker")
    progress = _Progress() if sys.stderr.isatty() else None
    try:
        summaries = run_campaign(
            protocols, args.seed, args.runs, out, jobs=args.jobs or default_jobs(),
            moves=args.moves, keep_all=args.keep_all, progress=progress, firmware=args.firmware,
            variants=variant_sets,
        )
    except KeyboardInterrupt:
        print("\nfake-marlin scenario fuzz: interrupted", file=sys.stderr)
        return 130
    finally:
        if progress is not None:
            progress.clear()
    for summary in summaries:
        if args.json:
            print(json.dumps(summary.as_json()))
            continue
        for failure in summary.failures:
            print(f"FAIL  {failure['case']} ({failure['kind']}): {failure['reason']}\n"
                  f"      {failure['file']}")
        print(summary.line(), flush=True)
    failed = sum(summary.failed for summary in summaries)
    if not args.json and len(summaries) > 1:
        runs = sum(summary.runs for summary in summaries)
        print(f"fuzz: {runs} runs, {runs - failed} passed, {failed} failed")
    return 1 if failed else 0


def _variant_sets(given: list[str], parser: argparse.ArgumentParser) -> tuple[Variants, ...]:
    """Each --variant's set, in order, once each; `each`: every variant alone, then all."""
    if not given:
        return (PLAIN,)
    sets: list[Variants] = []
    for text in given:
        if text.strip() == "each":
            found = [*(parse_variants(name) for name in NAMES), parse_variants(",".join(NAMES))]
        else:
            try:
                found = [parse_variants(text)]
            except VariantError as error:
                parser.error(f"--variant: {error}")
        sets += [variants for variants in found if variants not in sets]
    return tuple(sets)


class _Progress:
    """One line on the terminal, rewritten: protocol, cases done of all, failures so far."""

    def __init__(self) -> None:
        self._width = 0

    def __call__(self, protocol: str, done: int, total: int, failed: int) -> None:
        text = f"fuzz {protocol}: {done}/{total} done, {failed} failed"
        sys.stderr.write("\r" + text.ljust(self._width))
        sys.stderr.flush()
        self._width = len(text)

    def clear(self) -> None:
        if self._width:
            sys.stderr.write("\r" + " " * self._width + "\r")
            sys.stderr.flush()
