"""The numbers at the top of a report: what ran, what went wrong, and the verdict if known.

The exactly-once verdict needs the job: a scenario run writes it into the trace (its `verdict`
record); for a live printer's trace the caller may pass the job's G-code, which is checked
against the trace's `cmd` records as `fake-marlin verify` checks a journal.
"""

from collections import Counter
from dataclasses import dataclass, field

from fake_marlin.emulator.journal.verify import Kind, job_commands, verify
from fake_marlin.emulator.report.reader import Trace
from fake_marlin.emulator.report.series import ERROR_LINE
from fake_marlin.emulator.report.wirelog import describe

# What a byte fault's `n` counts, for "37 bits flipped".
UNITS = {"bit-errors": "bits flipped", "drop-bytes": "bytes dropped", "corrupt-lines": "lines corrupted"}


@dataclass(frozen=True)
class ExactlyOnce:
    source: str  # where the job came from: "the scenario run" or the G-code file's name
    passed: bool  # every job command ran once, in order
    job: int  # commands in the job
    ran: int  # commands the printer executed
    missing: tuple[str, ...]
    duplicated: tuple[str, ...]
    reordered: int = 0
    text: str = ""  # the verdict in full, as the tool that made it prints it
    scenario_passed: bool | None = None  # a scenario's own verdict (all its checks)
    outcome: str | None = None  # a scenario run's: completed, failed (the host gave up), stuck


@dataclass(frozen=True)
class FaultCount:
    kind: str
    fired: int
    detail: str  # "37 bits flipped", "to-printer 3, to-host 1", or ""


@dataclass
class Summary:
    title: str
    facts: list[tuple[str, str]]  # (what, value) about the run: protocol, seed, durations...
    commands: int
    bytes_in: int
    bytes_out: int
    resends: int  # the printer's rejects: each asked for a resend
    resend_reasons: list[tuple[str, int]]
    errors: int  # Error:/ProtoError: lines the printer sent
    host_resends: int | None  # the host's own counts, known for scenario runs
    timeouts: int | None
    faults: list[FaultCount]
    resets: list[str]  # each reboot's reason
    connects: int
    disconnects: int
    verdict: ExactlyOnce | None
    notes: list[str] = field(default_factory=list)  # what a reader should know about the file


def summarise(trace: Trace, job: str | None = None, job_name: str = "the job") -> Summary:
    """`job`: the G-code text of the job, to judge exactly-once by when the trace has none."""
    begin, records = trace.begin, trace.records
    counts = Counter(record["k"] for record in records)
    commands = [record["c"] for record in records if record["k"] == "cmd"]
    reasons = Counter(str(r.get("why") or "rejected") for r in records if r["k"] == "reject")
    faults = [r for r in records if r["k"] == "fault"]
    host = (trace.verdict or {}).get("host") or {}
    stop = float(records[-1]["t"]) if records else float(begin["t"])
    facts = [
        ("protocol", str(begin.get("protocol", "?"))),
        ("printer", str(begin.get("printer", 1))),
        ("seed", str(begin.get("seed"))),
        ("speed", f"{begin.get('speed', 1)}x"),
        ("simulated time", duration(stop - float(begin["t"]))),
    ]
    if trace.end is not None and isinstance(trace.end.get("w"), (int, float)):
        facts.append(("wall time", f"{trace.end['w']:.2f} s"))
    notes = []
    if trace.cut_short is not None:
        notes.append(f"The trace stops short, and what came before is shown: {trace.cut_short}.")
    elif trace.end is None:
        notes.append("The trace has no end record: the printer stopped before writing it.")
    if trace.skipped:
        kinds = ", ".join(f"{count} {kind!r}" for kind, count in sorted(trace.skipped.items()))
        notes.append(f"Records of kinds this version does not know were skipped: {kinds}.")
    end = trace.end or {}
    return Summary(
        title=str(begin.get("scenario") or trace.name),
        facts=facts,
        commands=len(commands),
        bytes_in=_count(end.get("bytes_in"), records, "in"),
        bytes_out=_count(end.get("bytes_out"), records, "out"),
        resends=counts["reject"],
        resend_reasons=reasons.most_common(),
        errors=_error_lines(records),
        host_resends=host.get("resends") if isinstance(host.get("resends"), int) else None,
        timeouts=host.get("timeouts") if isinstance(host.get("timeouts"), int) else None,
        faults=_faults(faults),
        resets=[describe(r) for r in records if r["k"] == "reset"],
        connects=counts["connect"],
        disconnects=counts["disconnect"],
        verdict=_verdict(trace, commands, job, job_name),
        notes=notes,
    )


def duration(seconds: float) -> str:
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, second = divmod(round(seconds), 60)
    hours, minute = divmod(minutes, 60)
    return f"{hours}:{minute:02d}:{second:02d}" if hours else f"{minute}:{second:02d} min"


def _count(stated: object, records: list[dict], kind: str) -> int:
    if isinstance(stated, int):
        return stated
    return sum(len(r["b"]) for r in records if r["k"] == kind)


def _error_lines(records: list[dict]) -> int:
    text = "".join(r["b"] if r["k"] == "out" else "\n" for r in records if r["k"] in ("out", "reset"))
    return sum(bool(ERROR_LINE.match(line.strip())) for line in text.split("\n"))


def _faults(faults: list[dict]) -> list[FaultCount]:
    kinds: dict[str, list[dict]] = {}
    for fault in faults:
        kinds.setdefault(fault["f"], []).append(fault)
    found = []
    for kind, fired in kinds.items():
        detail = ""
        sizes = [f["n"] for f in fired if isinstance(f.get("n"), int)]
        if sizes:
            detail = f"{sum(sizes)} {UNITS.get(kind, 'in all')}"
        directions = Counter(str(f["dir"]) for f in fired if f.get("dir"))
        if len(directions) > 1:
            split = ", ".join(f"{d} {n}" for d, n in sorted(directions.items()))
            detail = f"{detail} ({split})" if detail else split
        found.append(FaultCount(kind, len(fired), detail))
    return found


def _verdict(trace: Trace, commands: list[str], job: str | None, job_name: str) -> ExactlyOnce | None:
    if job is not None:
        result = verify(job_commands(job), commands)
        return ExactlyOnce(
            source=job_name, passed=result.passed(), job=result.job_commands, ran=len(commands),
            missing=tuple(p.command for p in result.problems if p.kind is Kind.MISSING),
            duplicated=tuple(p.command for p in result.problems if p.kind is Kind.DUPLICATED),
            reordered=result.count(Kind.REORDERED),
        )
    record = trace.verdict
    if record is None or not isinstance(record.get("job"), int):
        return None
    missing = tuple(str(c) for c in record.get("missing") or ())
    duplicated = tuple(str(c) for c in record.get("duplicated") or ())
    return ExactlyOnce(
        source="the scenario run", job=record["job"],
        passed=bool(record.get("exactly_once", not missing and not duplicated)),
        ran=int(record.get("ran") or 0), missing=missing, duplicated=duplicated,
        text=str(record.get("text") or ""), scenario_passed=bool(record["passed"]),
        outcome=str(record["outcome"]) if record.get("outcome") else None,
    )
