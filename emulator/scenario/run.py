"""Run a scenario: the printer and our host client in one process, on simulated time.

Both sides share trio's clock, here a MockClock that jumps ahead whenever everything waits,
so a scenario full of timeouts runs in moments, yet every delay is honoured in order.

A run is a pure function of its file. Nothing reads the wall clock; every fault decision
comes from a generator of its own, seeded from the scenario; and trio's scheduler, which on
purpose runs tasks that are ready at the same instant in a random order (and breaks ties
between equal deadlines by object address), is pinned to a seeded order for the run, as
pytest-trio and hypothesis pin it. The digest of the wire transcript (every chunk each way,
with its simulated time) proves it: the same file gives the same digest on every run.
"""

import hashlib
import io
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import trio
import trio.testing

from fake_marlin.emulator.journal.verify import FAILURES, Kind, describe_damage, verify
from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.link.memory import HostEnd, MemoryLink
from fake_marlin.emulator.printer.model import Printer, PrinterConfig
from fake_marlin.emulator.scenario.definition import Scenario
from fake_marlin.emulator.server.lifecycle import PrinterServer
from fake_marlin.emulator.trace.writer import Trace
from fake_marlin.host.connect import connect
from fake_marlin.host.errors import ConnectionLost, HostError
from fake_marlin.host.shell import ClientOptions, PrintSummary, StreamingClient, sole_exception

# A scenario that has not finished after a simulated day is stuck, whatever it does.
SIMULATED_TIME_LIMIT = 24 * 3600.0
FINISHING = 10.0  # simulated seconds the printer runs on after the host is done


@dataclass(frozen=True)
class Check:
    name: str
    passed: bool
    detail: str = ""


@dataclass
class ScenarioResult:
    scenario: Scenario
    outcome: str = "completed"  # completed | failed | stuck
    error: str | None = None  # "ErrorClass: message" when the host gave up
    summary: PrintSummary | None = None
    journal: list[str] = field(default_factory=list)
    transcript: list[str] = field(default_factory=list)  # what the printer said, line by line
    printer_halted: bool = False
    boots: int = 0
    simulated_seconds: float = 0.0
    checks: list[Check] = field(default_factory=list)
    digest: str = ""  # of the wire transcript: the same file gives the same digest

    @property
    def passed(self) -> bool:
        return all(check.passed for check in self.checks)


class _Wire:
    """Everything that crossed the line, as the host saw it: what the printer sent, and a
    running digest of every chunk each way with the simulated moment it crossed."""

    def __init__(self) -> None:
        self.received = bytearray()
        self._digest = hashlib.sha256()

    def record(self, direction: bytes, data: bytes) -> None:
        self._digest.update(b"%s %r %d:" % (direction, trio.current_time(), len(data)) + data)

    def digest(self) -> str:
        return self._digest.hexdigest()


class _Recorder:
    """The host's stream, keeping a record of the wire (one record across reconnections)."""

    def __init__(self, stream: HostEnd, wire: _Wire) -> None:
        self._stream = stream
        self.wire = wire

    async def send_all(self, data: bytes) -> None:
        self.wire.record(b">", data)
        await self._stream.send_all(data)

    async def receive_some(self, max_bytes: int | None = 4096) -> bytes:
        data = await self._stream.receive_some(max_bytes or 4096)
        self.wire.record(b"<", data)
        self.wire.received += data
        return data


@contextmanager
def pinned_scheduler(seed: int) -> Iterator[None]:
    """Trio's scheduler in a seeded order for the length of the block (see the module's
    docstring): what pytest-trio and hypothesis do, through the same private switch."""
    run = trio._core._run
    saved = run._ALLOW_DETERMINISTIC_SCHEDULING, run._r.getstate()
    run._ALLOW_DETERMINISTIC_SCHEDULING = True  # type: ignore[misc]
    run._r.seed(f"fake-marlin scheduler {seed}")
    try:
        yield
    finally:
        run._ALLOW_DETERMINISTIC_SCHEDULING = saved[0]  # type: ignore[misc]
        run._r.setstate(saved[1])


