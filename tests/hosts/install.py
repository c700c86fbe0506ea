"""Install everything the test suite runs besides fake-marlin itself: the one step that does.

    python -m tests.hosts.install                 # everything, once; later runs find it cached
    python -m tests.hosts.install --only cncjs    # one item (the option repeats)
    python -m tests.hosts.install --check         # what is there, installing nothing

What it installs, each at a pinned version outside the checkout, so that a fresh clone builds
it once and later runs reuse it:
- the real hosts' venvs under ~/.cache/fake-marlin/venvs (tests/hosts/venvs.py): OctoPrint,
  Printrun's printcore, binproto2, PrusaLink; the bench (`fake-marlin bench`) finds them there too;
- npm packages under ~/.cache/fake-marlin/npm (tests/hosts/npm.py): cncjs, playwright-core
  (the report page's browser test), pyright (the unresolved-import check);
- Debian packages with apt (tests/hosts/apt.py): avrdude, Chromium, and Node.js and npm where
  the machine has none; the libraries PrusaLink's venv needs, libcap-dev, libturbojpeg0 and
  libmagic1, before it (apt needs root);
- the container farm's Docker (tests/hosts/docker.py): docker.io, docker-compose and debootstrap
  from apt, dockerd started where it is not running, the offline `python:3.11-slim` base image
  (debootstrapped once, its tarball under ~/.cache/fake-marlin/docker) and the wheels the image
  installs from.

The tests install nothing: a test whose tool is missing skips, naming this command
(`not_installed`). One line per item says whether it was built now or found cached, where, and
how long its install took; anything that cannot be installed is said on stderr, the other items
are still done, and the exit status is 1.
"""

import argparse
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from tests.hosts import apt, docker, npm, venvs

COMMAND = "python -m tests.hosts.install"


def not_installed(label: str) -> str:
    """A skipping test's reason: what is missing and the command that installs it."""
    return f"{label} is not installed: run `{COMMAND}`"


@dataclass(frozen=True)
class Found:
    path: Path | str
    built_now: bool
    seconds: float | None  # how long its install took, whenever it happened (None: not ours)


@dataclass(frozen=True)
class Item:
    name: str  # for --only
    label: str
    find: Callable[[], Found | None]  # never installs
    install: Callable[[], Found]
    needs: tuple[str, ...] = field(default=())  # items installed first (--only takes them too)
    done: str = "built"  # what its install did, for the line that says so


class InstallError(RuntimeError):
    pass


def _venv(host: venvs.Host) -> Item:
    def find() -> Found | None:
        venv = venvs.find(host)
        return None if venv is None else Found(venv.path, False, venv.install_seconds)

    def install() -> Found:
        venv = venvs.ensure(host)
        return Found(venv.path, venv.built_now, venv.install_seconds)

    return Item(host.name, host.label, find, install, needs=host.apt)


def _npm(package: npm.Package) -> Item:
    def find() -> Found | None:
        done = npm.find(package)
        return None if done is None else Found(done.path, False, done.install_seconds)

    def install() -> Found:
        node, npm_program = apt.find(apt.NODE), apt.find(apt.NPM)
        if node is None or npm_program is None:
            raise InstallError("Node.js and npm are needed first")
        done = npm.ensure(package, node, npm_program)
        return Found(done.path, done.built_now, done.install_seconds)

    return Item(package.name, package.label, find, install, needs=("node", "npm"))


def _apt(tool: apt.Tool) -> Item:
    def find() -> Found | None:
        path = apt.find(tool)
        return None if path is None else Found(path, False, None)

    def install() -> Found:
        if (path := apt.find(tool)) is not None:
            return Found(path, False, None)
        started = time.monotonic()
        path = apt.ensure(tool)
        return Found(path, True, round(time.monotonic() - started, 1))

    return Item(tool.binary, f"{tool.label} (Debian's {tool.package})", find, install)


def _library(library: apt.Library) -> Item:
    def find() -> Found | None:
        installed = apt.find_library(library)
        return None if installed is None else Found(installed, False, None)

    def install() -> Found:
        if (installed := apt.find_library(library)) is not None:
            return Found(installed, False, None)
        started = time.monotonic()
        installed = apt.ensure_library(library)
        return Found(installed, True, round(time.monotonic() - started, 1))

    return Item(library.package, f"{library.label} (Debian's {library.package})", find, install)


