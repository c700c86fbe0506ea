"""`fake-marlin bench --only farm`: farms, each beside one printer alone in the same run.

- one process of 4,000 printers on ptys: how long until every path is printed, its CPU idle,
  its memory per printer after the first;
- 10,000 printers over K processes (one per core) on TCP, past the kernel's 4,096 ptys: the
  same figures, all processes together;
- 200 of a K-process farm streaming at once with our host: the slowest printer's cmd/s against
  one printer alone, exactly once by their journals, and each process's share of the CPU;
- the live view (--web): an idle farm's CPU with and without it, and one printer's streaming
  rate with its page open in a reader against the same printer without --web.
"""

import os
import threading
import time
import urllib.request
from dataclasses import dataclass
from pathlib import Path

from fake_marlin.emulator.bench import jobs
from fake_marlin.emulator.bench.measure import SPEED, Bench, _ratio
from fake_marlin.emulator.bench.procs import BenchError, Proc, fake_marlin
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

ONE_PROCESS_UP_GOAL = 4.0  # s for 4,000 printers: issue 26's measure, to keep
IDLE_CPU_GOAL = 1.0  # % of one core, a whole farm
MEMORY_GOAL = 80 * 1024  # bytes per printer after the first (72 KB when issue 26 was filed)
FARM_RATE_GOAL = 50.0  # cmd/s for each printer
SPREAD_GOAL = 1.5  # the busiest process's CPU over the least busy's, streaming
WEB_IDLE_GOAL = 0.5  # % of one core more, an idle farm with --web and nobody watching
WEB_STREAMING_GOAL = 0.90  # a streaming printer's rate with its page watched, over without
START_TIMEOUT = 300.0
STOP_TIMEOUT = 60.0  # thousands of printers take seconds to close
TCP_PORT = 20000  # the 10,000-printer farm's first port (below Linux's ephemeral range)


@dataclass(frozen=True)
class Sizes:
    one_process: int  # printers on ptys in one process
    many: int  # printers on TCP over the processes
    streaming: int  # printers streaming at once
    moves: int  # each one's job
    idle_window: float  # seconds the CPU is watched
    web_moves: int  # the job of the printer streaming with its page watched


FULL = Sizes(4000, 10_000, 200, 300, 5.0, 2000)
QUICK = Sizes(400, 1000, 20, 100, 2.0, 500)


def _processes() -> int:
    """One process per core, at least two (a farm over processes is the point)."""
    return max(2, os.cpu_count() or 1)


def _farm(count: int, *extra: str) -> Target:
    return Target(f"fake-marlin --printers {count}",
                  fake_marlin("--printers", str(count), "--protocol", "marlin", *extra))


def farm_section(bench: Bench) -> Section:
    sizes = QUICK if bench.options.quick else FULL
    processes = _processes()
    section = Section(
        "farm", f"Farms: {sizes.one_process:,} printers in one process, {sizes.many:,} over "
        f"{processes} processes, {sizes.streaming} streaming {sizes.moves} moves each, the live "
        "view", ("figure", "measured", "reference"))
    parts = (
        lambda: _one_process(bench, section, sizes),
        lambda: _many(bench, section, sizes, processes),
        lambda: _streaming(bench, section, sizes, processes),
        lambda: _web(bench, section, sizes),
    )
    for part in parts:
        try:
            part()
        except BenchError as error:
            section.rows.append(Row("(a part of this section)", f"not available: {error}",
                                    data={"available": False}))
    return section


# -- starting and idling ----------------------------------------------------------------------
@dataclass
class _Started:
    proc: Proc
    ports: list[str]
    up: float  # seconds from the start to the last path printed


def _start(bench: Bench, target: Target, count: int) -> _Started:
    started = time.monotonic()
    proc = bench.procs.start("farm", target.argv)
    try:
        ports = proc.read_lines(count, START_TIMEOUT)
    except BaseException:
        bench.procs.stop(proc, STOP_TIMEOUT)
        raise
    return _Started(proc, ports, time.monotonic() - started)


