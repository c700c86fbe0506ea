"""The firmware x host matrix: real hosts print a short job to every shipped firmware, with each
quirk on in turn, and each printer's journal says whether the job ran exactly once.

    python -m tests.hosts.matrix [--firmware NAME ...] [--quirk NAME ...]
                                 [--hosts octoprint,printcore] [--jobs 2] [--markdown] [--save DIR]

A cell is one firmware, one row (no quirk, or one quirk with a value that bites within the
job) and one host: a `fake-marlin --firmware F --quirk Q --speed 20` process of its own (its
pty and journal: fake_marlin.testing.start_printer), and the host printing JOB_LINES commands
to it. OctoPrint's cells go through as few driver processes as --jobs allows
(octoprint_driver.py --serve: OctoPrint's start-up costs seconds), a fresh MachineCom per cell;
printcore's cells each run printcore_driver.py, on the firmwares whose profile speaks Marlin's
ASCII protocol. Each journal is verified against the job (emulator/journal/verify.py: the host's
own M110, M105 ... are extras, not problems). A cell says "exactly once", or what went wrong:
commands missing or run twice, the host's error, a hang its own timeout (HOST_TIMEOUT) or ours
(CELL_LIMIT) cut, and the time. A row that means nothing for a firmware is "n/a", with why.

The firmwares come from `shipped()` at run time, the quirks from emulator/firmware/quirks.py:
a quirk added there gets a row (its non-default value) without a change here. A quirk a host
does not survive is a finding for docs/firmwares.md, not a failure of this program: it exits 0
whatever the hosts did, and 1 only if a cell could not be run (a printer that would not start or
crashed, a driver without a report).
"""

import argparse
import datetime
import json
import os
import queue
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from fake_marlin.emulator.firmware import Profile, load_profile, shipped
from fake_marlin.emulator.firmware.quirks import NAMES, Quirks
from fake_marlin.emulator.journal.verify import FAILURES, Kind, Verification, verify
from fake_marlin.testing import PrinterCrashed, start_printer
from tests.hosts import venvs

DRIVERS = Path(__file__).parent
EMULATOR = shlex.split(os.environ.get("FAKE_MARLIN_EMULATOR", "")) or [
    str(Path(sys.executable).parent / "fake-marlin")]
JOB_LINES = 60
SPEED = 20.0
# A host's own limit per cell: OctoPrint waits 30 s for a lost `ok` before it polls (3 s once it
# has seen `busy:`), so a cell that loses one or two still ends within it.
HOST_TIMEOUT = 80.0
CELL_LIMIT = 90.0  # ours: a driver that has not answered by then is killed, the cell a hang
SETUP_LIMIT = 60.0  # for OctoPrint's import and settings, before its first cell
# The resend quirks bite only when the printer asks for a line again: the 30th numbered line
# reaches it with noise in front, `N9N30 G1 ...*51`, whose line number (9) is not the next one,
# so it draws `Resend: 30` (Smoothieware's `rs N30`) at once, whatever the checksum rules. (A line
# lost whole draws nothing until the host writes another: printcore never does.)
BAD_LINE = {"kind": "garbage", "direction": "to-printer", "pattern": r"^N30 ", "times": 1,
            "text": "N9"}
# The quirks that change the line protocol, which fake-marlin models in its Marlin protocol's
# session (sessions/marlin.py) only; the Repetier session takes busy_interval alone.
LINE_QUIRKS = frozenset({"ok_before_output", "extra_ok_after_resend", "resend_without_ok",
                         "drop_ok_every", "broken_m29", "unchecked_line_numbers", "no_m112"})
RESEND_QUIRKS = frozenset({"extra_ok_after_resend", "resend_without_ok"})
# Values that bite within the job (the rest: the opposite of the default, bool quirks' True).
VALUES: dict[str, object] = {"drop_ok_every": 40, "busy_interval": 0.5, "password": "1234",
                             "locked": True}
