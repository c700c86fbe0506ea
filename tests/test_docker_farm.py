"""The container farm as a user deploys it (docs/farm.md): the image built from this checkout,
docker-compose.yml brought up with Compose 1 and docker-stack.yml deployed on a one-node swarm,
each 3 containers of 20 printers: every printer answers on its port, a job streamed to a printer
in each container runs exactly once (its journal, copied out of the container, verified),
printers of different containers say different UUIDs, and taking the farm down leaves nothing.

Docker is set up by `python -m tests.hosts.install` (tests/hosts/docker.py); the tests start the
daemon if it is installed but not running, and skip saying why where Docker cannot run. The
image is built once a session, offline, from the cached wheels and base image. The farm takes
the shipped host ports (9000-9019, 9100-9119, 9200-9219): a lock serialises the farms of test
sessions that run at once, and whatever an earlier session left (names starting `fmtest-`) is
taken down first.
"""

import contextlib
import fcntl
import json
import os
import re
import shutil
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from tests.hosts import apt, docker
from tests.hosts.install import not_installed

# Builds an image and starts containers: the slowest tests there are (about a minute each).
pytestmark = pytest.mark.e2e

CHECKOUT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
IMAGE = "fake-marlin:pytest"
PREFIX = "fmtest-"  # the compose projects and stacks these tests make
PRINTERS = 20
# node: (its first host port, its first printer number), as both shipped files have them.
NODES = {"node-1": (9000, 1), "node-2": (9100, 21), "node-3": (9200, 41)}
# The printer a job is streamed to in each node (its index there), and the one asked for M115.
PRINTED = {"node-1": 3, "node-2": 7, "node-3": 19}
ASKED = 1
JOURNAL = "/tmp/journal-{n}"
# The shipped command, run as it is with a journal added: the override's entrypoint appends it.
# ($$ is a literal $ to Compose's and the stack's variable substitution.)
ENTRYPOINT = ["sh", "-c", f'exec fake-marlin "$$@" --journal {JOURNAL}', "fake-marlin"]


def unavailable() -> str | None:
    """Why Docker cannot run the farm here, or None: after starting the daemon if need be."""
    for tool in (apt.DOCKER, apt.COMPOSE):
        if apt.find(tool) is None:
            return not_installed(f"{tool.label} (Debian's {tool.package})")
    try:
        docker.ensure_daemon()
    except docker.DockerUnavailable as error:
        return f"Docker cannot run here: {error}"
    if not docker.base_image_present():
        return not_installed(f"the {docker.BASE_IMAGE} base image")
    if docker.find_wheels() is None:
        return not_installed("the wheelhouse for pyproject.toml's requirements as they are now")
    return None