def run_scenario(scenario: Scenario, trace_path: str | None = None) -> ScenarioResult:
    """Run the scenario; with `trace_path`, write its wire trace there (docs/trace.md), which
    changes nothing in the run: the same digest, traced or not."""
    clock = trio.testing.MockClock(autojump_threshold=0)
    # The printer has an SD card, as `fake-marlin` gives it one: an empty temporary directory.
    with tempfile.TemporaryDirectory(prefix="fake-marlin-sd-") as sd_dir, pinned_scheduler(
        scenario.faults.seed
    ):
        trace = None
        if trace_path:
            trace = Trace.open(trace_path, scenario.printer.protocol, speed=1.0,
                               seed=scenario.faults.seed, scenario=scenario.name)
        try:
            return trio.run(_run, scenario, Path(sd_dir), trace, clock=clock)
        finally:
            if trace is not None:
                trace.close()


async def _run(scenario: Scenario, sd_dir: Path, trace: Trace | None = None) -> ScenarioResult:
    result = ScenarioResult(scenario)
    setup = scenario.printer
    firmware = setup.make_firmware(seed=scenario.faults.seed)
    printer = Printer(firmware.printer_config(setup.extruders, sd_dir))
    journal_text = io.StringIO()
    link = MemoryLink()
    server = PrinterServer(link, printer, Journal(journal_text), setup.server_config(scenario.faults),
                           trace=trace, firmware=firmware)
    options = ClientOptions(
        window=scenario.host.window, timeout=scenario.host.timeout,
        max_transmissions=scenario.host.retries, variants=scenario.host_variants,
    )
    start = trio.current_time()
    async with trio.open_nursery() as nursery:
        await nursery.start(server.run)
        wire = _Wire()
        stream = _Recorder(link.open_host(), wire)
        with trio.move_on_after(SIMULATED_TIME_LIMIT) as limit:
            try:
                job = list(scenario.job)
                if scenario.host.disconnect_after is not None:
                    job = await _print_until_disconnect(
                        stream, scenario, options, job, scenario.host.disconnect_after
                    )
                    stream = _Recorder(link.open_host(), wire)
                result.summary = await _print_reconnecting(link, stream, scenario, options, job)
                # What the printer was sent it runs even once the host is done: a host misled
                # by a repeated ok may finish before the last command has run.
                await trio.sleep(FINISHING)
            except BaseException as raised:  # noqa: BLE001 - the host's failure is the result
                error = sole_exception(raised)
                if not isinstance(error, HostError):
                    raise
                result.outcome = "failed"
                result.error = f"{type(error).__name__}: {error}"
        if limit.cancelled_caught:
            result.outcome = "stuck"
        nursery.cancel_scope.cancel()
    result.simulated_seconds = trio.current_time() - start
    result.journal = journal_text.getvalue().splitlines()
    result.transcript = wire.received.decode("latin-1").replace("\r", "").split("\n")
    result.digest = wire.digest()
    result.printer_halted = printer.halted
    result.boots = server.boots
    result.checks = _check(scenario, result)
    if trace is not None:
        trace.verdict(_verdict_facts(result))
    return result


def _verdict_facts(result: ScenarioResult) -> dict[str, object]:
    """The run's verdict for the trace's `verdict` record."""
    verdict = verify(list(enumerate(result.scenario.job, start=1)), result.journal)
    summary = result.summary
    return {
        "passed": result.passed,
        "outcome": result.outcome,
        "job": len(result.scenario.job),
        "ran": len(result.journal),
        "exactly_once": verdict.passed(),
        "missing": [p.command for p in verdict.problems if p.kind is Kind.MISSING],
        "duplicated": [p.command for p in verdict.problems if p.kind is Kind.DUPLICATED],
        "host": {"resends": summary.resends if summary else None,
                 "timeouts": summary.timeouts if summary else None},
        "text": report(result),
    }


async def _print_reconnecting(link, stream, scenario: Scenario, options, job: list[str]):
    """Print the job; when the line hangs up and the scenario says so, wait, reopen the port and
    send again everything not acknowledged (the host cannot know what else ran)."""
    while True:
        host = None
        try:
            async with connect(stream, scenario.host_protocol, options) as host:
                return await host.print_commands(job)
        except BaseException as raised:  # noqa: BLE001 - only a lost line is retried
            if scenario.host.reconnect_after is None or not isinstance(sole_exception(raised), ConnectionLost):
                raise
        job = job[host.known_run if isinstance(host, StreamingClient) else 0:]
        await trio.sleep(scenario.host.reconnect_after)
        while not link.connected:
            await trio.sleep(0.1)
        stream = _Recorder(link.open_host(), stream.wire)