def _idle_cpu(procs: list[Proc], window: float) -> list[float]:
    """Each farm's CPU (all its processes) in % of one core, watched side by side."""
    time.sleep(1.0)  # past the start-up's own work
    before = [sum(proc.tree_cpu_seconds()) for proc in procs], time.monotonic()
    time.sleep(window)
    after = [sum(proc.tree_cpu_seconds()) for proc in procs], time.monotonic()
    wall = after[1] - before[1]
    # Two clocks (schedstat, ticks) may disagree by a hair: an idle farm is never below 0.
    return [max(0.0, (b - a) / wall * 100) for a, b in zip(before[0], after[0])]


@dataclass
class _Idle:
    """A farm and one printer alone, started and left idle side by side."""

    one: _Started
    many: _Started
    one_cpu: float  # % of one core
    many_cpu: float
    rss_one: int
    rss_many: int  # all the farm's processes
    workers: int  # its --processes children (0: one process)

    def per_printer(self, count: int) -> float:
        """Memory per printer past each process's interpreter and first printer (which the
        one printer alone measures)."""
        serving = self.workers or 1
        processes = self.workers + 1 if self.workers else 1
        return (self.rss_many - processes * self.rss_one) / (count - serving)

    def cpu_row(self, count: int) -> Row:
        return Row(f"{count:,} printers idle: CPU", f"{self.many_cpu:.2f} % of one core",
                   f"{self.one_cpu:.2f} % (1 printer)", None, f"< {IDLE_CPU_GOAL:.0f} %",
                   self.many_cpu < IDLE_CPU_GOAL,
                   {"cpu_percent": self.many_cpu, "one_cpu_percent": self.one_cpu})


def _idle(bench: Bench, sizes: Sizes, count: int, one_extra: tuple[str, ...],
          many_extra: tuple[str, ...]) -> _Idle:
    one = _start(bench, _farm(1, *one_extra), 1)
    try:
        many = _start(bench, _farm(count, *many_extra), count)
        try:
            one_cpu, many_cpu = _idle_cpu([one.proc, many.proc], sizes.idle_window)
            return _Idle(one, many, one_cpu, many_cpu, one.proc.rss_bytes(),
                         many.proc.tree_rss_bytes(), len(many.proc.children()))
        finally:
            bench.procs.stop(many.proc, STOP_TIMEOUT)
    finally:
        bench.procs.stop(one.proc)


def _one_process(bench: Bench, section: Section, sizes: Sizes) -> None:
    count = sizes.one_process
    idle = _idle(bench, sizes, count, (), ())
    per_printer = idle.per_printer(count)
    full = sizes == FULL  # the goals are for the full farm: a small one is mostly start-up
    section.rows += [
        Row(f"{count:,} printers, one process, ptys: up", f"{idle.many.up:.2f} s",
            f"{idle.one.up:.2f} s (1 printer)", None,
            f"≤ {ONE_PROCESS_UP_GOAL:.1f} s" if full else "— (--quick)",
            idle.many.up <= ONE_PROCESS_UP_GOAL if full else None,
            {"seconds": idle.many.up, "one_seconds": idle.one.up}),
        idle.cpu_row(count),
        Row("memory per printer after the first", f"{per_printer / 1024:.0f} KB",
            f"{idle.rss_one / 2**20:.1f} MB (RSS, 1 printer)", None,
            f"≤ {MEMORY_GOAL // 1024} KB" if full else "— (--quick)",
            per_printer <= MEMORY_GOAL if full else None,
            {"bytes_per_printer": per_printer, "rss_one": idle.rss_one,
             "rss_many": idle.rss_many}),
    ]


def _many(bench: Bench, section: Section, sizes: Sizes, processes: int) -> None:
    count = sizes.many
    idle = _idle(bench, sizes, count, ("--tcp", "0"),
                 ("--processes", str(processes), "--tcp", f"127.0.0.1:{TCP_PORT}"))
    per_printer, workers = idle.per_printer(count), idle.workers
    full = sizes == FULL
    section.rows += [
        Row(f"{count:,} printers, {workers} processes, TCP: up", f"{idle.many.up:.2f} s",
            f"{idle.one.up:.2f} s (1 printer)", None, "every printer up",
            len(idle.many.ports) == count,
            {"seconds": idle.many.up, "one_seconds": idle.one.up, "processes": workers}),
        idle.cpu_row(count),
        Row(f"{count:,} printers: memory per printer", f"{per_printer / 1024:.0f} KB",
            f"{idle.rss_many / 2**20:,.0f} MB in all ({workers + 1} processes)", None,
            f"≤ {MEMORY_GOAL // 1024} KB" if full else "— (--quick)",
            per_printer <= MEMORY_GOAL if full else None,
            {"bytes_per_printer": per_printer, "rss_one": idle.rss_one,
             "rss_many": idle.rss_many}),
    ]


