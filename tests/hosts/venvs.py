"""Virtual environments for real host software, built outside the checkout.

The hosts pin libraries (OctoPrint pins Flask, werkzeug, pydantic) that must not meet the
project's own, and installing them takes a while, so each gets its own venv cached under
`~/.cache/fake-marlin/venvs/<name>-<version>` (FAKE_MARLIN_VENVS moves it; PrusaLink's is
`prusalink-0.8.1`): `python -m tests.hosts.install` builds it once (`ensure`), the tests and the
bench only look for it (`find`).
"""

import sys
from dataclasses import dataclass
from pathlib import Path

from fake_marlin.emulator.bench.runs import VENV_MARKER, venv_cache
from tests.hosts.cache import built_once, complete, run_step

MARKER = VENV_MARKER


@dataclass(frozen=True)
class Host:
    name: str
    version: str
    label: str  # what a person calls it
    pip_args: tuple[str, ...]
    module: str  # imported once the install is done, to prove it works
    apt: tuple[str, ...] = ()  # Debian packages it needs first (tests/hosts/apt.LIBRARIES)


OCTOPRINT = Host("octoprint", "1.11", "OctoPrint 1.11", ("octoprint>=1.11,<1.12",),
                 "octoprint.util.comm")
# The full Printrun install wants wxPython and dbus, which do not build here; printcore needs neither.
PRINTRUN = Host("printrun", "2.2.0", "Printrun 2.2.0 (printcore)",
                ("--no-deps", "printrun==2.2.0", "pyserial"), "printrun.printcore")
# Marlin's binary transfer client; it also requires `heatshrink`, which it only falls back from.
BINPROTO = Host("binproto", "0.0.7", "binproto2 0.0.7 (marlin-binary-protocol)", (
    "--no-deps", "marlin-binary-protocol==0.0.7", "heatshrink2==0.15.0", "pyserial"), "binproto2")
# Prusa's print server for the MK3S (tests/hosts/prusalink.py runs it). pip builds python-prctl
# against libcap's headers; importing prusa.link.daemon loads TurboJPEG and libmagic (ctypes),
# so the check proves the two runtime libraries are there as well.
PRUSALINK = Host("prusalink", "0.8.1", "PrusaLink 0.8.1", ("prusalink==0.8.1",),
                 "prusa.link.daemon", apt=("libcap-dev", "libturbojpeg0", "libmagic1"))


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


HOSTS = (OCTOPRINT, PRINTRUN, BINPROTO, PRUSALINK)


def find(host: Host) -> Venv | None:
    """The host's venv if a complete one is cached, else None; never installs anything."""
    built = complete(_path(host), MARKER, _usable)
    return None if built is None else Venv(built.path, built.install_seconds, False)


def ensure(host: Host) -> Venv:
    """The host's venv, building it first if no complete one is cached (tests/hosts/cache.py).
    (Console scripts in the venv keep the build directory in their shebang: run everything
    with `python -m`.)"""

    def build(directory: Path) -> None:
        _run([sys.executable, "-m", "venv", str(directory)], "create the venv")
        python = str(directory / "bin" / "python")
        _run([python, "-m", "pip", "install", "--disable-pip-version-check", *host.pip_args],
             f"pip install {' '.join(host.pip_args)}")
        _run([python, "-c", f"import {host.module}"], f"import {host.module}")

    built = built_once(_path(host), MARKER, build, {"pip_args": host.pip_args}, _usable)
    return Venv(built.path, built.install_seconds, built.built_now)


def _path(host: Host) -> Path:
    return venv_cache() / f"{host.name}-{host.version}"  # where the bench looks for them too


def _usable(path: Path) -> bool:
    # bin/python links to the interpreter that built it: gone if that Python was removed.
    return (path / "bin" / "python").exists()


def _run(command: list[str], what: str) -> None:
    run_step(command, what, VenvError)

