"""The bench's sections. Each measures its figures side by side with a reference in the same
run and returns a report.Section; none asserts anything (a missed goal is a figure, not an
error).

The line conditions (--baud, --latency-ms) run on the printer's simulated clock, like all its
time. Where a section needs them in wall time while the moves must not be what limits the rate,
it runs the printer faster and scales them: `--speed 100 --baud 2500` is a 250000-baud line in
wall time, with motion 100 times faster than a real printer's (0.4 mm at 100 mm/s is 18 ms of
acceleration-bound motion: 54 moves/s at --speed 1, below the wire's rate).
"""

import os
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from fake_marlin.emulator.bench import jobs
from fake_marlin.emulator.bench.procs import Processes
from fake_marlin.emulator.bench.report import Row, Section, rate
from fake_marlin.emulator.bench.runs import (
    BARE,
    BARE_ON_TRIO,
    Host,
    Run,
    Target,
    describe_error,
    octoprint,
    our_host,
    printcore,
    printer,
    start_printer,
    stream,
    write_job,
)
from fake_marlin.emulator.link.direct_wait import WAITS_VARIABLE, waits_in_use
from fake_marlin.host import ClientOptions
from fake_marlin.host.codecs import ultimaker as ultimaker_codec
from fake_marlin.wire import ultimaker as ultimaker_wire

SPEED = "1000"  # simulated time for throughput runs: the moves never limit the rate
# The M115 capabilities that make a host ask for reports at intervals; the bare responder has none.
AUTOREPORTS = ("AUTOREPORT_TEMP", "AUTOREPORT_POS", "AUTOREPORT_SD_STATUS")
WIRE_BAUD = 250000
BAUD_SPEED = 100
LATENCY_MS = 30.0
LATENCY_SPEED = 10


@dataclass(frozen=True)
class Options:
    quick: bool
    moves: int  # the throughput job
    rounds: int  # side-by-side rounds of each throughput pair
    only: tuple[str, ...]


class Bench:
    def __init__(self, options: Options, procs: Processes, workdir: Path) -> None:
        self.options = options
        self.procs = procs
        self.workdir = workdir
        self._pairs: dict[str, tuple[list[Run], list[Run]]] = {}

    def pair(self, host: Host, first: Target, second: Target, job: list[str],
             path: Path) -> tuple[list[Run], list[Run]]:
        """`rounds` runs against each target, alternating which goes first (ABBA...) so that
        the machine's drift during the pair falls on both alike. Cached per host: the hosts and
        cpu sections share our Marlin host's runs."""
        key = f"{host.key}:{first}:{second}:{len(job)}"
        if key not in self._pairs:
            firsts: list[Run] = []
            seconds: list[Run] = []
            for round_ in range(self.options.rounds):
                order = [(first, firsts), (second, seconds)]
                for target, runs in order if round_ % 2 == 0 else order[::-1]:
                    runs.append(stream(self.procs, host, target, path, len(job)))
            self._pairs[key] = (firsts, seconds)
        return self._pairs[key]

    def throughput_job(self) -> tuple[list[str], Path]:
        job = jobs.short_moves(self.options.moves)
        return job, write_job(self.workdir, f"short-{len(job)}", job)


def _summary(runs: list[Run]) -> dict:
    """The median rate of complete rounds; complete only if every round was."""
    rates = [run.rate for run in runs if run.rate is not None]
    return {"cmd_per_s": statistics.median(rates) if rates else None,
            "complete": bool(runs) and all(run.complete for run in runs),
            "acknowledged": min((run.acknowledged for run in runs), default=0),
            "job": runs[0].job if runs else 0, "runs": [run.as_dict() for run in runs]}


def _figure(summary: dict) -> str:
    if summary["complete"]:
        return rate(summary["cmd_per_s"])
    errors = [run["error"] for run in summary["runs"] if run["error"]]
    why = f": {errors[0][:160]}" if errors else ""
    return f"incomplete, {summary['acknowledged']}/{summary['job']} acknowledged{why}"


