"""Run fuzz campaigns: many generated scenarios (fuzz.py) with the built-in host, in parallel.

Each case runs in a worker process exactly as `fake-marlin scenario run FILE` runs it: its TOML
text is written to a file, loaded with the loader and run with run_scenario. A run is a pure
function of its file, so the worker that ran it, and what that worker ran before, do not
matter: a failing case written out as `DIR/<protocol>-<seed>-<n>.toml` fails again, with the
same digest, when run on its own. Results are gathered by case number, so what is printed and
written never depends on which worker finished first.
"""

import concurrent.futures
import multiprocessing
import os
import tempfile
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from fake_marlin.emulator.journal.verify import Kind, verify
from fake_marlin.emulator.scenario import fuzz
from fake_marlin.emulator.scenario.definition import ScenarioError, load
from fake_marlin.emulator.scenario.run import ScenarioResult, run_scenario
from fake_marlin.wire.ultimaker_variants import PLAIN, Variants


@dataclass(frozen=True)
class Case:
    protocol: str
    seed: int
    number: int
    table: fuzz.Table

    @property
    def name(self) -> str:
        return str(self.table["name"])  # fuzz.case_name's, with the firmware where not Marlin

    @property
    def text(self) -> str:
        return fuzz.scenario_text(self.table)


@dataclass(frozen=True)
class CaseResult:
    name: str
    passed: bool
    reason: str  # the first failing check, "name: detail"; for a pass, what happened
    outcome: str = ""
    digest: str = ""
    simulated_seconds: float = 0.0
    damaged: int = 0  # job commands that ran damaged past the protocol's check
    wall_seconds: float = 0.0


@dataclass
class Summary:
    protocol: str
    seed: int
    runs: int = 0
    passed: int = 0
    failed: int = 0
    ran_damaged: int = 0  # runs in which some command ran damaged (undetectable damage)
    damaged_commands: int = 0
    simulated_seconds: float = 0.0  # in all
    wall_seconds: float = 0.0
    failures: list[dict] = field(default_factory=list)  # case, file, kind, reason, digest

    @property
    def mean_simulated_seconds(self) -> float:
        return self.simulated_seconds / self.runs if self.runs else 0.0

    def as_json(self) -> dict:
        return {
            "protocol": self.protocol, "seed": self.seed, "runs": self.runs,
            "passed": self.passed, "failed": self.failed, "ran_damaged": self.ran_damaged,
            "damaged_commands": self.damaged_commands,
            "mean_simulated_seconds": round(self.mean_simulated_seconds, 3),
            "wall_seconds": round(self.wall_seconds, 3), "failures": self.failures,
        }

    def line(self) -> str:
        return (f"{self.protocol}: {self.runs} runs, {self.passed} passed, {self.failed} failed, "
                f"{self.ran_damaged} ran damaged ({self.damaged_commands} commands); "
                f"{self.mean_simulated_seconds:.1f} s simulated on average; "
                f"{self.wall_seconds:.1f} s wall")


def cases(protocol: str, seed: int, runs: int, moves: int | None = None,
          firmware: str = "marlin", variants: Variants = PLAIN) -> list[Case]:
    return [Case(protocol, seed, number,
                 fuzz.generate(protocol, seed, number, moves, firmware, variants))
            for number in range(1, runs + 1)]


def failure_reason(result: ScenarioResult) -> str:
    """The first failing check, as the report shows it: `outcome is completed: PrinterReset:
    ...`."""
    for check in result.checks:
        if not check.passed:
            return f"{check.name}: {check.detail}" if check.detail else check.name
    return ""