# -- streaming --------------------------------------------------------------------------------
def _host_processes() -> int:
    """One host process per spare CPU (up to 4), and at least 2: a host streaming to hundreds
    of printers must not be the one core that limits them all."""
    return max(2, min(4, (os.cpu_count() or 1) - 1))


def _streaming(bench: Bench, section: Section, sizes: Sizes, processes: int) -> None:
    count, moves = sizes.streaming, sizes.moves
    job = jobs.short_moves(moves)
    path = write_job(bench.workdir, f"farm-{moves}", job)
    host = our_host("marlin")
    alone = _stream_farm(bench, 1, 1, "alone", host, job, path)
    together = _stream_farm(bench, count, processes, "together", host, job, path)
    reference = alone.runs[0].rate if alone.runs else None
    rates = [run.rate for run in together.runs]
    known = [value for value in rates if value is not None]
    # The slowest of all: a printer whose run did not complete has no rate, and then no minimum.
    slowest = min(known) if known and len(known) == len(rates) == count else None
    complete = sum(run.complete for run in together.runs)
    once = sum(ok for ok, _ in together.verdicts)
    shares = together.process_cpu
    spread = max(shares) / min(shares) if shares and min(shares) > 0 else None
    section.rows += [
        Row(f"{count} printers streaming: the slowest", rate(slowest) if slowest else
            f"{complete} of {count} runs complete", f"{rate(reference)} (1 printer alone)",
            _ratio(slowest, reference), f"each ≥ {FARM_RATE_GOAL:.0f} cmd/s",
            slowest is not None and slowest >= FARM_RATE_GOAL,
            {"cmd_per_s": rates, "alone": reference, "complete": complete}),
        Row(f"{count} printers: ran exactly once", f"{once} of {count} journals",
            "verify against the job", None, "each exactly once",
            once == count == len(together.verdicts),
            {"journals": [why for _, why in together.verdicts]}),
        Row(f"{count} printers streaming: CPU of each process",
            " / ".join(f"{share:.0f} %" for share in shares) or "—",
            f"{alone.process_cpu[0]:.0f} % (1 printer alone)" if alone.process_cpu else "—",
            None, f"busiest ≤ {SPREAD_GOAL}× the least", spread is not None and
            spread <= SPREAD_GOAL, {"cpu_percent": shares, "spread": spread}),
    ]
    section.notes.append(
        f"--printers {count} --processes {processes} --protocol marlin --speed {SPEED}; our host "
        f"streams to all of them at once from {_host_processes()} process(es); CPU of each "
        "farm process in % of one core over the streaming (the first process only passes "
        "control requests on)")


@dataclass
class _Streamed:
    runs: list[Run]
    verdicts: list[tuple[bool, str]]
    process_cpu: list[float]  # % of one core over the run, of each process serving printers


def _stream_farm(bench: Bench, count: int, processes: int, name: str, host: Host,
                 job: list[str], path: Path) -> _Streamed:
    journals = bench.workdir / f"journals-{name}"
    journals.mkdir()
    extra = ["--processes", str(processes)] if processes > 1 else []
    target = _farm(count, "--speed", SPEED, "--journal", str(journals / "printer-{n}.log"),
                   *extra)
    farm = _start(bench, target, count)
    try:
        hosts = _host_processes() if count > 1 else 1
        groups = [farm.ports[k::hosts] for k in range(hosts)]
        before, started_at = farm.proc.tree_cpu_seconds(), time.monotonic()
        started = [start_host(bench.procs, host, group, path) for group in groups if group]
        runs = [run for each in started for run in collect(bench.procs, each, host, len(job))]
        after, wall = farm.proc.tree_cpu_seconds(), time.monotonic() - started_at
    finally:
        bench.procs.stop(farm.proc, STOP_TIMEOUT)
    shares = [(b - a) / wall * 100 for a, b in zip(before, after)]
    if processes > 1:
        shares = shares[1:]  # the printers' processes, not the first, which only relays
    files = sorted(journals.glob("*"))
    verdicts = [exactly_once(job, file) for file in files]
    verdicts += [(False, "no journal")] * max(0, count - len(files))
    return _Streamed(runs, verdicts, shares)