def run(command: list[str | Path], timeout: float = 180, check: bool = True,
        env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    done = subprocess.run([str(part) for part in command], capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL, env=env)
    if check:
        assert done.returncode == 0, (
            f"{' '.join(map(str, command))} exit {done.returncode}:\n{done.stdout}{done.stderr}")
    return done


def docker_cli(*args: str | Path, timeout: float = 180,
               check: bool = True) -> subprocess.CompletedProcess[str]:
    client = docker.cli()
    assert client is not None
    return run([client, *args], timeout=timeout, check=check)


@pytest.fixture(scope="session")
def image(tmp_path_factory: pytest.TempPathFactory) -> str:
    """The image, built once a session from this checkout's Dockerfile and files with no
    network: the context is the checkout (its .dockerignore applies) plus the cached wheels."""
    if (reason := unavailable()) is not None:
        pytest.skip(reason)
    wheels = docker.find_wheels()
    assert wheels is not None
    context = tmp_path_factory.mktemp("docker") / "context"
    shutil.copytree(CHECKOUT, context, symlinks=True, ignore=shutil.ignore_patterns(
        ".git", ".venv", "__pycache__", "*.egg-info", ".*_cache", ".hypothesis", "build",
        "node_modules", "wheels"))
    shutil.copytree(wheels.path, context / "wheels")
    before = docker_cli("image", "inspect", "--format", "{{.Id}}", IMAGE, check=False)
    docker_cli("build", "--tag", IMAGE, "--build-arg", "OFFLINE=1", context, timeout=600)
    after = docker_cli("image", "inspect", "--format", "{{.Id}}", IMAGE).stdout.strip()
    if before.returncode == 0 and before.stdout.strip() != after:  # the last session's, untagged
        docker_cli("image", "rm", before.stdout.strip(), check=False)
    return IMAGE


@contextlib.contextmanager
def farm_ports() -> Iterator[None]:
    """The farm's host ports for this test alone: another session's farm waits (flock); ports
    that something else holds skip the test."""
    docker.cache().mkdir(parents=True, exist_ok=True)
    with open(docker.cache() / "farm.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        take_down_leftovers()
        if taken := [port for port in all_ports() if not port_free(port)]:
            pytest.skip(f"the farm's host ports are in use by another program: {taken[:5]}")
        yield


def all_ports() -> list[int]:
    return [first + i for first, _ in NODES.values() for i in range(PRINTERS)]


def port_free(port: int) -> bool:
    with socket.socket() as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("0.0.0.0", port))
        except OSError:
            return False
    return True


def take_down_leftovers() -> None:
    """What an earlier session of these tests left running (killed before its cleanup)."""
    labels = docker_cli("ps", "-a", "--format", '{{.Label "com.docker.compose.project"}}').stdout
    for project in {name for name in labels.split() if name.startswith(PREFIX)}:
        run(["docker-compose", "-p", project, "-f", CHECKOUT / "docker-compose.yml", "down",
             "--volumes", "--remove-orphans", "--timeout", "5"], check=False)
    if swarm_state() == ("active", True):
        for stack in docker_cli("stack", "ls", "--format", "{{.Name}}").stdout.split():
            if stack.startswith(PREFIX):
                remove_stack(stack)


def unique_name() -> str:
    return f"{PREFIX}{os.getpid()}-{uuid.uuid4().hex[:6]}"


def write_override(path: Path, version: str | None) -> Path:
    services = {node: {"entrypoint": ENTRYPOINT} for node in NODES}
    path.write_text(json.dumps({**({"version": version} if version else {}),
                                "services": services}))
    return path


# -- what is checked of a running farm, either way -----------------------------------------------

def answers(port: int, deadline: float) -> bool:
    """Whether the printer on host port `port` greets a connection and answers M105 with ok,
    trying until `deadline` (a published port accepts and closes until its container listens)."""
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=5) as link:
                received = b""
                while b"start\n" not in received:
                    if not (chunk := link.recv(4096)):
                        raise ConnectionError("closed")
                    received += chunk
                link.sendall(b"M105\n")
                received = received.split(b"start\n", 1)[1]
                while not any(line.startswith(b"ok") for line in received.split(b"\n")[:-1]):
                    if not (chunk := link.recv(4096)):
                        raise ConnectionError("closed")
                    received += chunk
                return True
        except OSError:
            time.sleep(0.5)
    return False


def write_job(path: Path) -> int:
    lines = ["; a small job for one printer of the farm", "G28", "G1 Z0.3 F600",
             *(f"G1 X{n % 10 + 1} Y{n % 7 + 1} E{n / 100:.2f} F6000" for n in range(100)), "M400"]
    path.write_text("\n".join(lines) + "\n")
    return len(lines) - 1


def uuid_of(port: int) -> str:
    done = run([BIN / "fake-marlin-host", "send", f"socket://127.0.0.1:{port}", "M115",
                "--protocol", "marlin"], timeout=60)
    found = re.search(r"UUID:([0-9a-f-]{36})", done.stdout)
    assert found, done.stdout
    return found.group(1)


def check_farm(container_of: Callable[[str], str], workdir: Path) -> None:
    """All 60 printers answer; a job prints exactly once on one printer in each container;
    printers in different containers have different UUIDs."""
    deadline = time.monotonic() + 90
    with ThreadPoolExecutor(max_workers=20) as pool:
        answered = dict(zip(all_ports(), pool.map(lambda port: answers(port, deadline),
                                                  all_ports())))
    assert all(answered.values()), [port for port, ok in answered.items() if not ok]

    job = workdir / "job.gcode"
    commands = write_job(job)

    def print_on(node: str) -> tuple[str, subprocess.CompletedProcess[str]]:
        first_port, first_number = NODES[node]
        port, number = first_port + PRINTED[node], first_number + PRINTED[node]
        printed = run([BIN / "fake-marlin-host", "print", f"socket://127.0.0.1:{port}", job,
                       "--protocol", "marlin", "--json"], timeout=180)
        journal = workdir / f"journal-{number}"
        docker_cli("cp", f"{container_of(node)}:{JOURNAL.format(n=number)}", journal)
        return printed.stdout, run([BIN / "fake-marlin", "verify", job, journal], check=False)

    with ThreadPoolExecutor(max_workers=len(NODES)) as pool:
        results = dict(zip(NODES, pool.map(print_on, NODES)))
    for node, (summary, verified) in results.items():
        assert json.loads(summary)["commands"] == commands, (node, summary)
        assert verified.returncode == 0, (node, verified.stdout, verified.stderr)
        assert verified.stdout.startswith(
            f"OK: each of the {commands} job commands ran once, in order"), (node, verified.stdout)

    uuids = {node: uuid_of(first_port + ASKED) for node, (first_port, _) in NODES.items()}
    assert len(set(uuids.values())) == len(NODES), uuids


