"""PrusaLink 0.8.1, Prusa's print server, run headless against a printer's pty, as a test's host.

    with PrusaLink(venv_python, "/dev/pts/3", log=tmp_path / "prusalink.log") as link:
        link.wait_for_state({"IDLE", "READY"}, timeout=60)
        link.upload("job.gcode", data, print_after=True)
        ...

It runs from its own venv (tests/hosts/venvs.PRUSALINK, which `python -m tests.hosts.install`
builds) as `prusalink -f -d -c <ini>`: in the foreground (`-f`: no daemon, no setuid to `pi`)
and logging every serial line (`-d`) to one file. Everything it writes lives in its data dir:
the two config files written here, its storage (`PrusaLink gcodes/`, where uploads go) and its
power-panic file. PrusaLink refuses a storage directory under /tmp, /dev, /sys or /proc
(prusa/link/const.py BLACKLISTED_PATHS, a plain startswith()), so the data dir is made under
~/.cache/fake-marlin/prusalink-runs/ and removed at stop.

The HTTP API is spoken with the standard library: urllib, the X-Api-Key header, and a multipart
body built by hand for `POST /api/files/local`.

What to expect of it (0.8.1): `/api/v1/status` is 503 for ~5 s, then BUSY, then IDLE ~9 s after
the start (PRINTER_BOOT_WAIT: 8 s after it opens the port, it probes with `PRUSA Fir` and
`M862.2 Q`, outside its -d log). Once the port is accepted it marks everything queued meanwhile
as done without sending it (serial_queue.py _flush_queues), often `M155 S2 C7` too: then no
temperatures reach its status until its watchdog sends it again 60-70 s later
(auto_telemetry.py). A print ends in FINISHED at once after its last line and M77, without a
`job` in the status, and is IDLE again 11 s later (PRINT_END_TIMEOUT). SIGINT stops it in ~1-5 s.
"""

import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
import urllib.error
import urllib.request
import uuid
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar

USERNAME = "maker"
PASSWORD = "printer123"
API_KEY = "fake-marlin-key"
# prusa/link/web/lib/auth.py: the digest of `user:Administrator:password` (REALM "Administrator")
REALM = "Administrator"
PRINTER_NAME = "fake-marlin"
BLACKLISTED = ("/tmp", "/dev", "/sys", "/proc")  # prusa/link/const.py BLACKLISTED_PATHS
START_TIMEOUT = 30.0  # seconds for its HTTP server to answer at all (it does in about 1 s)
STOP_TIMEOUT = 20.0  # it stops in about 5 s (the shutdown G-code, then its threads)
HTTP_TIMEOUT = 10.0
# PrusaLink shuts down cleanly only on KeyboardInterrupt, and a process started from a shell
# that ignores SIGINT (a `&` job) inherits SIG_IGN: restore Python's handler before main().
BOOT = (
    "import signal, sys\n"
    "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
    "from prusa.link.__main__ import main\n"
    "sys.argv[0] = 'prusalink'\n"
    "sys.exit(main())\n"
)

T = TypeVar("T")


def runs_directory() -> Path:
    """Where the data dirs go: under the user's cache (the venvs' may be moved under /tmp)."""
    return Path.home() / ".cache" / "fake-marlin" / "prusalink-runs"


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def digest(username: str = USERNAME, password: str = PASSWORD) -> str:
    """The settings file's `digest`: md5 of `user:Administrator:password`."""
    return hashlib.md5(f"{username}:{REALM}:{password}".encode()).hexdigest()


def write_config(data_dir: Path, serial_port: str | os.PathLike[str], http_port: int) -> Path:
    """PrusaLink's two config files in `data_dir`, for the printer on `serial_port` and HTTP on
    127.0.0.1:`http_port`; returns prusalink.ini (its `-c`).

    prusalink.ini (prusa/link/config.py Config): the data dir, the port (any path, a symlink to
    a pty too: it is realpath()ed; the baud rate is always 115200), HTTP, no camera detection.
    prusa_printer_settings.ini (config.py Settings): an MK3S with a user, its digest and an API
    key, so the first-run wizard is skipped (is_wizard_needed), and no Connect token, so nothing
    goes to Prusa Connect. PrusaLink rewrites this file at every start, so a run writes it anew.
    """
    data_dir = Path(data_dir).resolve()
    if str(data_dir).startswith(BLACKLISTED):
        raise ValueError(f"PrusaLink refuses a data dir under {', '.join(BLACKLISTED)}: {data_dir}")
    data_dir.mkdir(parents=True, exist_ok=True)
    ini = data_dir / "prusalink.ini"
    ini.write_text(
        "[daemon]\n"
        f"data_dir = {data_dir}\n"
        "pid_file = ./prusalink.pid\n"
        "power_panic_file = ./power_panic\n"
        "threshold_file = ./threshold.data\n"
        "\n[printer]\n"
        f"port = {os.fspath(serial_port)}\n"
        "baudrate = 115200\n"
        "reset_disabling = False\n"
        "settings = ./prusa_printer_settings.ini\n"
        "directory = ./PrusaLink gcodes\n"
        "\n[http]\n"
        "address = 127.0.0.1\n"
        f"port = {http_port}\n"
        "link_info = False\n"
        "\n[cameras]\n"
        "auto_detect = False\n"
    )
    (data_dir / "prusa_printer_settings.ini").write_text(
        "[printer]\n"
        "type = MK3S\n"
        f"name = {PRINTER_NAME}\n"
        "location = fake-marlin\n"
        "farm_mode = False\n"
        "\n[network]\n"
        "hostname =\n"
        "\n[service::local]\n"
        "enable = 1\n"
        f"username = {USERNAME}\n"
        f"digest = {digest()}\n"
        f"api_key = {API_KEY}\n"
        "\n[service::connect]\n"
        "hostname = connect.prusa3d.com\n"
        "tls = True\n"
        "port = 0\n"
        "token =\n"
    )
    return ini