# -- the live view ----------------------------------------------------------------------------
def _web_url(proc: Proc, timeout: float = 30.0) -> str:
    """The live view's address, as the farm says it on stderr."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for line in proc.stderr_lines():
            if "live view at " in line:
                return line.split("live view at ", 1)[1].strip()
        time.sleep(0.05)
    raise BenchError(f"no live view address from {proc.name}: {proc.stderr_tail()}")


class _Reader(threading.Thread):
    """A browser's part: reads a page's event stream until told to stop."""

    def __init__(self, url: str) -> None:
        super().__init__(daemon=True)
        self.url = url
        self.events = 0
        self.error: str | None = None
        self._stopping = threading.Event()

    def run(self) -> None:
        try:
            with urllib.request.urlopen(self.url, timeout=10) as response:
                while not self._stopping.is_set():
                    line = response.readline()
                    if not line:
                        break
                    self.events += line.startswith(b"data:")
        except OSError as error:
            if not self._stopping.is_set():
                self.error = str(error)

    def stop(self) -> None:
        self._stopping.set()


def _web(bench: Bench, section: Section, sizes: Sizes) -> None:
    count = sizes.streaming
    without = _start(bench, _farm(count), count)
    try:
        with_web = _start(bench, _farm(count, "--web", "127.0.0.1:0"), count)
        try:
            _web_url(with_web.proc)
            plain_cpu, web_cpu = _idle_cpu([without.proc, with_web.proc], sizes.idle_window)
        finally:
            bench.procs.stop(with_web.proc, STOP_TIMEOUT)
    finally:
        bench.procs.stop(without.proc)
    section.rows.append(Row(
        f"{count} printers idle, --web, nobody watching: CPU", f"{web_cpu:.2f} % of one core",
        f"{plain_cpu:.2f} % (without --web)", None, f"< {WEB_IDLE_GOAL} % more",
        web_cpu - plain_cpu < WEB_IDLE_GOAL, {"cpu_percent": web_cpu, "without": plain_cpu}))

    job = jobs.short_moves(sizes.web_moves)
    path = write_job(bench.workdir, f"web-{len(job)}", job)
    host = our_host("marlin")
    plain, watched = [], []
    for _ in range(bench.options.rounds):  # side by side, in turns
        plain.append(_stream_one(bench, count, host, job, path, web=False))
        watched.append(_stream_one(bench, count, host, job, path, web=True))
    best_plain = max((run.rate for run in plain if run.rate), default=None)
    best_watched = max((run.rate for run in watched if run.rate), default=None)
    ratio = _ratio(best_watched, best_plain)
    section.rows.append(Row(
        "1 printer streaming, its page and the farm's watched", rate(best_watched),
        f"{rate(best_plain)} (without --web)", ratio, f"≥ {WEB_STREAMING_GOAL:.2f}",
        ratio is not None and ratio >= WEB_STREAMING_GOAL,
        {"watched": [run.rate for run in watched], "plain": [run.rate for run in plain]}))
    section.notes.append(
        f"the live view: --printers {count} idle with and without --web; then one printer "
        f"of {count} streaming {len(job)} moves at --speed {SPEED}, with two readers of the "
        "event streams of its page and the farm's page, the best of "
        f"{bench.options.rounds} turn(s) each")


def _stream_one(bench: Bench, count: int, host: Host, job: list[str], path: Path,
                web: bool) -> Run:
    extra = ["--web", "127.0.0.1:0"] if web else []
    farm = _start(bench, _farm(count, "--speed", SPEED, *extra), count)
    readers: list[_Reader] = []
    try:
        if web:
            url = _web_url(farm.proc)
            readers = [_Reader(url + "events"), _Reader(url + "printer/1/events")]
            for reader in readers:
                reader.start()
            time.sleep(0.5)  # the readers connected and the views are being fed
        started = start_host(bench.procs, host, farm.ports[:1], path)
        runs = collect(bench.procs, started, host, len(job))
        for reader in readers:
            if reader.error or (reader.is_alive() and not reader.events):
                raise BenchError(f"the live view's {reader.url} gave nothing: "
                                 f"{reader.error or 'no events'}")
    finally:
        for reader in readers:
            reader.stop()
        bench.procs.stop(farm.proc, STOP_TIMEOUT)
    return runs[0]
