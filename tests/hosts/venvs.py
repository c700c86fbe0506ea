"""Virtual environments for real host software, built on demand outside the checkout.

The hosts pin libraries (OctoPrint pins Flask, werkzeug, pydantic) that must not meet the
project's own, and installing them takes a while, so each gets its own venv cached under
`~/.cache/fake-marlin/venvs/<name>-<version>`: a fresh clone builds it once, later runs reuse it.
"""

import fcntl
import json
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from fake_marlin.emulator.bench.runs import VENV_MARKER, venv_cache

CACHE = venv_cache()  # the bench looks for them there too
MARKER = VENV_MARKER
INSTALL_TIMEOUT = 1200


@dataclass(frozen=True)
class Host:
    name: str
    version: str
    pip_args: tuple[str, ...]
    module: str  # imported once the install is done, to prove it works


OCTOPRINT = Host("octoprint", "1.11", ("octoprint>=1.11,<1.12",), "octoprint.util.comm")
# The full Printrun install wants wxPython and dbus, which do not build here; printcore needs neither.
PRINTRUN = Host("printrun", "2.2.0", ("--no-deps", "printrun==2.2.0", "pyserial"), "printrun.printcore")
# Marlin's binary transfer client; it also requires `heatshrink`, which it only falls back from.
BINPROTO = Host("binproto", "0.0.7", (
    "--no-deps", "marlin-binary-protocol==0.0.7", "heatshrink2==0.15.0", "pyserial"), "binproto2")


class VenvError(RuntimeError):
    pass


@dataclass(frozen=True)
class Venv:
    path: Path
    install_seconds: float  # how long the build took, whenever it happened
    built_now: bool

    @property
    def python(self) -> Path:
        return self.path / "bin" / "python"


def ensure(host: Host) -> Venv:
    """The host's venv, building it first if no complete one is cached.

    A flock serialises pytest processes that start together. The venv is built in a temporary
    directory and renamed into place only once the install and an import check succeeded, with a
    marker file written last, so an interrupted run leaves nothing that looks usable. (Console
    scripts in the venv keep the build directory in their shebang: run everything with
    `python -m`.)
    """
    final = CACHE / f"{host.name}-{host.version}"
    if (cached := _complete(final)) is not None:
        return cached
    CACHE.mkdir(parents=True, exist_ok=True)
    with open(CACHE / f".{final.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if (cached := _complete(final)) is not None:
            return cached
        for stale in CACHE.glob(f".{final.name}.build-*"):
            shutil.rmtree(stale, ignore_errors=True)
        if final.exists():
            shutil.rmtree(final)
        build = Path(tempfile.mkdtemp(prefix=f".{final.name}.build-", dir=CACHE))
        started = time.monotonic()
        try:
            _run([sys.executable, "-m", "venv", str(build)], "create the venv")
            python = str(build / "bin" / "python")
            _run([python, "-m", "pip", "install", "--disable-pip-version-check", *host.pip_args],
                 f"pip install {' '.join(host.pip_args)}")
            _run([python, "-c", f"import {host.module}"], f"import {host.module}")
            seconds = round(time.monotonic() - started, 1)
            (build / MARKER).write_text(json.dumps({"pip_args": host.pip_args, "install_seconds": seconds}))
            build.rename(final)
        except BaseException:
            shutil.rmtree(build, ignore_errors=True)
            raise
        return Venv(final, seconds, True)


def _complete(path: Path) -> Venv | None:
    try:
        facts = json.loads((path / MARKER).read_text())
    except (OSError, ValueError):
        return None
    venv = Venv(path, facts["install_seconds"], False)
    # bin/python links to the interpreter that built it: gone if that Python was removed.
    return venv if venv.python.exists() else None


def _run(command: list[str], what: str) -> None:
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=INSTALL_TIMEOUT)
    except subprocess.TimeoutExpired as timeout:
        raise VenvError(f"could not {what}: no result after {timeout.timeout} s") from None
    if done.returncode != 0:
        tail = "\n".join((done.stdout + done.stderr).strip().splitlines()[-25:])
        raise VenvError(f"could not {what} (exit {done.returncode}):\n{tail}")


if __name__ == "__main__":
    for each in (PRINTRUN, OCTOPRINT):
        venv = ensure(each)
        print(f"{venv.path}: {'built' if venv.built_now else 'cached'}, install took {venv.install_seconds} s")