def _docker_daemon() -> Item:
    def find() -> Found | None:
        version = docker.daemon_version()
        return None if version is None else Found(f"Docker {version}", False, None)

    def install() -> Found:
        daemon = docker.ensure_daemon()
        where = f"Docker {daemon.version}" + (
            f", log {docker.cache() / 'dockerd.log'}" if daemon.started_now else "")
        return Found(where, daemon.started_now, daemon.seconds)

    return Item("docker-daemon", "the Docker daemon, running", find, install,
                needs=(apt.DOCKER.binary,), done="started")


def _docker_base_image() -> Item:
    def find() -> Found | None:
        if docker.daemon_version() is None or not docker.base_image_present():
            return None
        cached = docker.rootfs_cached()
        return Found(docker.BASE_IMAGE, False, None if cached is None else cached.install_seconds)

    def install() -> Found:
        image = docker.ensure_base_image()
        return Found(image.description, image.built_now, image.seconds)

    return Item("docker-base-image", f"the {docker.BASE_IMAGE} base image, made offline", find,
                install, needs=(apt.DOCKER.binary, "docker-daemon", apt.DEBOOTSTRAP.binary))


def _docker_wheels() -> Item:
    def find() -> Found | None:
        built = docker.find_wheels()
        return None if built is None else Found(built.path, False, built.install_seconds)

    def install() -> Found:
        built = docker.ensure_wheels()
        return Found(built.path, built.built_now, built.install_seconds)

    return Item("docker-wheels", "the wheels the farm's image installs from", find, install)


ITEMS = (
    *(_apt(tool) for tool in (apt.NODE, apt.NPM, apt.AVRDUDE, apt.CHROMIUM)),
    *(_library(library) for library in apt.LIBRARIES),
    *(_venv(host) for host in venvs.HOSTS),
    *(_npm(package) for package in npm.PACKAGES),
    *(_apt(tool) for tool in (apt.DOCKER, apt.COMPOSE, apt.DEBOOTSTRAP)),
    _docker_daemon(), _docker_base_image(), _docker_wheels(),
)
BY_NAME = {item.name: item for item in ITEMS}
ERRORS = (venvs.VenvError, npm.NpmError, apt.AptUnavailable, apt.AptInstallFailed, InstallError,
          docker.DockerUnavailable, OSError)


def describe(item: Item, found: Found) -> str:
    if found.seconds is None:
        state = "installed now" if found.built_now else "present"
    elif found.built_now:
        state = f"{item.done} now in {found.seconds} s"
    else:
        state = f"cached (built in {found.seconds} s)"
    return f"{item.name:<16} {state:<28} {found.path}"


def chosen(only: list[str]) -> list[Item]:
    """The items `--only` names (with what they need), in install order; all without it."""
    if not only:
        return list(ITEMS)
    wanted: set[str] = set()
    for name in only:
        wanted |= {name, *BY_NAME[name].needs}
    return [item for item in ITEMS if item.name in wanted]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog=COMMAND,
        description="Install what the test suite runs besides fake-marlin (host venvs, npm\n"
        "packages, Debian packages), each once, at a pinned version, outside the checkout.\n"
        "The tests install nothing: a test whose tool is missing skips and names this command.",
        epilog="items, in install order:\n" + "\n".join(
            f"  {item.name:<16} {item.label}" for item in ITEMS),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--only", action="append", default=[], metavar="NAME",
                        choices=list(BY_NAME), help="install this item alone (and what it "
                        "needs); repeat for more")
    parser.add_argument("--check", action="store_true",
                        help="only say what is installed; exit 1 if anything is missing")
    args = parser.parse_args(argv)
    failed: dict[str, str] = {}
    for item in chosen(args.only):
        if args.check:
            found = item.find()
            if found is None:
                failed[item.name] = ""
                print(f"{item.name:<16} missing", flush=True)
            else:
                print(describe(item, found), flush=True)
            continue
        if blocked := [name for name in item.needs if name in failed]:
            failed[item.name] = f"not tried: it needs {', '.join(blocked)}"
        else:
            try:
                print(describe(item, item.install()), flush=True)
                continue
            except ERRORS as error:
                failed[item.name] = f"cannot install {item.label}: {error}"
        print(f"{item.name:<16} FAILED (below)", flush=True)
    for name, why in failed.items():
        if why:
            print(f"{COMMAND}: {name}: {why}", file=sys.stderr)
    if failed:
        print(f"{COMMAND}: not installed: {', '.join(failed)}"
              + (f" (run `{COMMAND}`)" if args.check else ""), file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