class PrusaLinkError(AssertionError):
    """PrusaLink did not do what was waited for, or died; the message ends with its log tail."""


class PrusaLink:
    """One PrusaLink process against one serial port, from `start()` (or `with`) to `stop()`."""

    def __init__(self, python: Path, serial_port: str | os.PathLike[str], log: Path,
                 http_port: int | None = None, data_dir: Path | None = None) -> None:
        self.python = python
        self.serial_port = os.fspath(serial_port)
        self.log = log  # its stdout and stderr: the -d log, every line sent and received
        self.http_port = http_port or free_port()
        self.url = f"http://127.0.0.1:{self.http_port}"
        self._own_data_dir = data_dir is None
        if data_dir is None:
            runs = runs_directory()
            runs.mkdir(parents=True, exist_ok=True)
            data_dir = Path(tempfile.mkdtemp(prefix="run-", dir=runs))
        self.data_dir = data_dir
        self.process: subprocess.Popen[bytes] | None = None
        self.returncode: int | None = None

    # -- the process ------------------------------------------------------------------------
    def start(self) -> "PrusaLink":
        ini = write_config(self.data_dir, self.serial_port, self.http_port)
        self.log.parent.mkdir(parents=True, exist_ok=True)
        with open(self.log, "wb") as log:
            # A session of its own: a Ctrl-C at the terminal reaches the test, which stops it.
            self.process = subprocess.Popen(
                [str(self.python), "-c", BOOT, "-f", "-d", "-c", str(ini)],
                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                cwd=self.data_dir, start_new_session=True,
            )
        self.wait_for(lambda: self._answers() or None, START_TIMEOUT, "its HTTP server to answer")
        return self

    def stop(self) -> int | None:
        """Stop it as Ctrl-C does (it then sends `M117 ~PrusaLink stopped`, `M552 P0.0.0.0` and
        `M155 S0 C0`), killing it if it takes over STOP_TIMEOUT; remove its data dir. Its exit
        code (0 for a clean stop), or None if it never started."""
        process = self.process
        if process is not None and self.returncode is None:
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
            try:
                self.returncode = process.wait(timeout=STOP_TIMEOUT)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
                self.returncode = -signal.SIGKILL
        if self._own_data_dir:
            shutil.rmtree(self.data_dir, ignore_errors=True)
        return self.returncode

    def __enter__(self) -> "PrusaLink":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    # -- its log ----------------------------------------------------------------------------
    def log_lines(self) -> list[str]:
        try:
            return self.log.read_text(errors="replace").splitlines()
        except FileNotFoundError:
            return []

    def serial_log(self) -> list[str]:
        """What it sent and received on the serial line, from its -d log: `Send: b'...'` and
        `Recv: ...`, each with its time. (The port probe writes and reads outside this log.)"""
        return [_short(line) for line in self.log_lines() if "]: Send: " in line or "]: Recv: " in line]

    def problems(self) -> list[str]:
        """Its ERROR and CRITICAL lines, and the WARNING lines that are no thread dump (an
        'interesting log' repeats earlier lines, prefixed `Was[`, and every thread's stack)."""
        found = []
        for line in self.log_lines():
            if "service_unavailable()" in line:  # the 503 of each request before the printer is there
                continue
            if " ERROR " in line or " CRITICAL " in line or (
                    " WARNING " in line and "]: Was[" not in line and "]:  " not in line
                    and "stack trace:" not in line):
                found.append(_short(line))
        return found

    def diagnosis(self, lines: int = 40) -> str:
        """What a failure message carries: its warnings and errors, the end of its serial
        exchange and the end of its log, and where the whole log is."""
        problems, exchange = self.problems(), self.serial_log()
        if self.process is None:
            state = "never started"
        else:
            state = "running" if self.alive else f"exited {self.process.poll()}"
        return "\n".join([
            f"--- PrusaLink ({state}), its whole log: {self.log}",
            f"--- its warnings and errors ({_last(lines, problems)}):", *problems[-lines:],
            f"--- its serial exchange after the probe ({_last(lines, exchange)}):",
            *exchange[-lines:],
            "--- its log (the last 15 lines):",
            *(_short(line) for line in self.log_lines()[-15:]),
        ])

    # -- its HTTP API -----------------------------------------------------------------------
    def request(self, method: str, path: str, body: bytes | None = None,
                headers: dict[str, str] | None = None) -> tuple[int, bytes]:
        """(HTTP status, body) of one request with the API key; 0 and b"" when nothing answers."""
        request = urllib.request.Request(
            self.url + path, data=body, method=method,
            headers={"X-Api-Key": API_KEY, "Accept": "application/json", **(headers or {})})
        try:
            with urllib.request.urlopen(request, timeout=HTTP_TIMEOUT) as response:
                return response.status, response.read()
        except urllib.error.HTTPError as error:
            return error.code, error.read()
        except (urllib.error.URLError, ConnectionError, TimeoutError, socket.timeout):
            return 0, b""

    def get_json(self, path: str) -> Any:
        """The JSON a GET answers with 200, else None (503 while the printer is not there yet,
        204 for /api/v1/job without a job)."""
        status, body = self.request("GET", path)
        return json.loads(body) if status == 200 and body else None

    def status(self) -> dict[str, Any] | None:
        """GET /api/v1/status (`printer.state`: BUSY, IDLE, READY, PRINTING, FINISHED...)."""
        return self.get_json("/api/v1/status")

    def state(self) -> str | None:
        status = self.status()
        return None if status is None else status.get("printer", {}).get("state")

    def info(self) -> dict[str, Any] | None:
        """GET /api/v1/info: the serial number (`serial`), `nozzle_diameter`, the name..."""
        return self.get_json("/api/v1/info")

    def version(self) -> dict[str, Any] | None:
        """GET /api/version: PrusaLink's and the printer's firmware (`firmware`)."""
        return self.get_json("/api/version")

    def upload(self, name: str, data: bytes, print_after: bool = True) -> tuple[int, bytes]:
        """POST /api/files/local, multipart (`file`, and `print=true`): it stores the file in
        its storage and, with print_after, starts the print in the same request (201)."""
        boundary = f"fake-marlin-{uuid.uuid4().hex}"
        parts = [
            (f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="{name}"\r\n'
             "Content-Type: application/octet-stream\r\n\r\n").encode() + data + b"\r\n",
            (f'--{boundary}\r\nContent-Disposition: form-data; name="print"\r\n\r\n'
             f"{'true' if print_after else 'false'}\r\n").encode(),
            f"--{boundary}--\r\n".encode(),
        ]
        body = b"".join(parts)
        return self.request("POST", "/api/files/local", body, {
            "Content-Type": f"multipart/form-data; boundary={boundary}",
            "Content-Length": str(len(body)),
        })

    # -- waiting ----------------------------------------------------------------------------
    def wait_for(self, condition: Callable[[], T | None], timeout: float,
                 what: str | Callable[[], str], interval: float = 0.2) -> T:
        """The first value of `condition()` that is not None, within `timeout` seconds; else
        PrusaLinkError saying what was waited for (`what`, or what it says then), with its
        diagnosis."""
        deadline = time.monotonic() + timeout
        while True:
            if self.process is not None and self.process.poll() is not None:
                raise PrusaLinkError(f"PrusaLink exited ({self.process.returncode}) while waiting "
                                     f"for {_say(what)}\n{self.diagnosis()}")
            if (value := condition()) is not None:
                return value
            if time.monotonic() > deadline:
                raise PrusaLinkError(f"no {_say(what)} within {timeout} s\n{self.diagnosis()}")
            time.sleep(interval)

    def wait_for_state(self, states: Iterable[str], timeout: float,
                       seen: list[str] | None = None,
                       watch: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
        """The status once `printer.state` is one of `states`; each new state it passes through
        is appended to `seen`, and `watch` sees every status read meanwhile."""
        wanted = set(states)
        record = seen if seen is not None else []

        def reached() -> dict[str, Any] | None:
            status = self.status()
            if status is not None and watch is not None:
                watch(status)
            state = None if status is None else status.get("printer", {}).get("state")
            if state is not None and (not record or record[-1] != state):
                record.append(state)
            return status if state in wanted else None

        return self.wait_for(reached, timeout, lambda: f"state {' or '.join(sorted(wanted))} "
                             f"(states seen: {record})")

    def _answers(self) -> bool:
        status, _ = self.request("GET", "/api/version")
        return status != 0


def _last(lines: int, found: list[str]) -> str:
    return f"the last {lines} of {len(found)}" if len(found) > lines else f"{len(found)}"


def _say(what: str | Callable[[], str]) -> str:
    return what if isinstance(what, str) else what()


def _short(line: str, width: int = 300) -> str:
    """A log line without its `{module.function():line}` part, cut to `width`."""
    if " {" in line and "} [" in line:
        head, _, rest = line.partition(" {")
        line = head + " [" + rest.partition("} [")[2]
    return line if len(line) <= width else line[:width] + "..."