def _ratio(value: float | None, reference: float | None) -> float | None:
    return value / reference if value is not None and reference else None


def _paired_ratio(values: list[float | None], references: list[float | None]) -> float | None:
    """The median of each round's own ratio: a round's two runs go back to back, so the
    machine's drift (several-fold within minutes here) falls on both alike, where a ratio of
    medians would mix runs minutes apart."""
    ratios = [value / reference for value, reference in zip(values, references)
              if value is not None and reference]
    return statistics.median(ratios) if ratios else None


# -- 1. host throughput ---------------------------------------------------------------------
HOST_GOALS = {"ours-marlin": 0.9, "octoprint": 0.95, "printcore": 0.95}
ULTIMAKER_GOAL = 5000.0
TRIO_WAITS = "trio's own waits"  # the variant without direct waits (link/direct_wait.py)


def _throughput_printer() -> Target:
    """fake-marlin as the hosts and cpu sections stream to it (one target, so that they share
    our host's runs), with the same capabilities as the responder's, so that a host does the
    same work against both: told of auto-reports, OctoPrint turns on M155 S2, M154 S5 and M27
    S1, whose intervals are simulated seconds (a position every 5 ms of wall time at --speed
    1000), and it would be timing its own reading of those."""
    return printer("marlin", "--speed", SPEED, *(f"--capability={name}=0" for name in AUTOREPORTS))


def _with_trio_waits(target: Target) -> Target:
    """The same printer waiting for its pty through trio alone, as on a trio release that
    direct waits are not verified on."""
    return target.with_env(f"{target.label}, {TRIO_WAITS}", **{WAITS_VARIABLE: "trio"})


def hosts(bench: Bench) -> Section:
    job, path = bench.throughput_job()
    rounds = bench.options.rounds
    section = Section("hosts", f"Host throughput: {len(job)} moves of 0.4 mm, "
                      + (f"median of {rounds} rounds (a ratio: of each round's pair)"
                         if rounds > 1 else "one round"),
                      ("host", "cmd/s to fake-marlin", "cmd/s to bare responder"))
    marlin = _throughput_printer()
    for host in (our_host("marlin"), octoprint(), printcore()):
        if host.command is None:
            section.rows.append(Row(host.label, host.missing, data={"host": host.key,
                                                                   "installed": False}))
            continue
        goal = HOST_GOALS.get(host.key)
        # fake-marlin as it runs here (direct waits on a verified trio), then without them.
        for target, label, row_goal in ((marlin, host.label, goal),
                                        (_with_trio_waits(marlin),
                                         f"{host.label}, fake-marlin on {TRIO_WAITS}", None)):
            printer_name = f"fake-marlin, {TRIO_WAITS}" if target.env else "fake-marlin"
            pair = bench.pair(host, target, BARE, job, path)
            emulated, bare = (_summary(runs) for runs in pair)
            ratio = _paired_ratio(*([run.rate for run in runs] for runs in pair))
            complete = emulated["complete"] and bare["complete"]
            section.rows.append(Row(
                label, _figure(emulated), _figure(bare), ratio,
                f"ratio ≥ {row_goal}" if row_goal else "—",
                None if row_goal is None else complete and ratio is not None and ratio >= row_goal,
                {"host": host.key, "printer": printer_name, "installed": True,
                 "fake_marlin": emulated, "bare": bare},
            ))
        if goal is not None:  # how near its goal any trio printer could come
            section.rows.append(_trio_floor_row(bench, host, job, path))
    ultimaker = our_host("ultimaker")
    runs = [stream(bench.procs, ultimaker, printer("ultimaker", "--speed", SPEED), path, len(job))
            for _ in range(bench.options.rounds)]
    emulated = _summary(runs)
    value = emulated["cmd_per_s"]
    section.rows.append(Row(
        ultimaker.label, _figure(emulated), "— (no bare Ultimaker peer)", None,
        f"≥ {ULTIMAKER_GOAL:,.0f} cmd/s",
        emulated["complete"] and value is not None and value >= ULTIMAKER_GOAL,
        {"host": ultimaker.key, "installed": True, "fake_marlin": emulated, "bare": None},
    ))
    section.notes.append(f"waits: {waits_in_use()[1]}; the rows `on {TRIO_WAITS}` run "
                         f"fake-marlin with {WAITS_VARIABLE}=trio, side by side")
    section.notes.append(f"fake-marlin runs at --speed {SPEED}; the bare responder "
                         "(fake_marlin.emulator.bench.responder) answers each line at once and "
                         "simulates nothing; every host and printer is a process of its own; "
                         "the time is the job's alone (connecting excluded); both advertise "
                         "the same capabilities (no AUTOREPORT_TEMP, _POS or _SD_STATUS), so "
                         "each host does the same work against both")
    return section


