"""Docker for the container farm's tests (tests/test_docker_farm.py), set up by
`python -m tests.hosts.install`: the engine running, the offline base image, the wheels.

- The engine: Debian's docker.io (tests/hosts/apt.py), started by hand where nothing started
  it (no systemd here): `dockerd` in the background, logging to ~/.cache/fake-marlin/docker/
  dockerd.log, until `docker info` answers (`ensure_daemon`). The tests call it too, so a
  session whose daemon went (CI starts with none) starts it again; they never assume it.
- The base image: no image registry is reachable, so the Dockerfile's `python:3.11-slim` is
  a stand-in made offline, where `docker image inspect` does not find it: `debootstrap
  --variant=minbase bookworm` from the Debian mirror apt uses, with python3 (3.11 in bookworm),
  pip, venv and ca-certificates (and this machine's own CA certificates), Debian's
  EXTERNALLY-MANAGED marker removed and `python`/`pip` on PATH as in the real image; tarred
  once into the cache (rootfs.tar.gz) and `docker import`ed, so that a later machine state
  without the image only imports (`ensure_base_image`).
- The wheels: the image is built with no network (a machine may have none for containers),
  so the package's dependencies (and the setuptools its build needs) are downloaded once on
  this machine, for the image's Python, into a wheelhouse named after
  pyproject.toml's requirements (`ensure_wheels`); the test copies it into the build context's
  wheels/ and builds with `--build-arg OFFLINE=1` (the Dockerfile's `--no-index`).
"""

import fcntl
import hashlib
import json
import os
import platform
import shutil
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

from tests.hosts.cache import Built, built_once, complete, run_step

CHECKOUT = Path(__file__).resolve().parents[2]
BASE_IMAGE = "python:3.11-slim"
SUITE = "bookworm"  # Debian 12, whose python3 is 3.11 as the real image's
PACKAGES = ("python3", "python3-pip", "python3-venv", "ca-certificates")
DEFAULT_MIRROR = "http://deb.debian.org/debian"
ROOTFS = "rootfs.tar.gz"
LOCAL_CAS = "/usr/local/share/ca-certificates"
MARKER = "fake-marlin-docker.json"  # written last: the build is whole
DAEMON_TIMEOUT = 60  # seconds for a started dockerd to answer
# What the real image sets, and a label that says this one is the stand-in.
IMPORT_CHANGES = (
    "ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
    "ENV LANG=C.UTF-8",
    'CMD ["python3"]',
    "LABEL org.fake-marlin.base=debootstrap-bookworm",
)


class DockerUnavailable(RuntimeError):
    """Docker cannot run here, and why (not installed, not root, dockerd would not start)."""


def cache() -> Path:
    return Path(os.environ.get("FAKE_MARLIN_DOCKER",
                               Path.home() / ".cache" / "fake-marlin" / "docker"))


def cli() -> str | None:
    """The docker client: the engine's own (docker.io's /usr/bin/docker, the same version as the
    daemon) before any other on PATH (a newer client alone may lack the legacy builder)."""
    engines = Path("/usr/bin/docker")
    return str(engines) if engines.exists() else shutil.which("docker")


def _dockerd() -> str | None:
    return shutil.which("dockerd", path=os.environ.get("PATH", "") + ":/usr/sbin:/sbin")