# -- Compose 1 -----------------------------------------------------------------------------------

def test_the_compose_farm_prints_once_per_container_and_comes_down_whole(
        image: str, tmp_path: Path) -> None:
    project = unique_name()
    environment = {**os.environ, "FAKE_MARLIN_IMAGE": image}
    files: list[str | Path] = ["-f", CHECKOUT / "docker-compose.yml",
                               "-f", write_override(tmp_path / "journal.json", None)]

    def compose(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
        return run(["docker-compose", "-p", project, *files, *args], env=environment,
                   check=check, timeout=300)

    with farm_ports():
        try:
            compose("up", "-d", "--no-build")

            def container_of(node: str) -> str:
                return compose("ps", "-q", node).stdout.strip()

            assert all(container_of(node) for node in NODES)
            check_farm(container_of, tmp_path)
            compose("down", "--timeout", "10")
            label = f"label=com.docker.compose.project={project}"
            assert docker_cli("ps", "-a", "-q", "--filter", label).stdout.strip() == ""
            assert docker_cli("network", "ls", "-q", "--filter", label).stdout.strip() == ""
            assert all(port_free(port) for port in all_ports())
        finally:
            compose("down", "--volumes", "--remove-orphans", "--timeout", "5", check=False)


# -- a stack on a one-node swarm -----------------------------------------------------------------

def swarm_state() -> tuple[str, bool]:
    """(LocalNodeState, whether this node is a manager)."""
    state, manager = docker_cli(
        "info", "--format", "{{.Swarm.LocalNodeState}} {{.Swarm.ControlAvailable}}").stdout.split()
    return state, manager == "true"


def stack_containers(stack: str) -> list[str]:
    return docker_cli("ps", "-a", "-q", "--filter",
                      f"label=com.docker.stack.namespace={stack}").stdout.split()


def remove_stack(stack: str) -> None:
    """`docker stack rm`, then wait for its containers to go (the command does not wait)."""
    docker_cli("stack", "rm", stack, check=False)
    deadline = time.monotonic() + 60
    while stack_containers(stack) and time.monotonic() < deadline:
        time.sleep(0.5)


@contextlib.contextmanager
def one_node_swarm() -> Iterator[None]:
    """This machine as a swarm manager: the one it is, or a swarm made here and left after."""
    state, manager = swarm_state()
    if state == "active" and not manager:
        pytest.skip("this machine is a swarm worker: a stack is deployed from a manager")
    if state == "active":
        yield
        return
    had_gwbridge = docker_cli("network", "inspect", "docker_gwbridge", check=False).returncode == 0
    # The loopback address: a swarm of this machine alone, advertised on no network.
    docker_cli("swarm", "init", "--advertise-addr", "127.0.0.1")
    try:
        yield
    finally:
        docker_cli("swarm", "leave", "--force", check=False)
        if not had_gwbridge:  # swarm init's bridge, which leaving keeps
            docker_cli("network", "rm", "docker_gwbridge", check=False)


def test_the_stack_on_a_one_node_swarm_prints_once_per_container_and_comes_down_whole(
        image: str, tmp_path: Path) -> None:
    stack = unique_name()
    override = write_override(tmp_path / "journal.json", "3.8")
    with farm_ports(), one_node_swarm():
        try:
            run([docker.cli() or "docker", "stack", "deploy", "--resolve-image", "never",
                 "-c", CHECKOUT / "docker-stack.yml", "-c", override, stack],
                env={**os.environ, "FAKE_MARLIN_IMAGE": image})

            def container_of(node: str) -> str:
                deadline = time.monotonic() + 60
                while time.monotonic() < deadline:
                    if running := docker_cli("ps", "-q", "--filter",
                                             f"label=com.docker.swarm.service.name={stack}_{node}"
                                             ).stdout.split():
                        return running[0]
                    time.sleep(0.5)
                raise AssertionError(f"no running container of {stack}_{node}")

            assert all(container_of(node) for node in NODES)
            check_farm(container_of, tmp_path)
            remove_stack(stack)
            assert stack_containers(stack) == []
            assert docker_cli("service", "ls", "-q", "--filter",
                              f"label=com.docker.stack.namespace={stack}").stdout.strip() == ""
            assert stack not in docker_cli("stack", "ls", "--format", "{{.Name}}").stdout.split()
        finally:
            remove_stack(stack)