def _trio_floor_row(bench: Bench, host: Host, job: list[str], path: Path) -> Row:
    """The host against the bare responder on trio: how near 1 any trio printer can come."""
    pair = bench.pair(host, BARE_ON_TRIO, BARE, job, path)
    on_trio, bare = (_summary(runs) for runs in pair)
    ratio = _paired_ratio(*([run.rate for run in runs] for runs in pair))
    return Row(f"{host.label}, to the bare responder on trio", _figure(on_trio), _figure(bare),
               ratio, "— (the floor)", None,
               {"host": host.key, "printer": BARE_ON_TRIO.label, "installed": True,
                "bare_on_trio": on_trio, "bare": bare})


# -- 2. CPU per command ---------------------------------------------------------------------
def _cpu_per_command(pair: tuple[list[Run], list[Run]]) -> tuple[list[float], list[float]] | None:
    """Each side's printer CPU µs per command, round by round; None if a run was incomplete."""
    if not pair[0] or not all(run.complete and run.printer_cpu is not None
                              for side in pair for run in side):
        return None
    first, second = ([(run.printer_cpu or 0.0) / run.job * 1e6 for run in side] for side in pair)
    return first, second


def cpu(bench: Bench) -> Section:
    job, path = bench.throughput_job()
    section = Section("cpu", f"Printer CPU per command: our host, Marlin, {len(job)} moves",
                      ("process", "µs CPU per command", "bare responder"))
    # The ratio to the bare responder is a figure, not a goal: what a user feels is the host's
    # speed (the hosts section), and a cheaper command is not worth a dependency's private state.
    mine: float | None = None  # as fake-marlin runs here (direct waits on a verified trio)
    for target, label in ((_throughput_printer(), "fake-marlin --protocol marlin"),
                          (_with_trio_waits(_throughput_printer()),
                           f"fake-marlin --protocol marlin, {TRIO_WAITS}")):
        measured = _cpu_per_command(bench.pair(our_host("marlin"), target, BARE, job, path))
        if measured is None:
            section.rows.append(Row(label, "not measured: a run was incomplete"))
            continue
        emulated, bare = measured
        us, reference = statistics.median(emulated), statistics.median(bare)
        if not target.env:
            mine = us
        section.rows.append(Row(label, f"{us:.1f} µs", f"{reference:.1f} µs",
                                _paired_ratio(list(emulated), list(bare)), "—", None,
                                {"fake_marlin_us": us, "bare_us": reference,
                                 "rounds": len(emulated), "printer": target.label}))
    if mine is None:
        return section
    section.rows.append(Row("fake-marlin, absolute", f"{mine:.1f} µs", "—", None,
                            "≤ 100 µs (unloaded machine)", mine <= 100, {"fake_marlin_us": mine}))
    section.rows.append(_trace_row(bench, job, path))
    floor = _cpu_per_command(bench.pair(our_host("marlin"), BARE_ON_TRIO, BARE, job, path))
    if floor is not None:
        on_trio, plain = floor
        section.rows.append(Row(
            "bare responder on trio", f"{statistics.median(on_trio):.1f} µs",
            f"{statistics.median(plain):.1f} µs", _paired_ratio(list(on_trio), list(plain)),
            "— (the floor)", None,
            {"trio_us": statistics.median(on_trio), "bare_us": statistics.median(plain)}))
        section.notes.append("the bare responder on trio answers as the bare one does but waits "
                             "for its pty as fake-marlin does (link/direct_wait.py): "
                             "what any printer on trio pays per command before it does anything")
    section.notes.append(f"the printer process's own CPU time (user + system, /proc) while the "
                         f"job ran, over the job's commands; load average "
                         f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    return section


def _trace_row(bench: Bench, job: list[str], path: Path) -> Row:
    """What writing a trace costs the printer: the same job, traced and not, side by side."""
    trace = bench.workdir / "bench.trace.jsonl"
    plain = _throughput_printer()
    traced = Target(f"{plain.label} --trace", [*plain.argv, "--trace", str(trace)])
    runs = bench.pair(our_host("marlin"), traced, plain, job, path)
    measured = _cpu_per_command(runs)
    if measured is None:
        return Row("fake-marlin --trace FILE", "not measured: a run was incomplete")
    with_trace, without = measured
    speed = _paired_ratio(*([run.rate for run in side] for side in runs))
    size = trace.stat().st_size * 1000 / len(job) if trace.exists() else None
    return Row(
        "fake-marlin --trace FILE", f"{statistics.median(with_trace):.1f} µs",
        f"{statistics.median(without):.1f} µs untraced",
        _paired_ratio(list(with_trace), list(without)),
        f"— (host speed {speed:.2f} of untraced; {size / 1000:.0f} KB per 1,000 commands)"
        if speed is not None and size is not None else "—", None,
        {"traced_us": statistics.median(with_trace), "untraced_us": statistics.median(without),
         "host_speed_ratio": speed, "bytes_per_1000_commands": size})


# -- 3. paced at 250000 baud ------------------------------------------------------------------
def baud(bench: Bench) -> Section:
    job = jobs.short_moves(150 if bench.options.quick else 600)
    path = write_job(bench.workdir, f"baud-{len(job)}", job)
    section = Section("baud", f"Ultimaker at {WIRE_BAUD} baud: {len(job)} moves of 0.4 mm",
                      ("host", "packets/s", "wire limit"))
    to_printer = statistics.mean(len(ultimaker_codec.encode_command(1, c)) for c in job)
    to_host = len(f"\n{ultimaker_wire.frame_body('o', 1, 15)}\n")  # one `o` frame per packet
    limit = WIRE_BAUD / 10 / max(to_printer, to_host)
    target = printer("ultimaker", "--speed", str(BAUD_SPEED), "--baud",
                     str(WIRE_BAUD // BAUD_SPEED))
    run = stream(bench.procs, our_host("ultimaker"), target, path, len(job))
    packets = run.summary.get("packets_sent")
    measured = packets / run.elapsed if run.complete and run.elapsed and packets else None
    figure = rate(measured, "packets/s") if measured else _figure(_summary([run]))
    section.rows.append(Row(
        "our host, Ultimaker", figure, f"{limit:,.0f} packets/s", _ratio(measured, limit),
        "—", None,
        {"packets_per_s": measured, "wire_limit": limit, "bytes_to_printer": to_printer,
         "bytes_to_host": to_host, "run": run.as_dict()},
    ))
    section.notes.append(
        f"the limit: {WIRE_BAUD // 10:,} bytes/s over the busier direction's bytes per packet "
        f"({to_printer:.1f} to the printer, {to_host} back); the printer runs at --speed "
        f"{BAUD_SPEED} --baud {WIRE_BAUD // BAUD_SPEED} (pacing is in simulated time, so that "
        f"is {WIRE_BAUD} baud of wall time, and the moves do not limit the rate)")
    return section


# -- 4. 30 ms latency -------------------------------------------------------------------------
def latency(bench: Bench) -> Section:
    job = jobs.short_moves(40 if bench.options.quick else 200)
    path = write_job(bench.workdir, f"latency-{len(job)}", job)
    section = Section("latency", f"{LATENCY_MS:.0f} ms latency each way: {len(job)} moves",
                      ("host", "cmd/s", "reference"))
    extra = ("--speed", str(LATENCY_SPEED), "--latency-ms", str(LATENCY_MS * LATENCY_SPEED))
    window = ClientOptions().window
    windowed = stream(bench.procs, our_host("ultimaker"), printer("ultimaker", *extra), path,
                      len(job))
    waiting = stream(bench.procs, our_host("marlin"), printer("marlin", *extra), path, len(job))
    round_trip = 2 * LATENCY_MS / 1000
    u, m = windowed.rate, waiting.rate
    u_text, m_text = (_figure(_summary([run])) for run in (windowed, waiting))
    section.rows += [
        Row(f"Ultimaker, windowed ({window} in flight)", u_text,
            f"{m_text} (Marlin, stop-and-wait)", _ratio(u, m),
            data={"ultimaker": windowed.as_dict(), "marlin": waiting.as_dict()}),
        Row("Ultimaker against its bound", u_text,
            f"{window / round_trip:,.1f} cmd/s (window / round trip)",
            _ratio(u, window / round_trip)),
        Row("Marlin against its bound", m_text, f"{1 / round_trip:,.1f} cmd/s (1 / round trip)",
            _ratio(m, 1 / round_trip)),
    ]
    section.notes.append(f"the printer runs at --speed {LATENCY_SPEED} --latency-ms "
                         f"{LATENCY_MS * LATENCY_SPEED:.0f}: {LATENCY_MS:.0f} ms of wall time")
    return section


# -- 5. one simulated hour --------------------------------------------------------------------
def simhour(bench: Bench) -> Section:
    hours = 1 / 6 if bench.options.quick else 1.0
    job = jobs.long_moves(jobs.long_moves_for(3600 * hours))
    path = write_job(bench.workdir, f"long-{len(job)}", job)
    simulated = jobs.simulated_seconds(job)
    section = Section("simhour", f"One simulated hour: {len(job) - 1} moves of 200 mm at "
                      f"50 mm/s and M400 ({simulated / 60:.0f} simulated minutes), --speed "
                      f"{SPEED}", ("printer", "wall s per simulated hour", "ideal"))
    run = stream(bench.procs, our_host("marlin"), printer("marlin", "--speed", SPEED), path,
                 len(job))
    ideal = 3600 / float(SPEED)
    per_hour = run.elapsed * 3600 / simulated if run.complete and run.elapsed else None
    section.rows.append(Row(
        "fake-marlin --protocol marlin, our host", f"{per_hour:.2f} s" if per_hour else
        _figure(_summary([run])), f"{ideal:.2f} s (3600 / speed)", _ratio(per_hour, ideal),
        data={"wall_s_per_sim_hour": per_hour, "simulated_s": simulated, "run": run.as_dict()},
    ))
    section.notes.append("simulated time is the printer model's own motion time for the job "
                         "(emulator/printer/planner.py), the wall time the host's, start to the "
                         "M400's ok")
    return section


# -- 6. farms ---------------------------------------------------------------------------------
def farm(bench: Bench) -> Section:
    from fake_marlin.emulator.bench.farm_section import farm_section

    return farm_section(bench)


# -- 7. the protocol lab ----------------------------------------------------------------------
def lab(bench: Bench) -> Section:
    from fake_marlin.emulator.bench.lab_section import lab_section

    return lab_section(bench.options.quick)


SECTIONS: dict[str, Callable[[Bench], Section]] = {
    "hosts": hosts, "cpu": cpu, "baud": baud, "latency": latency, "simhour": simhour,
    "farm": farm, "lab": lab,
}


def run_section(bench: Bench, key: str) -> Section:
    """One section; a part that could not run is a row saying why, never a traceback."""
    started = time.monotonic()
    try:
        section = SECTIONS[key](bench)
    except Exception as error:  # noqa: BLE001 - a measurement reports, it does not crash
        section = Section(key, key, ("figure", "measured", "reference"),
                          [Row(key, f"could not run: {describe_error(error)}")])
    section.seconds = time.monotonic() - started
    return section
