"""`fake-marlin bench --only farm`: many printers in one process, idle and streaming."""

import os
import time
from pathlib import Path

from fake_marlin.emulator.bench import jobs
from fake_marlin.emulator.bench.measure import SPEED, Bench, _ratio
from fake_marlin.emulator.bench.procs import BenchError, fake_marlin
from fake_marlin.emulator.bench.report import Row, Section, rate
from fake_marlin.emulator.bench.runs import (
    Host,
    Run,
    Target,
    collect,
    exactly_once,
    our_host,
    start_host,
    write_job,
)


# -- farms ---------------------------------------------------------------------------------
IDLE_CPU_GOAL = 5.0  # % of one core
MEMORY_GOAL = 1 << 20  # bytes per printer
FARM_RATE_GOAL = 50.0  # cmd/s for each printer
FARM_START_TIMEOUT = 180.0


def _farm(count: int, *extra: str) -> Target:
    return Target(f"fake-marlin --printers {count}",
                  fake_marlin("--printers", str(count), "--protocol", "marlin", *extra))


def farm_section(bench: Bench) -> Section:
    quick = bench.options.quick
    idle_count, streaming, moves = (50, 10, 100) if quick else (200, 50, 300)
    section = Section("farm", f"Farms: {idle_count} printers idle, {streaming} streaming "
                      f"{moves} moves each", ("figure", "measured", "reference"))
    try:
        _farm_idle(bench, section, idle_count)
        _farm_streaming(bench, section, streaming, moves)
    except BenchError as error:
        text = str(error)
        if "--printers" in text or "unrecognized" in text:
            text = f"fake-marlin has no --printers yet ({text})"
        section.rows.append(Row("fake-marlin --printers N", f"not available: {text}",
                                data={"available": False}))
    return section


def _farm_idle(bench: Bench, section: Section, count: int) -> None:
    window = 2.0 if bench.options.quick else 5.0
    one, _ = _start_farm(bench, _farm(1), 1)
    many, _ = _start_farm(bench, _farm(count), count)
    try:
        time.sleep(1.0)  # past the start-up's own work
        before = (one.cpu_seconds(), many.cpu_seconds(), time.monotonic())
        time.sleep(window)
        after = (one.cpu_seconds(), many.cpu_seconds(), time.monotonic())
        wall = after[2] - before[2]
        one_cpu, many_cpu = ((b - a) / wall * 100 for a, b in zip(before[:2], after[:2]))
        rss_one, rss_many = one.rss_bytes(), many.rss_bytes()
    finally:
        bench.procs.stop(many)
        bench.procs.stop(one)
    per_printer = (rss_many - rss_one) / (count - 1)
    section.rows += [
        Row(f"{count} printers idle: CPU", f"{many_cpu:.2f} % of one core",
            f"{one_cpu:.2f} % (1 printer)", None, f"< {IDLE_CPU_GOAL:.0f} %",
            many_cpu < IDLE_CPU_GOAL, {"cpu_percent": many_cpu, "one_cpu_percent": one_cpu,
                                       "seconds": wall}),
        Row("memory per printer after the first", f"{per_printer / 2**20:.2f} MB",
            f"{rss_one / 2**20:.1f} MB (RSS, 1 printer)", None, "< 1 MB",
            per_printer < MEMORY_GOAL, {"bytes_per_printer": per_printer, "rss_one": rss_one,
                                        f"rss_{count}": rss_many}),
    ]


def _start_farm(bench: Bench, target: Target, count: int):
    proc = bench.procs.start("farm", target.argv)
    try:
        return proc, proc.read_lines(count, FARM_START_TIMEOUT)
    except BaseException:
        bench.procs.stop(proc)
        raise


def _farm_streaming(bench: Bench, section: Section, count: int, moves: int) -> None:
    job = jobs.short_moves(moves)
    path = write_job(bench.workdir, f"farm-{moves}", job)
    host = our_host("marlin")
    alone = _stream_farm(bench, 1, "alone", host, job, path)
    together = _stream_farm(bench, count, "together", host, job, path)
    reference = alone[0][0].rate if alone[0] else None
    rates = [run.rate for run in together[0]]
    known = [value for value in rates if value is not None]
    # The slowest of all: a printer whose run did not complete has no rate, and then no minimum.
    slowest = min(known) if known and len(known) == len(rates) == count else None
    complete = sum(run.complete for run in together[0])
    verdicts = together[1]
    once = sum(ok for ok, _ in verdicts)
    section.rows += [
        Row(f"{count} printers streaming: the slowest", rate(slowest) if slowest else
            f"{complete} of {count} runs complete", f"{rate(reference)} (1 printer alone)",
            _ratio(slowest, reference), f"each ≥ {FARM_RATE_GOAL:.0f} cmd/s",
            slowest is not None and slowest >= FARM_RATE_GOAL,
            {"cmd_per_s": rates, "alone": reference, "complete": complete}),
        Row(f"{count} printers: ran exactly once", f"{once} of {count} journals",
            "verify against the job", None, "each exactly once",
            once == count == len(verdicts),
            {"journals": [why for _, why in verdicts]}),
    ]
    section.notes.append(f"--printers {count} --protocol marlin --speed {SPEED}; our host streams "
                         f"to all of them at once from {_host_processes()} process(es)")


def _host_processes() -> int:
    """One host process per spare CPU (up to 4): more than that only take turns on a core."""
    return max(1, min(4, (os.cpu_count() or 1) - 1))


def _stream_farm(bench: Bench, count: int, name: str, host: Host, job: list[str],
                 path: Path) -> tuple[list[Run], list[tuple[bool, str]]]:
    journals = bench.workdir / f"journals-{name}"
    journals.mkdir()
    target = _farm(count, "--speed", SPEED, "--journal", str(journals / "printer-{n}.log"))
    proc, ports = _start_farm(bench, target, count)
    try:
        groups = [ports[k::_host_processes()] for k in range(_host_processes())]
        started = [start_host(bench.procs, host, group, path) for group in groups if group]
        runs = [run for each in started for run in collect(bench.procs, each, host, len(job))]
    finally:
        bench.procs.stop(proc)
    files = sorted(journals.glob("*"))
    verdicts = [exactly_once(job, file) for file in files]
    verdicts += [(False, "no journal")] * max(0, count - len(files))
    return runs, verdicts