# What a streamed print never sends, so the quirk's row only shows the host connects and prints.
NOT_EXERCISED = {
    "no_m112": "the job sends no M112",
    "broken_m29": "a streamed print sends no M28/M29",
    "eeprom": "the job sends no M500-M503",
    "unchecked_line_numbers": "no line of the job is bad",
}


# -- the rows ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Variant:
    """A row of the matrix: the quirks on (none, one, or password with locked) and the faults
    that make them bite."""

    name: str  # what the row and --quirk call it
    quirks: Mapping[str, object] = field(default_factory=dict)
    faults: tuple[Mapping[str, object], ...] = ()
    not_exercised: str = ""  # why a streamed print does not exercise the quirk, if it does not

    def __hash__(self) -> int:  # (the quirks are a dict) the name says the row
        return hash(self.name)

    @property
    def label(self) -> str:
        label = self.name
        if self.faults and self.quirks:
            label += " + a bad line"
        return label + (" †" if self.not_exercised else "")

    def matches(self, wanted: str) -> bool:
        return wanted in (self.name, self.name.split("=")[0], *self.quirks)


def _spelled(value: object) -> str:
    return json.dumps(value) if isinstance(value, bool) else str(value)


def variants() -> list[Variant]:
    """Every row: none, the bad line alone (the control of the resend quirks' rows), and each
    quirk alone (password and locked together: a lock needs its password)."""
    defaults = Quirks()
    rows = [Variant("none"), Variant("bad_line", faults=(BAD_LINE,))]
    for name in NAMES:
        if name == "locked":
            continue
        if name == "password":
            quirks = {"password": VALUES["password"], "locked": VALUES["locked"]}
            rows.append(Variant("password=1234+locked=true", quirks))
            continue
        default = getattr(defaults, name)
        value = VALUES.get(name, not default if isinstance(default, bool) else default)
        label = name if value is True else f"{name}={_spelled(value)}"
        faults = (BAD_LINE,) if name in RESEND_QUIRKS else ()
        rows.append(Variant(label, {name: value}, faults, NOT_EXERCISED.get(name, "")))
    return rows


# -- the hosts ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Host:
    name: str
    label: str
    venv: venvs.Host
    protocols: tuple[str, ...]  # the fake-marlin protocols it speaks, the preferred first


OCTOPRINT = Host("octoprint", "OctoPrint 1.11", venvs.OCTOPRINT, ("marlin", "repetier"))
PRINTCORE = Host("printcore", "Printrun 2.2.0 (printcore)", venvs.PRINTRUN, ("marlin",))
HOSTS = {host.name: host for host in (OCTOPRINT, PRINTCORE)}


def protocol_for(host: Host, profile: Profile) -> str | None:
    """The protocol the host talks to this firmware in, or None if the firmware speaks none of
    its protocols (printcore: the ASCII firmwares, those whose profile speaks `marlin`)."""
    return next((protocol for protocol in host.protocols if protocol in profile.protocols), None)


def not_applicable(host: Host, profile: Profile, variant: Variant) -> str | None:
    """Why the row means nothing for this firmware and host ("n/a (...)"), or None."""
    protocol = protocol_for(host, profile)
    if protocol is None:
        return (f"n/a ({host.name} speaks {' or '.join(host.protocols)}; "
                f"{profile.name} speaks {', '.join(profile.protocols)})")
    quirks = set(variant.quirks)
    if protocol != "marlin" and quirks & LINE_QUIRKS:
        return f"n/a (fake-marlin's {protocol} protocol does not model it)"
    rules = profile.lines
    if "unchecked_line_numbers" in quirks and not rules.sequence and rules.checksum == "ignored":
        return "n/a (already)"
    if variant.faults and not (rules.sequence and rules.bad_line == "resend"):
        return "n/a (never asks for a line again)"
    if "busy_interval" in quirks and not any(profile.templates.get("busy_processing", ())):
        return "n/a (says no busy: at all)"
    if quirks & {"password", "locked"} and "M511" in profile.unsupported:
        return "n/a (no M511: no PASSWORD_FEATURE)"
    if quirks & {"password", "locked"} and not any(profile.templates.get("printer_locked", ())):
        return "n/a (no words for a lock: no PASSWORD_FEATURE)"
    if "eeprom" in quirks and "EEPROM" not in dict(profile.capabilities) and (
            "M500" in profile.unsupported):
        return "n/a (no EEPROM)"
    return None