def run_case(name: str, text: str) -> CaseResult:
    """Run one scenario, given as the text of its file, as `scenario run` would (the worker)."""
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="fake-marlin-fuzz-") as directory:
        path = Path(directory) / f"{name}.toml"
        path.write_text(text, encoding="utf-8")
        try:
            scenario = load(path)
        except ScenarioError as error:  # a generator bug: it must make valid files
            return CaseResult(name, False, f"the loader refused the generated scenario: {error}")
        try:
            result = run_scenario(scenario)
        except Exception as error:  # noqa: BLE001 - a crash is a finding, not the campaign's end
            return CaseResult(name, False, f"the run crashed: {type(error).__name__}: {error}",
                              "crashed", wall_seconds=time.perf_counter() - started)
    damaged = verify(list(enumerate(scenario.job, start=1)), result.journal).count(Kind.DAMAGED)
    if result.passed:
        reason = f"{result.outcome}" + (f": {result.error}" if result.error else "")
    else:
        reason = failure_reason(result)
    return CaseResult(name, result.passed, reason, result.outcome, result.digest,
                      result.simulated_seconds, damaged, time.perf_counter() - started)


def write_case(directory: Path, case: Case, reason: str) -> Path:
    """`DIR/<name>.toml`: the case as a standalone scenario, its first line `# <reason>`."""
    path = directory / f"{case.name}.toml"
    path.write_text(fuzz.scenario_text(case.table, reason), encoding="utf-8")
    return path


Progress = Callable[[str, int, int, int], None]  # protocol, done, total, failed so far


def run_campaign(
    protocols: Iterable[str], seed: int, runs: int, out: Path, jobs: int = 1,
    moves: int | None = None, keep_all: bool = False, progress: Progress | None = None,
    firmware: str = "marlin", variants: Iterable[Variants] = (PLAIN,),
) -> list[Summary]:
    """Run `runs` cases per protocol (and per variant set, for Ultimaker), one after another,
    in `jobs` worker processes; write each failing case (each case, with `keep_all`) to
    `out`."""
    executor = None
    if jobs > 1:
        # Fresh interpreters (spawn), not forks of this one: a worker holds nothing but what
        # a `scenario run` process would.
        executor = concurrent.futures.ProcessPoolExecutor(
            max_workers=jobs, mp_context=multiprocessing.get_context("spawn"))
    summaries = []
    try:
        for protocol in protocols:
            for variant_set in variants if protocol == "ultimaker" else (PLAIN,):
                summaries.append(_run_protocol(
                    protocol, seed, runs, out, executor, moves, keep_all, progress, firmware,
                    variant_set))
    finally:
        if executor is not None:
            executor.shutdown(wait=True, cancel_futures=True)
    return summaries


def _run_protocol(protocol, seed, runs, out, executor, moves, keep_all, progress,
                  firmware="marlin", variants: Variants = PLAIN) -> Summary:
    started = time.perf_counter()
    todo = cases(protocol, seed, runs, moves, firmware, variants)
    name = protocol if firmware == "marlin" else f"{protocol} ({firmware})"
    if not variants.plain:
        name = f"{protocol} ({variants})"
    results: dict[int, CaseResult] = {}
    failed = 0

    def done(index: int, result: CaseResult) -> None:
        nonlocal failed
        results[index] = result
        failed += not result.passed
        if progress is not None:
            progress(name, len(results), len(todo), failed)

    if executor is None:
        for index, case in enumerate(todo):
            done(index, run_case(case.name, case.text))
    else:
        futures = {executor.submit(run_case, case.name, case.text): index
                   for index, case in enumerate(todo)}
        for future in concurrent.futures.as_completed(futures):
            done(futures[future], future.result())
    summary = Summary(name, seed)
    for index, case in enumerate(todo):
        result = results[index]
        summary.runs += 1
        summary.passed += result.passed
        summary.failed += not result.passed
        summary.ran_damaged += result.damaged > 0
        summary.damaged_commands += result.damaged
        summary.simulated_seconds += result.simulated_seconds
        if not result.passed or keep_all:
            verdict = "PASS: " if result.passed else "FAIL: "
            path = write_case(out, case, verdict + result.reason)
        if not result.passed:
            summary.failures.append({
                "case": case.name, "file": str(path), "kind": fuzz.case_kind(case.table),
                "reason": fuzz.one_line(result.reason), "digest": result.digest,
            })
    summary.wall_seconds = time.perf_counter() - started
    return summary


def default_jobs() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1
