"""One timed run: a printer program (fake-marlin, a farm, or the bare responder) in its own
process, a host program streaming a job to it in another, and what that took.

The hosts: ours (fake_marlin.emulator.bench.stream, with this interpreter), and OctoPrint's comm
layer and printcore when their venvs exist, found where the test suite's install step (`python
-m tests.hosts.install`, tests/hosts/venvs.py) builds them; the path logic is copied, since an
installed bench has no tests/. A missing venv makes its host "not installed", never an error.
"""

import json
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from fake_marlin.emulator.bench.procs import BenchError, Proc, Processes, fake_marlin
from fake_marlin.emulator.journal.verify import job_commands, verify

START_TIMEOUT = 60.0  # seconds for a printer to print its pty path (the machine may be loaded)
RUN_TIMEOUT = 600.0  # seconds for one host run
VENV_MARKER = "fake-marlin-venv.json"  # written last by tests/hosts/venvs.py: the venv is whole


def venv_cache() -> Path:
    """Where the real hosts' venvs are cached, for the test suite's install step (which builds
    them), the tests and the bench (which use them)."""
    default = Path.home() / ".cache" / "fake-marlin" / "venvs"
    return Path(os.environ.get("FAKE_MARLIN_VENVS", default))


@dataclass(frozen=True)
class Host:
    key: str  # in the JSON
    label: str  # in the table
    # The command line streaming `job` to `port`, or None when the host is not installed.
    command: Callable[[str, Path], list[str]] | None
    missing: str = ""  # why it is not installed


def our_host(protocol: str, window: int = 0) -> Host:
    def command(port: str, job: Path) -> list[str]:
        extra = ["--window", str(window)] if window else []
        return [sys.executable, "-m", "fake_marlin.emulator.bench.stream", "--protocol",
                protocol, "--job", str(job), *extra, port]

    name = "Marlin" if protocol == "marlin" else "Ultimaker"
    return Host(f"ours-{protocol}", f"our host, {name}", command)


def _venv_host(key: str, label: str, venv: str, driver: str) -> Host:
    path = venv_cache() / venv
    python = path / "bin" / "python"
    script = Path(__file__).with_name(driver)
    if not (path / VENV_MARKER).is_file() or not python.exists():
        hint = "python -m tests.hosts.install in a checkout builds it"
        return Host(key, label, None, f"not installed (no venv {path}; {hint})")
    if not script.is_file():
        return Host(key, label, None, f"not installed (no driver {script})")
    return Host(key, label, lambda port, job: [str(python), str(script), port, str(job)])


def octoprint() -> Host:
    return _venv_host("octoprint", "OctoPrint 1.11 comm layer", "octoprint-1.11",
                      "octoprint_host.py")


def printcore() -> Host:
    return _venv_host("printcore", "printcore 2.2 (Printrun)", "printrun-2.2.0",
                      "printcore_host.py")


@dataclass(frozen=True)
class Target:
    label: str
    argv: list[str]
    env: tuple[tuple[str, str], ...] = ()  # set in its environment, beside the bench's own

    def with_env(self, label: str, **variables: str) -> "Target":
        return Target(label, self.argv, (*self.env, *variables.items()))


def printer(protocol: str, *extra: str) -> Target:
    return Target(f"fake-marlin --protocol {protocol}",
                  fake_marlin("--protocol", protocol, *extra))


BARE = Target("bare responder",
              [sys.executable, "-m", "fake_marlin.emulator.bench.responder"])
# The same responder waiting on trio, as the emulator does: the floor of any trio printer.
BARE_ON_TRIO = Target("bare responder on trio",
                      [sys.executable, "-m", "fake_marlin.emulator.bench.responder", "--trio"])


