"""Debian packages that tests run (avrdude, Chromium; Node.js and npm where the machine has none;
the Docker engine, Docker Compose 1 and debootstrap for the container farm, tests/hosts/docker.py),
and the libraries a host's venv needs (PrusaLink's: libcap-dev, libturbojpeg0, libmagic1),
installed with the machine's apt by `python -m tests.hosts.install`.

The machines this project runs on are root with apt-get; a package that is missing is installed
once, under a flock so that installs starting together do not race for dpkg's lock, and apt
itself keeps it installed for later runs. The tests only look for the program on PATH (`find`);
a library, which puts nothing on PATH, is looked for in dpkg's database (`find_library`).
Where apt cannot be used at all (no apt-get, not root) the install says so (AptUnavailable);
an install that apt tried and failed says what apt said (AptInstallFailed).
"""

import fcntl
import functools
import os
import shutil
import subprocess
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

LOCK = Path.home() / ".cache" / "fake-marlin" / "apt.lock"
TIMEOUT = 900  # seconds for one apt-get run: an update of the lists, then the download
# apt-get waits for a dpkg lock held by another apt (not ours) instead of failing at once.
APT_GET = ("apt-get", "-y", "-q", "--no-install-recommends", "-o", "DPkg::Lock::Timeout=300")


@dataclass(frozen=True)
class Tool:
    package: str  # Debian's
    binary: str  # what it puts on PATH
    label: str  # what a person calls it


NODE = Tool("nodejs", "node", "Node.js")
NPM = Tool("npm", "npm", "npm")
AVRDUDE = Tool("avrdude", "avrdude", "avrdude")
CHROMIUM = Tool("chromium", "chromium", "Chromium")
# The container farm's (tests/test_docker_farm.py). Debian 12 has Compose 1 (1.29) and no
# Compose 2 plugin; debootstrap builds the offline base image (tests/hosts/docker.py).
DOCKER = Tool("docker.io", "dockerd", "the Docker engine")
COMPOSE = Tool("docker-compose", "docker-compose", "Docker Compose 1")
DEBOOTSTRAP = Tool("debootstrap", "debootstrap", "debootstrap")


@dataclass(frozen=True)
class Library:
    """A Debian package a host's venv needs to build or to run, with no program on PATH."""

    package: str  # Debian's, also the install step's item name
    label: str  # what a person calls it, and who needs it


# PrusaLink 0.8.1 (tests/hosts/venvs.PRUSALINK): pip builds python-prctl against libcap's
# headers; PyTurboJPEG and python-magic load their libraries with ctypes when PrusaLink starts.
LIBCAP_DEV = Library("libcap-dev", "libcap's headers, for PrusaLink")
LIBTURBOJPEG = Library("libturbojpeg0", "TurboJPEG, for PrusaLink")
LIBMAGIC = Library("libmagic1", "libmagic, for PrusaLink")
LIBRARIES = (LIBCAP_DEV, LIBTURBOJPEG, LIBMAGIC)


class AptUnavailable(RuntimeError):
    """apt cannot install anything here (no apt-get, not root)."""


class AptInstallFailed(RuntimeError):
    """apt was there but the install did not work."""


def find(tool: Tool) -> str | None:
    """The tool's path if it is on PATH, else None; never installs anything."""
    return shutil.which(tool.binary)


def ensure(tool: Tool) -> str:
    return ensure_apt_package(tool.package, tool.binary)


def find_library(library: Library) -> str | None:
    """`<package> <version>` if dpkg has the package installed, else None; never installs."""
    return _dpkg_installed(library.package)


def ensure_library(library: Library) -> str:
    """What find_library says, after installing the package if it is missing."""
    return _ensure(library.package, library.package,
                   lambda: _dpkg_installed(library.package), "dpkg does not list it installed")


@functools.cache
def ensure_apt_package(package: str, binary: str) -> str:
    """The path of `binary`, after installing the Debian `package` that has it if it is missing."""
    return _ensure(package, binary, lambda: shutil.which(binary), f"it has no {binary} on PATH")


def _ensure(package: str, what: str, present: Callable[[], str | None], absent: str) -> str:
    """`present()`, after installing `package` with apt-get if it says None (`what` is missing)."""
    if (found := present()) is not None:
        return found
    if shutil.which("apt-get") is None:
        raise AptUnavailable(f"{what} is not installed and this machine has no apt-get")
    if os.geteuid() != 0:
        raise AptUnavailable(f"{what} is not installed, and only root may apt-get install it")
    LOCK.parent.mkdir(parents=True, exist_ok=True)
    with open(LOCK, "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if (found := present()) is None:
            # The package lists may be missing or stale on a fresh machine: update, then retry.
            if _apt_get("install", package) is not None:
                _apt_get("update", check=True)
                _apt_get("install", package, check=True)
            found = present()
    if found is None:
        raise AptInstallFailed(f"apt-get installed {package}, but {absent}")
    return found


def _dpkg_installed(package: str) -> str | None:
    """`<package> <version>` if dpkg's database has the package installed (status `ii`)."""
    if shutil.which("dpkg-query") is None:
        return None
    done = subprocess.run(
        ["dpkg-query", "-W", "-f", "${db:Status-Abbrev}|${Version}", package],
        capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=60,
    )
    status, _, version = done.stdout.partition("|")
    return f"{package} {version}" if done.returncode == 0 and status.strip() == "ii" else None


def _apt_get(*args: str, check: bool = False) -> str | None:
    """None when apt-get succeeded, else what it said (raised as AptInstallFailed with check)."""
    command = [*APT_GET, *args]
    environment = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    try:
        done = subprocess.run(
            command, capture_output=True, text=True, timeout=TIMEOUT, env=environment,
            stdin=subprocess.DEVNULL,
        )
        failure = None if done.returncode == 0 else (
            f"exit {done.returncode}:\n" + "\n".join(
                (done.stdout + done.stderr).strip().splitlines()[-15:]
            )
        )
    except subprocess.TimeoutExpired:
        failure = f"no result after {TIMEOUT} s"
    if failure is not None and check:
        raise AptInstallFailed(f"{' '.join(command)} failed ({failure})")
    return failure
