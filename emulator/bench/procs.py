"""The bench's subprocesses: starting them, reading what they announce, their CPU time and
memory from /proc, and stopping every one of them whatever happens.

Each printer, responder and host runs in a process of its own, so that each one's CPU time is
its own (/proc/<pid>/...), not mixed with the bench's or with the other side's.
"""

import contextlib
import ctypes
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

STOP_TIMEOUT = 5.0
_CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
_PR_SET_PDEATHSIG = 1


class BenchError(Exception):
    """A part of the bench could not run; the message says which, in one line."""


def _die_with_parent() -> None:  # pragma: no cover - runs in the child, before exec
    """Ask Linux to SIGTERM the child when the bench dies, even by SIGKILL, so that no printer
    outlives a bench that could not clean up."""
    with contextlib.suppress(Exception):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)


def _stat_fields(pid: int) -> list[str]:
    """/proc/<pid>/stat's fields after the command's name (field 3 on: state, ppid, ...)."""
    with open(f"/proc/{pid}/stat") as file:
        return file.read().rsplit(")", 1)[1].split()


def children_of(pid: int) -> list[int]:
    """The pids of a process's children, lowest (in practice: the first started) first."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            with contextlib.suppress(OSError, IndexError, ValueError):
                if int(_stat_fields(int(entry))[1]) == pid:
                    found.append(int(entry))
    return sorted(found)


def _cpu_seconds(pid: int) -> float:
    fields = _stat_fields(pid)
    ticks = int(fields[11]) + int(fields[12])  # utime, stime (fields 14 and 15)
    try:
        nanoseconds = 0
        for task in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task}/schedstat") as file:
                nanoseconds += int(file.read().split()[0])
        # Threads that ended took their schedstat with them, but not their ticks.
        return max(nanoseconds / 1e9, ticks / _CLOCK_TICKS - 2 / _CLOCK_TICKS)
    except (OSError, ValueError, IndexError):
        return ticks / _CLOCK_TICKS


def _rss_bytes(pid: int, name: str) -> int:
    with open(f"/proc/{pid}/status") as file:
        for line in file:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise BenchError(f"no VmRSS for {name}")


class Proc:
    def __init__(self, name: str, argv: Sequence[str], workdir: Path,
                 env: dict[str, str] | None = None) -> None:
        self.name = name.split("-", 1)[-1]  # for messages; the files carry the counter too
        self._stderr_path = workdir / f"{name}.stderr"
        self._stdout_path = workdir / f"{name}.stdout"
        with open(self._stderr_path, "wb") as stderr, open(self._stdout_path, "wb") as stdout:
            # A session of its own: a Ctrl-C at the terminal reaches only the bench, which then
            # stops its children in order (a host in the middle of a line would print tracebacks).
            self.popen = subprocess.Popen(
                list(argv), stdin=subprocess.DEVNULL, stdout=stdout, stderr=stderr, env=env,
                start_new_session=True, preexec_fn=_die_with_parent,
            )
        self.pid = self.popen.pid

    # -- what it says ---------------------------------------------------------------------
    def read_lines(self, count: int, timeout: float) -> list[str]:
        """The first `count` lines of its stdout (pty paths), waiting up to `timeout` seconds.
        stdout is a file, not a pipe, so nothing it prints later can ever block it."""
        deadline = time.monotonic() + timeout
        while True:
            text = self._stdout_path.read_text(errors="replace")
            lines = text.split("\n")
            if len(lines) > count:
                return lines[:count]
            if self.popen.poll() is not None:
                raise BenchError(f"{self.name} exited ({self.popen.returncode}) before it was "
                                 f"ready: {self.stderr_tail()}")
            if time.monotonic() > deadline:
                raise BenchError(f"{self.name} was not ready after {timeout:.0f} s "
                                 f"({len(lines) - 1} of {count} lines)")
            time.sleep(0.01 if count == 1 else 0.05)

    def stderr_lines(self) -> list[str]:
        try:
            return self._stderr_path.read_text(errors="replace").splitlines()
        except OSError:
            return []

    def stderr_tail(self) -> str:
        try:
            lines = self._stderr_path.read_text(errors="replace").strip().splitlines()
        except OSError:
            return "(no output)"
        return lines[-1] if lines else "(no output)"

    def wait_json(self, timeout: float) -> dict:
        """Wait for a driver to exit and read the JSON object on its last stdout line."""
        try:
            self.popen.wait(timeout)
        except subprocess.TimeoutExpired:
            self.stop()
            raise BenchError(f"{self.name} did not finish within {timeout:.0f} s") from None
        lines = self._stdout_path.read_text(errors="replace").strip().splitlines()
        try:
            report = json.loads(lines[-1])
        except (IndexError, ValueError):
            raise BenchError(f"{self.name} exited ({self.popen.returncode}) without a report: "
                             f"{self.stderr_tail()}") from None
        if not isinstance(report, dict):
            raise BenchError(f"{self.name} printed no JSON object")
        return report

    # -- what it costs --------------------------------------------------------------------
    def cpu_seconds(self) -> float:
        """CPU time so far, user and system. The scheduler's nanosecond account
        (/proc/<pid>/task/*/schedstat) where it exists, since the clock-tick one (/proc/<pid>/stat,
        10 ms steps) is too coarse for the bare responder, which may use 50 ms in a whole run."""
        return _cpu_seconds(self.pid)

    def rss_bytes(self) -> int:
        return _rss_bytes(self.pid, self.name)

    def children(self) -> list[int]:
        """Its child processes' pids, in the order they started (a farm's --processes)."""
        return children_of(self.pid)

    def tree_cpu_seconds(self) -> list[float]:
        """CPU time so far of it and of each of its children, it first."""
        return [_cpu_seconds(pid) for pid in (self.pid, *self.children())]

    def tree_rss_bytes(self) -> int:
        """Memory of it and its children together."""
        return sum(_rss_bytes(pid, self.name) for pid in (self.pid, *self.children()))

    # -- ending it ------------------------------------------------------------------------
    def stop(self, timeout: float = STOP_TIMEOUT) -> None:
        """SIGTERM (the printer's Ctrl-C), then SIGKILL if it lingers `timeout` seconds; reaps
        it either way."""
        if self.popen.returncode is not None:
            return
        with contextlib.suppress(ProcessLookupError):
            self.popen.send_signal(signal.SIGTERM)
        try:
            self.popen.wait(timeout)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                self.popen.kill()
            self.popen.wait()


class Processes:
    """Every process the bench started, stopped by `stop_all` (the CLI's `finally`)."""

    def __init__(self, workdir: Path) -> None:
        self.workdir = workdir
        self._running: list[Proc] = []
        self._count = 0

    def start(self, name: str, argv: Sequence[str], env: dict[str, str] | None = None) -> Proc:
        self._count += 1
        proc = Proc(f"{self._count:03d}-{name}", argv, self.workdir, env)  # unique file names
        self._running.append(proc)
        return proc

    def stop(self, proc: Proc, timeout: float = STOP_TIMEOUT) -> None:
        proc.stop(timeout)
        with contextlib.suppress(ValueError):
            self._running.remove(proc)

    def stop_all(self) -> None:
        while self._running:
            self.stop(self._running[-1])


def python_module(module: str) -> list[str]:
    """The command line that runs one of our modules with this interpreter."""
    return [sys.executable, "-m", module]


def fake_marlin(*args: str) -> list[str]:
    """The printer, as users start it (the same entry point as the console script)."""
    return [sys.executable, "-m", "fake_marlin.emulator.cli", *args]