# -- the job -----------------------------------------------------------------------------------
def write_job(path: Path, count: int = JOB_LINES) -> list[str]:
    """A job of `count` commands with a slicer's comments and blank lines; returns the commands.
    (No `( )` comments: which firmwares strip those is not this matrix's question.)"""
    lines = ["; generated by tests/hosts/matrix.py", "", "G28 ; home", "M104 S200", "M140 S60",
             "G92 E0", "G1 Z0.3 F600", "M106 S127"]
    moves = count - 8
    for n in range(moves):
        lines.append(f"G1 X{10 + n % 40}.{n % 10} Y{10 + n % 23}.5 E{n / 50:.3f} F3000")
        if n == moves // 2:
            lines.append("")
    lines += ["M107 ; fan off", "M400"]
    path.write_text("\n".join(lines) + "\n")
    commands = [line.split(";")[0].strip() for line in lines]
    return [command for command in commands if command]


# -- one cell ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Cell:
    firmware: str
    variant: Variant
    host: str

    def __str__(self) -> str:
        return f"{self.host} x {self.firmware} x {self.variant.name}"


@dataclass
class Result:
    cell: Cell
    na: str | None = None
    report: dict = field(default_factory=dict)  # the driver's
    journal: list[str] = field(default_factory=list)
    verification: Verification | None = None
    seconds: float = 0.0
    killed: bool = False  # no report within CELL_LIMIT: we ended the driver
    trouble: str = ""  # the cell could not be run: the printer or the driver failed

    @property
    def hang(self) -> bool:
        """Cut by a timeout, the host's own or ours."""
        return self.killed or bool(self.report.get("timed_out") or self.report.get("stuck_on"))

    @property
    def host_errors(self) -> list[str]:
        """The host's errors, but for the timeout that a hang already says."""
        return [error for error in self.report.get("errors", [])
                if "before the timeout" not in error]

    @property
    def host_done(self) -> bool:
        """The host says it printed the job (printcore says so by no error and no hang)."""
        if "done" in self.report:
            return bool(self.report["done"])
        return bool(self.report) and not self.report.get("errors")

    @property
    def exactly_once(self) -> bool:
        return self.verification is not None and self.verification.passed()

    @property
    def ok(self) -> bool:
        return (self.na is None and not self.trouble and self.exactly_once and self.host_done
                and not self.host_errors and not self.hang)

    def counts(self) -> dict[str, int]:
        if self.verification is None:
            return {}
        return {kind.value: n for kind in FAILURES if (n := self.verification.count(kind))}

    def never_bit(self) -> str:
        """Why the quirk (or the bad line) did not happen on the wire, if it did not: a cell
        that passes then says nothing of the host."""
        wire = self.report.get("wire", [])
        if not wire or self.na:
            return ""
        variant = self.cell.variant
        received = [line[2:] for line in wire if line.startswith("< ")]
        if variant.faults and not any(line.lower().startswith(("resend", "rs ")) for line in received):
            return "no line was asked for again"
        if "drop_ok_every" in variant.quirks:
            # From the job's start (OctoPrint's last `M110 N0`, printcore's first `M110 N-1`),
            # every line written gets an `ok` but the dropped ones.
            starts = [i for i, line in enumerate(wire) if line.startswith("> ")
                      and ("M110 N0" in line or "M110 N-1" in line)]
            if starts:
                start = starts[-1] if self.cell.host == "octoprint" else starts[0]
                job = wire[start:]
                sent = sum(line.startswith("> ") for line in job)
                oks = sum(line.startswith("< ok") for line in job)
                if oks >= sent:
                    return f"no ok went missing ({oks} for {sent} lines)"
        if "busy_interval" in variant.quirks and not any("busy" in line for line in received):
            return "no busy: line came"
        return ""

    def text(self) -> str:
        """The cell: `exactly once, 0.5 s`, or what went wrong."""
        if self.na:
            return self.na
        took = f"{self.seconds:.1f} s"
        if self.ok:
            never = self.never_bit()
            return f"exactly once (never bit: {never}), {took}" if never else f"exactly once, {took}"
        parts = []
        if self.trouble:
            parts.append(f"not run: {shorten(self.trouble, 60)}")
        if self.hang:
            limit = CELL_LIMIT if self.killed else HOST_TIMEOUT
            parts.append(f"hang, cut at {limit:.0f} s")
        elif self.host_errors:
            parts.append(f"host error: {shorten(self.host_errors[0], 70)}")
        elif not self.host_done and not self.trouble:
            parts.append("host did not finish")
        elif self.host_done and not self.exactly_once:
            parts.append("host says done")
        if self.verification is not None:
            if self.exactly_once:
                parts.append("the job ran exactly once")
            else:
                jobs = self.verification.job_commands
                parts += [f"{n} of {jobs} {kind}" for kind, n in self.counts().items()]
        return ", ".join(parts) + f", {took}"

    def details(self) -> list[str]:
        """What went wrong, for the findings: errors, problems, the wire around them."""
        lines = [f"host error: {error}" for error in self.host_errors[:3]]
        if self.trouble:
            lines.append(f"not run: {self.trouble}")
        if self.report.get("stuck_on"):
            lines.append(f"stuck on: {self.report['stuck_on']}")
        lines += [f"host warning: {first_line(w)}" for w in self.report.get("warnings", [])
                  if "Profile _default does not exist" not in w][:3]
        lines += [f"host note: {first_line(note)}" for note in self.report.get("notes", [])
                  if not note.startswith(("Printer reports firmware name", "Detected "))][:4]
        if self.report and "firmware_name" in self.report:
            lines.append(f"firmware name read: {self.report['firmware_name']!r}")
        problems = self.verification.failures() if self.verification else ()
        for problem in problems[:4]:
            where = f"job line {problem.job_line}" if problem.job_line else "extra"
            lines.append(f"{problem.kind.value}: {where} `{problem.command}`")
        if len(problems) > 4:
            lines.append(f"... and {len(problems) - 4} more")
        wire = self.report.get("wire", [])
        if wire:
            lines.append("wire (> host to printer, < printer to host):")
            lines += ["    " + line for line in wire_excerpt(wire, problems, self.hang)]
        return lines


