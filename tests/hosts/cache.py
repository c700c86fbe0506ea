"""A directory built once and kept: the real hosts' venvs and npm installs, outside the checkout.

Installing a host takes a while and a fresh clone must do it only once, so each lives in a
directory of its own under ~/.cache/fake-marlin, named after the host and its version.
`python -m tests.hosts.install` builds them (`built_once`); the tests only look for them
(`complete`). A flock serialises installs that start together. The directory is built under a
temporary name and renamed into place only once the build (and its check) succeeded, with a
marker file written last, so an interrupted install leaves nothing that looks usable.
"""

import fcntl
import json
import shutil
import subprocess
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

INSTALL_TIMEOUT = 1200  # seconds for one step of an install (pip, npm)


@dataclass(frozen=True)
class Built:
    path: Path
    install_seconds: float  # how long the build took, whenever it happened
    built_now: bool


def built_once(final: Path, marker: str, build: Callable[[Path], None],
               facts: dict[str, object], usable: Callable[[Path], bool]) -> Built:
    """`final`, running `build(directory)` first if no complete one is there. `usable` says
    whether a directory with its marker still works (its interpreter not gone, say)."""
    if (cached := complete(final, marker, usable)) is not None:
        return cached
    final.parent.mkdir(parents=True, exist_ok=True)
    with open(final.parent / f".{final.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if (cached := complete(final, marker, usable)) is not None:
            return cached
        for stale in final.parent.glob(f".{final.name}.build-*"):
            shutil.rmtree(stale, ignore_errors=True)
        if final.exists():
            shutil.rmtree(final)
        directory = Path(tempfile.mkdtemp(prefix=f".{final.name}.build-", dir=final.parent))
        started = time.monotonic()
        try:
            build(directory)
            seconds = round(time.monotonic() - started, 1)
            (directory / marker).write_text(json.dumps({**facts, "install_seconds": seconds}))
            directory.rename(final)
        except BaseException:
            shutil.rmtree(directory, ignore_errors=True)
            raise
        return Built(final, seconds, True)


def complete(path: Path, marker: str, usable: Callable[[Path], bool]) -> Built | None:
    """`path` if a build finished there (its marker written) and it still works, else None:
    what the tests look for, without building anything."""
    try:
        facts = json.loads((path / marker).read_text())
    except (OSError, ValueError):
        return None
    return Built(path, facts["install_seconds"], False) if usable(path) else None


def run_step(command: list[str], what: str, error: type[Exception], cwd: Path | None = None) -> None:
    """One step of a build; `error` (the installer's own) says what failed, with the tail of
    what the command printed."""
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=INSTALL_TIMEOUT,
                              cwd=cwd, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired as timeout:
        raise error(f"could not {what}: no result after {timeout.timeout} s") from None
    if done.returncode != 0:
        tail = "\n".join((done.stdout + done.stderr).strip().splitlines()[-25:])
        raise error(f"could not {what} (exit {done.returncode}):\n{tail}")