@dataclass
class Run:
    """What one host did against one printer."""

    job: int
    acknowledged: int = 0
    elapsed: float | None = None  # seconds of the job alone
    printer_cpu: float | None = None  # the printer process's CPU seconds during the run
    error: str | None = None
    summary: dict = field(default_factory=dict)  # our host's PrintSummary, where it is ours

    @property
    def complete(self) -> bool:
        return self.error is None and self.acknowledged == self.job and bool(self.elapsed)

    @property
    def rate(self) -> float | None:
        """Commands per second, only for a complete run: the bench's numbers are for those."""
        return self.job / self.elapsed if self.complete and self.elapsed else None

    def as_dict(self) -> dict:
        return {"job": self.job, "acknowledged": self.acknowledged, "complete": self.complete,
                "elapsed": self.elapsed, "cmd_per_s": self.rate, "printer_cpu_s": self.printer_cpu,
                "error": self.error, **({"summary": self.summary} if self.summary else {})}


def start_printer(procs: Processes, target: Target, lines: int = 1) -> tuple[Proc, list[str]]:
    env = {**os.environ, **dict(target.env)} if target.env else None
    proc = procs.start(target.label.split()[0], target.argv, env)
    try:
        return proc, proc.read_lines(lines, START_TIMEOUT)
    except BaseException:
        procs.stop(proc)
        raise


def start_host(procs: Processes, host: Host, ports: list[str], job_path: Path) -> Proc:
    """Start `host` streaming the job (to several ports at once: ours only)."""
    assert host.command is not None
    argv = host.command(ports[0], job_path)
    return procs.start(host.key, [*argv, *ports[1:]])


def collect(procs: Processes, proc: Proc, host: Host, job_length: int) -> list[Run]:
    """Wait for a host started by start_host; one Run per port."""
    try:
        report = proc.wait_json(RUN_TIMEOUT)
    finally:
        procs.stop(proc)
    if host.key.startswith("ours-"):
        runs = []
        for client in report.get("clients", []):
            run = Run(job_length, int(client.get("commands", 0)), client.get("elapsed"),
                      error=client.get("error"))
            run.summary = {k: v for k, v in client.items() if k not in ("port", "error")}
            runs.append(run)
        return runs
    errors = report.get("errors") or []
    return [Run(job_length, int(report.get("acknowledged", 0)), report.get("elapsed"),
                error="; ".join(map(str, errors))[:300] if errors else None)]


def run_host(procs: Processes, host: Host, ports: list[str], job_path: Path,
             job_length: int) -> list[Run]:
    return collect(procs, start_host(procs, host, ports, job_path), host, job_length)


def stream(procs: Processes, host: Host, target: Target, job_path: Path,
           job_length: int) -> Run:
    """A fresh printer, one host run against it, the printer's CPU time while it ran. A part
    that fails makes a Run with its error, so that one broken row leaves the others standing."""
    try:
        proc, (port,) = start_printer(procs, target)
    except BenchError as error:
        return Run(job_length, error=str(error))
    try:
        before = proc.cpu_seconds()
        (run,) = run_host(procs, host, [port], job_path, job_length) or [Run(job_length)]
        run.printer_cpu = proc.cpu_seconds() - before
        if proc.popen.poll() is not None:
            run.error = run.error or f"{target.label} died: {proc.stderr_tail()}"
    except (BenchError, OSError, ValueError) as error:
        run = Run(job_length, error=describe_error(error))
    finally:
        procs.stop(proc)
    return run


def exactly_once(job: list[str], journal: Path) -> tuple[bool, str]:
    """Did the printer behind this journal run the job once, in order? And if not, why not."""
    try:
        lines = journal.read_text(encoding="utf-8", errors="replace").split("\n")
    except OSError as error:
        return False, f"no journal {journal.name}: {error.strerror}"
    result = verify(job_commands("\n".join(job)), lines)
    if result.passed():
        return True, "ok"
    kinds = {problem.kind.value for problem in result.failures()}
    return False, f"{len(result.failures())} problems ({', '.join(sorted(kinds))})"


def write_job(directory: Path, name: str, job: list[str]) -> Path:
    path = directory / f"{name}.gcode"
    path.write_text("\n".join(job) + "\n")
    return path


def describe_error(error: BaseException) -> str:
    if isinstance(error, BenchError):
        return str(error)
    if isinstance(error, json.JSONDecodeError):
        return f"unreadable report: {error}"
    return f"{type(error).__name__}: {error}"
