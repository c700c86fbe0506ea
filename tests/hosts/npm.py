"""Node.js host software (cncjs), installed with npm on demand outside the checkout.

As tests/hosts/venvs.py does for the Python hosts: each package at its pinned version gets an
`npm install --prefix` directory of its own under `~/.cache/fake-marlin/npm/<name>-<version>`
(FAKE_MARLIN_NPM moves it), so a fresh clone installs it once and later runs reuse it. Node.js
and npm come with the machine; where they are missing they are installed from Debian's packages.
"""

import os
from dataclasses import dataclass
from pathlib import Path

from tests.hosts.apt import AptInstallFailed, AptUnavailable, ensure_apt_package
from tests.hosts.cache import built_once, run_step

MARKER = "fake-marlin-npm.json"  # written last: the install is whole


def npm_cache() -> Path:
    return Path(os.environ.get("FAKE_MARLIN_NPM", Path.home() / ".cache" / "fake-marlin" / "npm"))


@dataclass(frozen=True)
class Package:
    name: str
    version: str  # an exact version: the cache directory is named after it
    # Run with `node -e` in the install directory once npm is done, to prove the install works
    # here (a native module that neither came prebuilt nor built fails it).
    check: str


# cncjs 1.11.5 (the newest, engines: node >= 18) runs on Node.js 20. Its serial port is
# serialport 10, whose native binding ships prebuilt for linux-x64 (glibc and musl) and arm:
# nothing compiles, so npm's install scripts are not run at all.
CNCJS = Package("cncjs", "1.11.5", (
    "require('@serialport/bindings-cpp/dist/load-bindings.js');"
    "const v = require('cncjs/package.json').version;"
    "if (v !== '1.11.5') throw new Error('cncjs ' + v + ' installed');"
))


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


def ensure(package: Package) -> Install:
    """The package's install directory, running npm first if no complete one is cached
    (tests/hosts/cache.py); the install is checked by loading it with node before it counts."""
    node, npm = node_tools()
    spec = f"{package.name}@{package.version}"

    def build(directory: Path) -> None:
        _run([npm, "install", "--prefix", str(directory), "--no-audit", "--no-fund",
              "--ignore-scripts", "--loglevel=error", spec], f"npm install {spec}")
        _run([node, "-e", package.check], f"load {spec} (node -e {package.check!r})", cwd=directory)

    built = built_once(npm_cache() / f"{package.name}-{package.version}", MARKER, build,
                       {"package": spec},
                       lambda path: (path / "node_modules" / package.name / "package.json").is_file())
    return Install(built.path, node, built.install_seconds, built.built_now)


def node_tools() -> tuple[str, str]:
    """`node` and `npm`, from Debian's packages (tests/hosts/apt.py) if the machine has none."""
    try:
        return ensure_apt_package("nodejs", "node"), ensure_apt_package("npm", "npm")
    except (AptUnavailable, AptInstallFailed) as error:
        raise NpmError(f"no Node.js or npm to install cncjs with: {error}") from None


def _run(command: list[str], what: str, cwd: Path | None = None) -> None:
    run_step(command, what, NpmError, cwd)


if __name__ == "__main__":
    install = ensure(CNCJS)
    print(f"{install.path}: {'installed' if install.built_now else 'cached'}, install took {install.install_seconds} s")
