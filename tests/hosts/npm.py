"""Node.js software the tests run (cncjs, playwright-core, pyright), installed with npm outside
the checkout.

As tests/hosts/venvs.py does for the Python hosts: each package at its pinned version gets an
`npm install --prefix` directory of its own under `~/.cache/fake-marlin/npm/<name>-<version>`
(FAKE_MARLIN_NPM moves it), which `python -m tests.hosts.install` fills once (`ensure`) and the
tests only look for (`find`). Node.js and npm come with the machine; where they are missing the
install step installs them from Debian's packages (tests/hosts/apt.py).
"""

import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from tests.hosts.cache import built_once, complete, run_step

MARKER = "fake-marlin-npm.json"  # written last: the install is whole


def npm_cache() -> Path:
    return Path(os.environ.get("FAKE_MARLIN_NPM", Path.home() / ".cache" / "fake-marlin" / "npm"))


@dataclass(frozen=True)
class Package:
    name: str
    version: str  # an exact version: the cache directory is named after it
    label: str  # what a person calls it
    # Run with `node -e` in the install directory once npm is done, to prove the install works
    # here (a native module that neither came prebuilt nor built fails it).
    check: str


# cncjs 1.11.5 (the newest, engines: node >= 18) runs on Node.js 20. Its serial port is
# serialport 10, whose native binding ships prebuilt for linux-x64 (glibc and musl) and arm:
# nothing compiles, so npm's install scripts are not run at all.
CNCJS = Package("cncjs", "1.11.5", "cncjs 1.11.5", (
    "require('@serialport/bindings-cpp/dist/load-bindings.js');"
    "const v = require('cncjs/package.json').version;"
    "if (v !== '1.11.5') throw new Error('cncjs ' + v + ' installed');"
))
# The browser test's driver (tests/test_report_browser.py): playwright-core drives Debian's
# Chromium and downloads no browser of its own.
PLAYWRIGHT = Package("playwright-core", "1.65.1", "playwright-core 1.65.1", (
    "const v = require('playwright-core/package.json').version;"
    "if (v !== '1.65.1') throw new Error('playwright-core ' + v + ' installed');"
))
# Microsoft's type checker, for the unresolved-import check (tests/test_typing.py); the npm
# package is the whole checker (no download at first run, unlike PyPI's pyright wrapper).
PYRIGHT = Package("pyright", "1.1.414", "pyright 1.1.414", (
    "const v = require('pyright/package.json').version;"
    "if (v !== '1.1.414') throw new Error('pyright ' + v + ' installed');"
))
PACKAGES = (CNCJS, PLAYWRIGHT, PYRIGHT)


class NpmError(RuntimeError):
    pass


@dataclass(frozen=True)
class Install:
    path: Path  # the --prefix directory: node_modules/<name> is the package
    node: str
    install_seconds: float  # how long the install took, whenever it happened
    built_now: bool

    def module(self, name: str) -> Path:
        return self.path / "node_modules" / name


def find(package: Package) -> Install | None:
    """The package's install directory if a complete one is cached and node is on PATH, else
    None; never installs anything."""
    node = shutil.which("node")
    built = complete(_path(package), MARKER, _usable(package))
    if built is None or node is None:
        return None
    return Install(built.path, node, built.install_seconds, False)


def ensure(package: Package, node: str, npm: str) -> Install:
    """The package's install directory, running `npm` first if no complete one is cached
    (tests/hosts/cache.py); the install is checked by loading it with `node` before it counts."""
    spec = f"{package.name}@{package.version}"

    def build(directory: Path) -> None:
        _run([npm, "install", "--prefix", str(directory), "--no-audit", "--no-fund",
              "--ignore-scripts", "--loglevel=error", spec], f"npm install {spec}")
        _run([node, "-e", package.check], f"load {spec} (node -e {package.check!r})", cwd=directory)

    built = built_once(_path(package), MARKER, build, {"package": spec}, _usable(package))
    return Install(built.path, node, built.install_seconds, built.built_now)


def _path(package: Package) -> Path:
    return npm_cache() / f"{package.name}-{package.version}"


def _usable(package: Package) -> Callable[[Path], bool]:
    return lambda path: (path / "node_modules" / package.name / "package.json").is_file()


def _run(command: list[str], what: str, cwd: Path | None = None) -> None:
    run_step(command, what, NpmError, cwd)