def docker(*args: str, timeout: float = 120, check: bool = True,
           env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """Run the docker client; a timeout, and with check a failure, raises DockerUnavailable
    with what it said."""
    client = cli()
    if client is None:
        raise DockerUnavailable("the docker client is not installed")
    try:
        done = subprocess.run([client, *args], capture_output=True, text=True, timeout=timeout,
                              stdin=subprocess.DEVNULL, env=env)
    except subprocess.TimeoutExpired:
        raise DockerUnavailable(f"docker {' '.join(args)}: no answer in {timeout} s") from None
    if check and done.returncode != 0:
        raise DockerUnavailable(f"docker {' '.join(args)} failed (exit {done.returncode}): "
                                + (done.stderr or done.stdout).strip()[-2000:])
    return done


# -- the engine ----------------------------------------------------------------------------------

def daemon_version() -> str | None:
    """The engine's version if the daemon answers, else None; never starts it."""
    if cli() is None:
        return None
    try:
        done = docker("info", "--format", "{{.ServerVersion}}", timeout=30, check=False)
    except DockerUnavailable:
        return None
    version = done.stdout.strip()
    return version if done.returncode == 0 and version and "Error" not in version else None


@dataclass(frozen=True)
class Daemon:
    version: str
    started_now: bool
    seconds: float | None  # how long it took to answer, when started now


def ensure_daemon() -> Daemon:
    """The running engine, after starting dockerd in the background if it does not answer."""
    if (version := daemon_version()) is not None:
        return Daemon(version, False, None)
    if cli() is None or (dockerd := _dockerd()) is None:
        raise DockerUnavailable("the Docker engine is not installed")
    if os.geteuid() != 0:
        raise DockerUnavailable("dockerd is not running, and only root may start it here")
    cache().mkdir(parents=True, exist_ok=True)
    log_path = cache() / "dockerd.log"
    with open(cache() / "dockerd.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if (version := daemon_version()) is not None:
            return Daemon(version, False, None)
        started = time.monotonic()
        with open(log_path, "ab") as log:
            log.write(f"--- {time.strftime('%Y-%m-%d %H:%M:%S')} started by "
                      f"tests/hosts/docker.py\n".encode())
            log.flush()
            # Its own session: it outlives the install step, and Ctrl-C in a test run.
            daemon = subprocess.Popen([dockerd], stdin=subprocess.DEVNULL, stdout=log,
                                      stderr=subprocess.STDOUT, start_new_session=True)
        _started.append(daemon)  # kept: it runs on when this process ends, unwaited for
        while time.monotonic() - started < DAEMON_TIMEOUT:
            if daemon.poll() is not None:
                raise DockerUnavailable(f"dockerd exited at once (status {daemon.returncode}); "
                                        f"the end of {log_path}:\n{_tail(log_path)}")
            if (version := daemon_version()) is not None:
                return Daemon(version, True, round(time.monotonic() - started, 1))
            time.sleep(0.5)
    raise DockerUnavailable(f"dockerd did not answer within {DAEMON_TIMEOUT} s; the end of "
                            f"{log_path}:\n{_tail(log_path)}")


_started: list[subprocess.Popen[bytes]] = []


def _tail(path: Path, lines: int = 15) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return "(no log)"


# -- the base image ------------------------------------------------------------------------------

def base_image_present() -> bool:
    """Whether the daemon answers and has python:3.11-slim (pulled or imported); never builds."""
    return (cli() is not None and
            docker("image", "inspect", BASE_IMAGE, timeout=30, check=False).returncode == 0)


def rootfs_cached() -> Built | None:
    """The cached debootstrap tarball, if a build finished; never builds."""
    return complete(_rootfs_dir(), MARKER, lambda path: (path / ROOTFS).is_file())


@dataclass(frozen=True)
class BaseImage:
    description: str
    built_now: bool
    seconds: float | None


def ensure_base_image() -> BaseImage:
    """python:3.11-slim in the engine, imported from the cached tarball (debootstrapped first
    when there is none) if the engine lacks it. The engine must be running (ensure_daemon)."""
    if base_image_present():
        cached = rootfs_cached()
        return BaseImage(BASE_IMAGE, False, None if cached is None else cached.install_seconds)
    if (debootstrap := shutil.which("debootstrap",
                                    path=os.environ.get("PATH", "") + ":/usr/sbin")) is None:
        raise DockerUnavailable("debootstrap is not installed")
    if os.geteuid() != 0:
        raise DockerUnavailable("debootstrap needs root")
    mirror = debian_mirror()
    built = built_once(_rootfs_dir(), MARKER, lambda directory: _debootstrap(
        debootstrap, mirror, directory), {"suite": SUITE, "mirror": mirror,
                                          "packages": list(PACKAGES)},
        lambda path: (path / ROOTFS).is_file())
    started = time.monotonic()
    changes = [argument for change in IMPORT_CHANGES for argument in ("--change", change)]
    docker("import", *changes, "--message", f"debootstrap {SUITE} minbase + {' '.join(PACKAGES)}",
           str(built.path / ROOTFS), BASE_IMAGE, timeout=600)
    imported = round(time.monotonic() - started, 1)
    how = (f"debootstrapped in {built.install_seconds} s" if built.built_now
           else "from the cached tarball")
    return BaseImage(f"{BASE_IMAGE} ({how}, imported in {imported} s) {built.path / ROOTFS}",
                     True, built.install_seconds if built.built_now else imported)


def _rootfs_dir() -> Path:
    return cache() / f"base-{SUITE}-python3"


def debian_mirror() -> str:
    """The Debian mirror apt uses here (sources.list or deb822 .sources), else deb.debian.org."""
    sources = Path("/etc/apt")
    files = [sources / "sources.list", *sorted((sources / "sources.list.d").glob("*.list")),
             *sorted((sources / "sources.list.d").glob("*.sources"))]
    for path in files:
        try:
            text = path.read_text()
        except OSError:
            continue
        uris: list[str] = []
        if path.suffix == ".sources":
            for stanza in text.split("\n\n"):
                fields = dict(line.split(":", 1) for line in stanza.splitlines()
                              if ":" in line and not line.startswith(("#", " ")))
                if "deb" in fields.get("Types", "").split() and "main" in fields.get(
                        "Components", "").split():
                    uris += fields.get("URIs", "").split()
        else:
            for line in text.splitlines():
                words = [word for word in line.split("#", 1)[0].split()
                         if not word.startswith("[")]
                if len(words) >= 4 and words[0] == "deb" and "main" in words[3:]:
                    uris.append(words[1])
        for uri in uris:
            if uri.rstrip("/").endswith("/debian") and uri.startswith(("http:", "https:")):
                return uri.rstrip("/")
    return DEFAULT_MIRROR


def _debootstrap(debootstrap: str, mirror: str, directory: Path) -> None:
    root = directory / "root"
    try:
        run_step([debootstrap, "--variant=minbase", f"--include={','.join(PACKAGES)}", SUITE,
                  str(root), mirror], f"debootstrap {SUITE} from {mirror}", DockerUnavailable)
        # As in the real image: pip may install into the system Python, `python` and `pip` work.
        (root / "usr/lib/python3.11/EXTERNALLY-MANAGED").unlink(missing_ok=True)
        for name, target in (("python", "/usr/bin/python3"), ("pip", "/usr/bin/pip3")):
            link = root / "usr/local/bin" / name
            if not link.exists() and not link.is_symlink():
                link.symlink_to(target)
        # This machine's own CA certificates too (a TLS-inspecting network's), so that a
        # build that does use the network (no OFFLINE) reaches the package index as the host does.
        local_cas = sorted(Path(LOCAL_CAS).glob("*.crt"))
        if local_cas:
            (root / LOCAL_CAS.lstrip("/")).mkdir(parents=True, exist_ok=True)
            for certificate in local_cas:
                shutil.copyfile(certificate, root / LOCAL_CAS.lstrip("/") / certificate.name)
            run_step(["chroot", str(root), "update-ca-certificates"],
                     "add this machine's CA certificates", DockerUnavailable)
        for leftovers in (root / "var/cache/apt/archives", root / "var/lib/apt/lists"):
            for path in leftovers.glob("*"):
                if path.is_file():
                    path.unlink()
        run_step(["tar", "--numeric-owner", "-C", str(root), "-czf", str(directory / ROOTFS),
                  "."], "tar the base image's root", DockerUnavailable)
    finally:
        _unmount_under(root)  # a debootstrap cut short may leave /proc or /dev mounted there
        shutil.rmtree(root, ignore_errors=True)


def _unmount_under(root: Path) -> None:
    try:
        mounts = [line.split()[1] for line in Path("/proc/self/mounts").read_text().splitlines()]
    except OSError:
        return
    for mount in sorted((m for m in mounts if m.startswith(f"{root}/")), reverse=True):
        subprocess.run(["umount", "-l", mount], capture_output=True, check=False)


# -- the wheels ----------------------------------------------------------------------------------

def requirements() -> list[str]:
    """What `pip install .` needs in the image: pyproject's build requirements and dependencies."""
    with open(CHECKOUT / "pyproject.toml", "rb") as file:
        project = tomllib.load(file)
    return [*project["build-system"]["requires"], *project["project"]["dependencies"]]


def wheels_dir() -> Path:
    digest = hashlib.sha256(json.dumps(sorted(requirements())).encode()).hexdigest()[:12]
    return cache() / f"wheels-py311-{platform.machine()}-{digest}"


def find_wheels() -> Built | None:
    """The wheelhouse for pyproject's requirements as they are now, if downloaded; never
    downloads."""
    return complete(wheels_dir(), MARKER, lambda path: any(path.glob("*.whl")))


def ensure_wheels() -> Built:
    """The wheelhouse, downloaded first if missing: wheels for the image's Python (CPython 3.11
    on this machine's architecture, glibc), whatever Python runs this."""
    machine = platform.machine()
    binary = ["--only-binary=:all:", "--implementation", "cp", "--python-version", "3.11",
              *(argument for tag in (f"manylinux_2_36_{machine}", f"manylinux2014_{machine}",
                                     f"linux_{machine}") for argument in ("--platform", tag))]

    def download(directory: Path) -> None:
        try:
            run_step([sys.executable, "-m", "pip", "download", "--disable-pip-version-check",
                      "--dest", str(directory), *binary, *requirements()],
                     "download the image's wheels", DockerUnavailable)
        except DockerUnavailable:
            if sys.version_info[:2] != (3, 11):
                raise
            # A dependency with no wheel for 3.11: build it here, where the Python is 3.11 too.
            run_step([sys.executable, "-m", "pip", "wheel", "--disable-pip-version-check",
                      "--wheel-dir", str(directory), *requirements()],
                     "build the image's wheels", DockerUnavailable)

    return built_once(wheels_dir(), MARKER, download, {"requirements": requirements()},
                      lambda path: any(path.glob("*.whl")))