async def _print_until_disconnect(stream, scenario: Scenario, options, job: list[str], after: int):
    """Print until `after` commands are acknowledged, then drop the port with packets still in
    flight, as a host that crashes or loses its cable does. Returns what it must still send:
    everything not known to have run, since it cannot know what else the printer ran."""
    async with connect(stream, scenario.host_protocol, options) as host:
        # Scenarios that drop the port mid-print are for the streaming protocols (the loader
        # refuses a reconnect for CommStack, which uploads its job whole).
        assert isinstance(host, StreamingClient)
        for command in job:
            await host.submit(command)
            if host.completed >= after:
                break
        with trio.move_on_after(60):
            while host.completed < after:
                await trio.sleep(0.01)
        done = host.known_run
    return job[done:]


def _check(scenario: Scenario, result: ScenarioResult) -> list[Check]:
    expect = scenario.expect
    checks = []
    if expect.outcome is not None:
        checks.append(Check(f"outcome is {expect.outcome}", result.outcome == expect.outcome,
                            result.error or result.outcome))
    if expect.error is not None:
        checks.append(Check(f"the host reports {expect.error}",
                            result.error is not None and result.error.startswith(expect.error + ":"),
                            result.error or "no error"))
    if expect.exactly_once is not None:
        verdict = verify(list(enumerate(scenario.job, start=1)), result.journal)
        counts = ", ".join(
            f"{verdict.count(kind)} {kind.value}" for kind in FAILURES
            if kind is not Kind.DAMAGED or verdict.count(kind)
        )
        extras = [p.command for p in verdict.problems if p.kind is Kind.EXTRA]
        damaged = [p for p in verdict.problems if p.kind is Kind.DAMAGED]
        checks.append(Check(
            "every job command ran exactly once, in order" if expect.exactly_once
            else "some job command did not run exactly once",
            verdict.passed(allow_undetectable=expect.allow_undetectable) == expect.exactly_once,
            counts
            + "".join(f"; {describe_damage(p)}" for p in damaged)
            + (f"; host's own: {', '.join(sorted(set(extras)))}" if extras else ""),
        ))
    if expect.missing is not None or expect.duplicated_at_most is not None:
        verdict = verify(list(enumerate(scenario.job, start=1)), result.journal)
        missing, duplicated = verdict.count(Kind.MISSING), verdict.count(Kind.DUPLICATED)
        if expect.missing is not None:
            checks.append(Check(f"{expect.missing} job commands never ran", missing == expect.missing, str(missing)))
        if expect.duplicated_at_most is not None:
            checks.append(Check(f"at most {expect.duplicated_at_most} job commands ran twice",
                                duplicated <= expect.duplicated_at_most, str(duplicated)))
    if expect.resends is not None:
        resends = result.summary.resends if result.summary else None
        least, most = expect.resends
        checks.append(Check(f"host resends within {least}..{most}",
                            resends is not None and least <= resends <= most, f"{resends}"))
    if expect.printer_halted is not None:
        checks.append(Check("the printer halted" if expect.printer_halted else "the printer did not halt",
                            result.printer_halted == expect.printer_halted, str(result.printer_halted)))
    for text in expect.lines_include:
        seen = any(text in line for line in result.transcript)
        checks.append(Check(f"the printer said {text!r}", seen))
    for text in expect.lines_exclude:
        said = [line for line in result.transcript if text in line]
        checks.append(Check(f"the printer never said {text!r}", not said, said[0] if said else ""))
    return checks


def report(result: ScenarioResult) -> str:
    scenario = result.scenario
    summary = result.summary
    lines = [f"{'PASS' if result.passed else 'FAIL'}  {scenario.name}  ({scenario.path})"]
    if scenario.description:
        lines.append(f"      {scenario.description}")
    lines.append(
        f"      {result.outcome}"
        + (f": {result.error}" if result.error else "")
        + f"; {len(result.journal)} commands executed of {len(scenario.job)} in the job"
        + f"; {result.simulated_seconds:.1f} s simulated; printer booted {result.boots}x"
        + f"; wire digest {result.digest[:12]}"
    )
    if summary is not None:
        lines.append(
            f"      host: {summary.packets_sent} sent, {summary.resends} resends, "
            f"{summary.timeouts} timeouts, {summary.rejects} rejects, {summary.corrupt_frames} "
            f"corrupt frames, {summary.unconfirmed} unconfirmed"
        )
    for check in result.checks:
        mark = "ok  " if check.passed else "FAIL"
        lines.append(f"      [{mark}] {check.name}" + (f": {check.detail}" if check.detail else ""))
    return "\n".join(lines)