def first_line(text: str) -> str:
    return text.splitlines()[0] if text else text


def shorten(text: str, width: int) -> str:
    text = first_line(text)
    return text if len(text) <= width else text[:width - 1] + "…"


def wire_excerpt(wire: Sequence[str], problems: Sequence, hang: bool, around: int = 6) -> list[str]:
    """The lines that show what happened: where the first command that went wrong was sent,
    or, for a hang (or nothing to look for), the last lines."""
    quiet = ("< ok T:", "<  T:", "< T:", "< Not SD printing", "< X:", "< echo:busy")
    for problem in problems[:1]:
        sent = [i for i, line in enumerate(wire)
                if line.startswith("> ") and problem.command in line]
        if sent and not hang:
            at = sent[min(1, len(sent) - 1)] if problem.kind is Kind.DUPLICATED else sent[0]
            return list(wire[max(0, at - around):at + around + 1])
    tail = [line for line in wire if not line.startswith(quiet)]
    return tail[-2 * around:]


class DriverError(RuntimeError):
    """A host's driver would not start."""


# The printers and drivers of the cells running now: ended at once if the run is interrupted.
_LIVE: set[object] = set()
_LIVE_LOCK = threading.Lock()


def _track(thing: object) -> None:
    with _LIVE_LOCK:
        _LIVE.add(thing)


def _untrack(thing: object) -> None:
    with _LIVE_LOCK:
        _LIVE.discard(thing)


def end_everything() -> None:
    """Kill every driver and stop every printer still running (Ctrl-C, SIGTERM)."""
    with _LIVE_LOCK:
        things = list(_LIVE)
        _LIVE.clear()
    for thing in things:
        if isinstance(thing, subprocess.Popen):
            if thing.poll() is None:
                thing.kill()
        else:
            thing.stop(check=False)  # type: ignore[attr-defined]


class OctoPrintDriver:
    """One `octoprint_driver.py --serve` process, printing a port at a time."""

    def __init__(self, python: Path, stderr: Path) -> None:
        self._stderr = open(stderr, "ab")
        self.process = subprocess.Popen(
            [str(python), str(DRIVERS / "octoprint_driver.py"), "--serve",
             "--timeout", str(HOST_TIMEOUT)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr, text=True,
            start_new_session=True)
        _track(self.process)
        self._lines: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()
        self._requests = 0
        ready = self._next(lambda report: "ready" in report, SETUP_LIMIT)
        if ready is None:
            self.kill()
            raise DriverError(f"OctoPrint's driver did not start within {SETUP_LIMIT:.0f} s: "
                               f"{stderr.read_text(errors='replace')[-500:]}")
        self.setup_seconds = float(ready.get("setup_seconds", 0.0))

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self._lines.put(line)
        self._lines.put(None)

    def _next(self, wanted: Callable[[dict], bool], limit: float) -> dict | None:
        deadline = time.monotonic() + limit
        while True:
            try:
                line = self._lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                return None
            if line is None:  # the driver died
                self._lines.put(None)
                return None
            try:
                report = json.loads(line)
            except ValueError:
                continue
            if isinstance(report, dict) and wanted(report):
                return report

    @property
    def alive(self) -> bool:
        return self.process.poll() is None

    def print(self, port: str, gcode: Path, limit: float = CELL_LIMIT) -> dict | None:
        """The driver's report on printing `gcode` to `port`; None if it gave none within
        `limit` (it is killed then: a new driver is needed)."""
        self._requests += 1
        request = {"port": port, "gcode": str(gcode), "id": self._requests}
        assert self.process.stdin is not None
        try:
            self.process.stdin.write(json.dumps(request) + "\n")
            self.process.stdin.flush()
        except (BrokenPipeError, OSError):
            return None
        report = self._next(lambda report: report.get("id") == request["id"], limit)
        if report is None:
            self.kill()
        return report

    def close(self) -> None:
        if self.alive and self.process.stdin is not None:
            try:
                self.process.stdin.close()
            except OSError:
                pass
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                pass
        self.kill()

    def kill(self) -> None:
        if self.alive:
            self.process.kill()
        self.process.wait()
        _untrack(self.process)
        self._stderr.close()


class OctoPrint:
    """An OctoPrint driver on demand: started at the first call, again after one was killed."""

    def __init__(self, python: Path, stderr: Path) -> None:
        self.python = python
        self.stderr = stderr
        self.driver: OctoPrintDriver | None = None
        self.starts = 0

    def __call__(self) -> OctoPrintDriver:
        if self.driver is None or not self.driver.alive:
            if self.driver is not None:
                self.driver.kill()
            self.starts += 1
            self.driver = OctoPrintDriver(self.python, self.stderr)
        return self.driver

    def close(self) -> None:
        if self.driver is not None:
            self.driver.close()
            self.driver = None


def run_printcore(python: Path, port: str, gcode: Path) -> dict | None:
    """printcore_driver.py's report, or None if it gave none within CELL_LIMIT."""
    process = subprocess.Popen(
        [str(python), str(DRIVERS / "printcore_driver.py"), port, str(gcode),
         "--timeout", str(HOST_TIMEOUT)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _track(process)
    try:
        stdout, stderr = process.communicate(timeout=CELL_LIMIT)
    except subprocess.TimeoutExpired:
        process.kill()
        process.communicate()
        return None
    finally:
        _untrack(process)
    try:
        report = json.loads(stdout.strip().splitlines()[-1])  # printcore runs `stty` too
    except (IndexError, ValueError):
        return {"errors": [f"driver: exited {process.returncode} without a report: "
                           f"{stderr.strip()[-300:]}"], "driver_failed": True}
    report["exit_code"] = process.returncode
    return report


@dataclass
class Workspace:
    """Where a run keeps its job, and what each cell needs."""

    directory: Path
    commands: list[str]
    pythons: dict[str, Path]  # host name -> its venv's python

    @property
    def job(self) -> Path:
        return self.directory / "job.gcode"


def make_workspace(directory: Path, hosts: Iterable[Host]) -> Workspace:
    """The job written to `directory`; each host's python (a host without a venv is missing)."""
    commands = write_job(directory / "job.gcode")
    pythons = {}
    for host in hosts:
        venv = venvs.find(host.venv)
        if venv is not None:
            pythons[host.name] = venv.python
    return Workspace(directory, commands, pythons)


def run_cell(cell: Cell, workspace: Workspace,
             octoprint: Callable[[], OctoPrintDriver] | None = None) -> Result:
    """Print the job in one cell. `octoprint` gives the OctoPrint driver to use (a live one)."""
    profile = load_profile(cell.firmware)
    host = HOSTS[cell.host]
    reason = not_applicable(host, profile, cell.variant)
    if reason:
        return Result(cell, na=reason)
    protocol = protocol_for(host, profile)
    assert protocol is not None
    started = time.monotonic()
    try:
        printer = start_printer(
            program=EMULATOR, firmware=cell.firmware, protocol=protocol, speed=SPEED,
            quirks=dict(cell.variant.quirks), faults=[dict(f) for f in cell.variant.faults])
    except PrinterCrashed as crash:
        return Result(cell, trouble=f"the printer would not start: {crash}")
    _track(printer)
    result = Result(cell)
    try:
        if host is OCTOPRINT:
            assert octoprint is not None, "an OctoPrint cell needs a driver"
            report = octoprint().print(printer.port, workspace.job)
        else:
            report = run_printcore(workspace.pythons[host.name], printer.port, workspace.job)
        result.seconds = time.monotonic() - started
        if report is None:
            result.killed = True
        else:
            result.report = report
            result.seconds = report.get("elapsed") or result.seconds
            if report.get("driver_failed"):
                result.trouble = report["errors"][0]
    finally:
        printer.stop(check=False)
        _untrack(printer)
    if "Traceback" in printer.stderr or printer.returncode not in (0, None):
        result.trouble = (f"the printer failed (exit {printer.returncode}): "
                          f"{printer.stderr.strip()[-400:]}")
    result.journal = printer.journal
    result.verification = verify(list(enumerate(workspace.commands, 1)), result.journal)
    return result


# -- many cells --------------------------------------------------------------------------------
def cells_for(firmwares: Sequence[str], rows: Sequence[Variant], hosts: Sequence[Host]) -> list[Cell]:
    return [Cell(firmware, variant, host.name)
            for host in hosts for firmware in firmwares for variant in rows]


def expected_seconds(cell: Cell) -> float:
    """A guess, to start the slow cells first."""
    variant = cell.variant
    if "drop_ok_every" in variant.quirks:
        return 80.0 if cell.host == "printcore" else 30.0
    if variant.faults:
        return 10.0
    if "locked" in variant.quirks:
        return 6.0
    return 2.0


def run_cells(cells: Sequence[Cell], workspace: Workspace, jobs: int = 2,
              on_result: Callable[[Result], None] = lambda result: None) -> list[Result]:
    """Every cell, `jobs` at a time (each worker with an OctoPrint driver of its own, started
    at its first OctoPrint cell); the results in the order of `cells`."""
    order = sorted(range(len(cells)), key=lambda i: -expected_seconds(cells[i]))
    work: queue.Queue[int] = queue.Queue()
    for i in order:
        work.put(i)
    results: list[Result | None] = [None] * len(cells)
    lock = threading.Lock()

    def worker(number: int) -> None:
        octoprint = None
        if "octoprint" in workspace.pythons:
            octoprint = OctoPrint(workspace.pythons["octoprint"],
                                  workspace.directory / f"octoprint-{number}.stderr")
        failed_start: list[str] = []
        try:
            while True:
                try:
                    i = work.get_nowait()
                except queue.Empty:
                    return
                cell = cells[i]
                if cell.host not in workspace.pythons:
                    result = Result(cell, trouble=f"no venv: {venvs_hint(HOSTS[cell.host])}")
                elif failed_start and cell.host == "octoprint":
                    result = Result(cell, trouble=failed_start[0])
                else:
                    try:
                        result = run_cell(cell, workspace, octoprint)
                    except DriverError as error:  # OctoPrint's driver would not start
                        failed_start.append(str(error))
                        result = Result(cell, trouble=str(error))
                    except Exception as error:  # a profile that does not load (now), a bug
                        result = Result(cell, trouble=f"{type(error).__name__}: {error}")
                with lock:
                    results[i] = result
                    on_result(result)
        finally:
            if octoprint is not None:
                octoprint.close()

    threads = [threading.Thread(target=worker, args=(n,), daemon=True) for n in range(max(1, jobs))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return [result for result in results if result is not None]


def venvs_hint(host: Host) -> str:
    from tests.hosts.install import not_installed
    return not_installed(host.venv.label)


# -- output ------------------------------------------------------------------------------------
def findings(results: Sequence[Result]) -> list[Result]:
    return [result for result in results if result.na is None and not result.ok]


def markdown(results: Sequence[Result], firmwares: Sequence[str], rows: Sequence[Variant],
             hosts: Sequence[Host]) -> str:
    """A table per host (rows: the quirks; columns: the firmwares), then the findings."""
    found = findings(results)
    number = {id(result): n for n, result in enumerate(found, 1)}
    by_cell = {(r.cell.host, r.cell.firmware, r.cell.variant.name): r for r in results}
    out = []
    for host in hosts:
        out += [f"### {host.label}", "",
                "| quirk | " + " | ".join(firmwares) + " |",
                "| --- |" + " --- |" * len(firmwares)]
        for variant in rows:
            cells = []
            for firmware in firmwares:
                result = by_cell.get((host.name, firmware, variant.name))
                if result is None:
                    cells.append("")
                    continue
                text = result.text()
                if id(result) in number:
                    text += f" [{number[id(result)]}]"
                cells.append(text.replace("|", "\\|"))
            out.append(f"| {variant.label} | " + " | ".join(cells) + " |")
        out.append("")
    notes = [f"`{v.label}`: {v.not_exercised}" for v in rows if v.not_exercised]
    if notes:
        out += ["† The quirk is on, but the job never exercises it (" + "; ".join(notes) +
                "): the row shows the host still connects and prints.", ""]
    if any(variant.faults for variant in rows):
        out += ["`+ a bad line`: the 30th numbered line reaches the printer as `N9N30 ...` (a "
                f"fault: `{json.dumps(BAD_LINE)}`), so it asks for it again; the `bad_line` row "
                "is that alone, without a quirk.", ""]
    if found:
        out += ["### Findings", ""]
        for result in found:
            out.append(f"{number[id(result)]}. **{result.cell}**: {result.text()}")
            out += ["   " + line if not line.startswith("    ") else "       " + line.strip()
                    for line in result.details()]
            out.append("")
    return "\n".join(out)


def plain(results: Sequence[Result]) -> str:
    out = []
    width = max((len(str(result.cell)) for result in results), default=0)
    for result in results:
        out.append(f"{str(result.cell):<{width}}  {result.text()}")
    found = findings(results)
    if found:
        out += ["", "Findings:"]
        for result in found:
            out.append(f"- {result.cell}: {result.text()}")
            out += ["    " + line for line in result.details()]
    return "\n".join(out)


def save(results: Sequence[Result], directory: Path) -> None:
    """Each cell's driver report and journal, as files named after it."""
    directory.mkdir(parents=True, exist_ok=True)
    for result in results:
        if result.na:
            continue
        name = f"{result.cell.host}--{result.cell.firmware}--{result.cell.variant.name}"
        name = "".join(c if c.isalnum() or c in "-_.=+" else "_" for c in name)
        summary = {"cell": str(result.cell), "text": result.text(), "details": result.details(),
                   "counts": result.counts(), "report": result.report}
        (directory / f"{name}.json").write_text(json.dumps(summary, indent=1))
        (directory / f"{name}.journal").write_text("\n".join(result.journal) + "\n")


def _interrupted(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.hosts.matrix", description=__doc__.split("\n\n")[0])
    parser.add_argument("--firmware", action="append", metavar="NAME",
                        help="a shipped firmware (repeatable; default: every one)")
    parser.add_argument("--quirk", action="append", metavar="NAME",
                        help="a row: none, bad_line, or a quirk's name (repeatable; default: all)")
    parser.add_argument("--hosts", default="octoprint,printcore",
                        help="comma-separated: octoprint, printcore (default: both)")
    parser.add_argument("--jobs", type=int, default=2, help="cells at a time (default 2)")
    parser.add_argument("--markdown", action="store_true", help="print Markdown tables")
    parser.add_argument("--save", type=Path, metavar="DIR",
                        help="keep each cell's driver report and journal in DIR")
    args = parser.parse_args(argv)
    available = shipped()
    firmwares = args.firmware or available
    unknown = [name for name in firmwares if name not in available]
    if unknown:
        parser.error(f"not shipped: {', '.join(unknown)} (shipped: {', '.join(available)})")
    rows = variants()
    if args.quirk:
        wanted = [name.strip() for name in args.quirk]
        missing = [name for name in wanted if not any(v.matches(name) for v in rows)]
        if missing:
            parser.error(f"no row {', '.join(missing)}: one of {', '.join(v.name for v in rows)}")
        rows = [v for v in rows if any(v.matches(name) for name in wanted)]
    try:
        hosts = [HOSTS[name.strip()] for name in args.hosts.split(",") if name.strip()]
    except KeyError as error:
        parser.error(f"no host {error.args[0]!r}: {', '.join(HOSTS)}")
    started = time.monotonic()
    directory = Path(tempfile.mkdtemp(prefix="fm-matrix-"))
    try:
        workspace = make_workspace(directory, hosts)
        for host in hosts:
            if host.name not in workspace.pythons:
                print(f"{host.label}: {venvs_hint(host)}", file=sys.stderr)
        cells = cells_for(firmwares, rows, hosts)
        done = [0]

        def progress(result: Result) -> None:
            done[0] += 1
            print(f"[{done[0]}/{len(cells)}] {result.cell}: {result.text()}", file=sys.stderr,
                  flush=True)

        signal.signal(signal.SIGTERM, _interrupted)
        try:
            results = run_cells(cells, workspace, args.jobs, progress)
        except KeyboardInterrupt:
            end_everything()
            print("interrupted: every printer and driver of the run ended", file=sys.stderr)
            return 130
    finally:
        shutil.rmtree(directory, ignore_errors=True)
    if args.save:
        save(results, args.save)
    elapsed = time.monotonic() - started
    if args.markdown:
        command = "python -m tests.hosts.matrix " + " ".join(
            shlex.quote(arg) for arg in (argv if argv is not None else sys.argv[1:]))
        print(f"Run {datetime.date.today().isoformat()} ({elapsed / 60:.1f} min, --jobs "
              f"{args.jobs}): `{command.strip()}`; firmwares shipped: {', '.join(available)}.\n")
        print(markdown(results, firmwares, rows, hosts))
    else:
        print(plain(results))
        print(f"\n{len(results)} cells in {elapsed:.0f} s", file=sys.stderr)
    return 1 if any(result.trouble for result in results) else 0


if __name__ == "__main__":
    sys.exit(main())
