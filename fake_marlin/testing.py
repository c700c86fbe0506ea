"""Virtual printers for a host's own test suite: each a real `fake-marlin` process on a real pty.

    from fake_marlin.testing import running_printer

    with running_printer(protocol="marlin", speed=100) as printer:
        host = MyHost(printer.port)            # any host: threaded, trio, asyncio, a script
        host.print("job.gcode")
        assert printer.journal == [...]        # the commands the printer executed
        printer.control.inject(kind="thermal-runaway")

A print farm's tests can have many printers in one process:

    with running_printer(protocol="marlin", printers=50) as farm:
        hosts = [MyHost(farm.printer(n).port) for n in range(1, 51)]
        ...
        assert farm.printer(7).journal == [...]

With pytest the same comes as fixtures (`fake_printer`, `fake_printer_factory`; see
fake_marlin.pytest_plugin). The printer runs as its own process, exactly the program users run,
so it serves hosts in threads and in any event loop alike, and never competes with the test for
the interpreter. A printer that crashes (or would not start) raises PrinterCrashed with what it
printed on stderr.

For a trio host's own protocol tests there is also a printer in memory, in the test's own event
loop, so that trio's autojump clock runs its simulated time:

    async def test_my_host(autojump_clock):
        async with memory_printer(protocol="marlin") as printer:
            stream = printer.open()            # a trio byte stream, opened as a port is
            await my_host.print(stream, job)   # minutes of printing in milliseconds
            assert printer.journal == job
"""

import dataclasses
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
from collections.abc import AsyncIterator, Iterator, Mapping, Sequence
from contextlib import asynccontextmanager, contextmanager
from pathlib import Path
from typing import TypedDict, Unpack

import trio
import trio.testing

from fake_marlin.wire.ultimaker_variants import variants_of
from fake_marlin.emulator.control.client import ControlClient
from fake_marlin.emulator.faults.layer import FaultConfig
from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.link.memory import HostEnd, MemoryLink
from fake_marlin.emulator.firmware import Firmware, load_profile
from fake_marlin.emulator.firmware.quirks import read_quirks
from fake_marlin.emulator.printer.model import Printer
from fake_marlin.emulator.tables import TableReader
from fake_marlin.emulator.scenario.definition import PrinterSetup, add_fault_table, load
from fake_marlin.emulator.server.lifecycle import PrinterServer, ServerConfig

__all__ = [
    "FakePrinter",
    "FarmPrinter",
    "MemoryPrinter",
    "PrinterCrashed",
    "PrinterOptions",
    "memory_printer",
    "running_printer",
    "serve_in_memory",
    "start_printer",
]

START_TIMEOUT = 30.0  # seconds for the program to print its pty path
STOP_TIMEOUT = 10.0
DEFAULT_PROGRAM = (sys.executable, "-m", "fake_marlin.emulator.cli")


class PrinterCrashed(AssertionError):
    """The printer process failed: it would not start, or it died, or left a traceback."""


class FakePrinter:
    """One running virtual printer. `port` is the path a host opens (it follows the pty when a
    `disconnect` fault brings the line back under a new name; `ports` lists every one announced),
    `journal` the commands executed so far, `control` the control channel.

    Once the printer has died on its own, `journal` and `control` raise PrinterCrashed until
    `stop(check=False)` acknowledges it (then `journal` is what it had executed)."""

    def __init__(
        self,
        args: Sequence[str],
        directory: Path,
        keep_directory: bool,
        program: Sequence[str] | None = None,
        link: Path | None = None,
        printers: int = 1,
        first_number: int = 1,
    ) -> None:
        self.directory = directory
        self.link = link  # the symlink to the pty, if one was asked for
        self.printers = printers
        self.first_number = first_number  # the number of its first printer (first_number=)
        self._keep_directory = keep_directory
        self._journal_path = directory / ("journal.log" if printers == 1 else "journal-{n}.log")
        self._control_path = directory / "control.sock"
        self._stderr_path = directory / "stderr.log"
        self._control: ControlClient | None = None
        self._stopped = False
        # stderr and each printer's journal, kept at stop
        self._final: tuple[str, list[list[str]]] | None = None
        self._farm_controls: dict[int, ControlClient] = {}
        self.returncode: int | None = None
        command = [
            *(program or DEFAULT_PROGRAM),
            "--journal",
            str(self._journal_path),
            "--control",
            str(self._control_path),
            *args,
        ]
        self.args = tuple(command)
        with open(self._stderr_path, "wb") as stderr:
            self.process = subprocess.Popen(
                command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=stderr, text=True
            )
        self.ports: list[str] = []  # every pty path the printer announced, the first first
        self._announced = threading.Condition()
        self._stdout_closed = False
        threading.Thread(target=self._read_paths, name="fake-printer-stdout", daemon=True).start()
        if not self._wait_for(printers, START_TIMEOUT):
            self.stop(check=False)
            raise PrinterCrashed(
                f"fake-marlin did not start ({' '.join(self.args)}):\n{self.stderr}"
            )

    def _read_paths(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            with self._announced:
                self.ports.append(line.strip())
                self._announced.notify_all()
        with self._announced:
            self._stdout_closed = True
            self._announced.notify_all()

    def _wait_for(self, number: int, timeout: float) -> bool:
        with self._announced:
            self._announced.wait_for(
                lambda: len(self.ports) >= number or self._stdout_closed, timeout
            )
            return len(self.ports) >= number

    # -- what a test reads ----------------------------------------------------------------
    @property
    def port(self) -> str:
        """The pty to open (its /dev/pts path): the one announced last."""
        return self.ports[-1]

    def wait_for_port(self, number: int, timeout: float = 10.0) -> str:
        """The `number`-th pty path the printer announced (1: the first), waiting for it: a
        `disconnect` fault's line comes back announced anew, perhaps under the same name."""
        if not self._wait_for(number, timeout):
            self._check_alive()
            raise TimeoutError(
                f"the printer announced {len(self.ports)} ports in {timeout} s, not {number}"
            )
        return self.ports[number - 1]

    @property
    def journal(self) -> list[str]:
        """Every command the printer has executed, in order, as it executed it."""
        self._check_alive()
        if self._final is not None:
            return list(self._final[1][0])
        return self._read_journal()

    def _read_journal(self, number: int = 1) -> list[str]:
        path = Path(str(self._journal_path).replace("{n}", str(number)))
        try:
            return path.read_text(encoding="ascii", errors="replace").splitlines()
        except FileNotFoundError:
            return []

    def printer(self, number: int) -> "FarmPrinter":
        """Printer `number` (from 1, or first_number=) of a process started with printers=N."""
        first, last = self.first_number, self.first_number + self.printers - 1
        if not first <= number <= last:
            raise IndexError(f"printer {number}: this process serves printers {first} to {last}")
        return FarmPrinter(self, number)

    @property
    def control(self) -> ControlClient:
        """The control channel: state(), inject(**fault), set_temperature(), set_target(), say()."""
        self._check_alive()
        if self._control is None:
            self._control = ControlClient(str(self._control_path))
        return self._control

    @property
    def stderr(self) -> str:
        """What the printer printed on stderr (all of it, once it has stopped)."""
        if self._final is not None:
            return self._final[0]
        try:
            return self._stderr_path.read_text(errors="replace")
        except FileNotFoundError:
            return ""

    @property
    def alive(self) -> bool:
        return self.process.poll() is None

    def _check_alive(self) -> None:
        if not self._stopped and self.process.poll() is not None:
            raise PrinterCrashed(self._crash_report())

    def _crash_report(self) -> str:
        return f"the printer exited with code {self.process.returncode}:\n{self.stderr}"

    # -- the end --------------------------------------------------------------------------
    def stop(self, check: bool = True) -> None:
        """Stop the printer as Ctrl-C does. With `check`, raise PrinterCrashed if it had died
        before, or did not stop cleanly, or printed a traceback."""
        if self._stopped:
            return
        died_on_its_own = self.process.poll() is not None
        self._stopped = True
        for client in [self._control, *self._farm_controls.values()]:
            if client is not None:
                client.close()
        if not died_on_its_own:
            self.process.send_signal(signal.SIGINT)
        try:
            self.returncode = self.process.wait(timeout=STOP_TIMEOUT)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.returncode = self.process.wait()
            if check:
                raise PrinterCrashed(
                    f"the printer did not stop within {STOP_TIMEOUT} s:\n{self.stderr}"
                )
        report = self._crash_report()
        failed = died_on_its_own or self.returncode != 0 or "Traceback" in self.stderr
        self._final = (
            self.stderr, [self._read_journal(n) for n in
                          range(self.first_number, self.first_number + self.printers)]
        )
        if not self._keep_directory:
            shutil.rmtree(self.directory, ignore_errors=True)
        if check and failed:
            raise PrinterCrashed(report)

    def __enter__(self) -> "FakePrinter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop(check=exc[0] is None)

    def __repr__(self) -> str:
        port = self.ports[-1] if self.ports else None
        return f"<FakePrinter {port} {'running' if self.alive else 'stopped'}>"


class FarmPrinter:
    """One printer of a FakePrinter process that serves several (`printers=N`): its port,
    journal and control channel."""

    def __init__(self, process: FakePrinter, number: int) -> None:
        self.process = process
        self.number = number

    @property
    def port(self) -> str:
        return self.process.ports[self.number - self.process.first_number]

    @property
    def journal(self) -> list[str]:
        process = self.process
        process._check_alive()
        if process._final is not None:
            return list(process._final[1][self.number - process.first_number])
        return process._read_journal(self.number)

    @property
    def control(self) -> ControlClient:
        process = self.process
        process._check_alive()
        if self.number not in process._farm_controls:
            process._farm_controls[self.number] = ControlClient(
                str(process._control_path), printer=self.number
            )
        return process._farm_controls[self.number]


class PrinterOptions(TypedDict, total=False):
    """A printer's settings, as `fake-marlin`'s command line takes them."""

    protocol: str  # auto (default), marlin, ultimaker, repetier, commstack, g2core
    # With protocol ultimaker: the protocol lab's variants, "ack,crc8" or names (the host's
    # ClientOptions(variants=...) must be the same; docs/protocol-lab.md)
    variants: "str | Sequence[str]"
    firmware: str | os.PathLike[str]  # marlin (default), prusa, klipper...; or a profile file
    quirks: Mapping[str, object]  # the firmware's quirks to switch, e.g. {"ok_before_output": True}
    speed: float  # simulated time runs this many times faster than real time (default 1)
    extruders: int
    sd_dir: str | os.PathLike[str]  # the directory behind the SD card (default: a temporary one)
    advanced_ok: bool
    baud: int | bool  # pace the line at this rate; True: at the rate the host sets
    latency_ms: float
    jitter_ms: float
    faults: Sequence[Mapping[str, object]]  # tables as a scenario's [[fault]]
    seed: int
    scenario: str | os.PathLike[str]  # take settings and faults from this scenario file
    boot_delay: float
    capabilities: Mapping[str, bool]  # M115 Cap: lines, e.g. {"AUTOREPORT_TEMP": False}
    link: str | os.PathLike[str]  # also make this path a symlink to the pty ({n} with printers)
    printers: int  # serve this many printers from one process: FakePrinter.printer(n)
    processes: int  # spread the printers over this many processes (one control socket still)
    first_number: int  # the first printer's number (and identity) in a larger farm
    extra_args: Sequence[str]  # more arguments, as on the command line


OWN_FLAGS = ("--journal", "--control")  # the FakePrinter's: its journal and control depend on them


def command_line(options: PrinterOptions) -> list[str]:
    """The `fake-marlin` arguments for these options."""
    unknown = set(options) - set(PrinterOptions.__annotations__)
    if unknown:  # a typo in an untyped caller's keyword must not pass unnoticed
        raise TypeError(f"unknown printer options: {', '.join(sorted(unknown))}")
    taken = [arg for arg in options.get("extra_args", ()) if arg.split("=")[0] in OWN_FLAGS]
    if taken:
        raise ValueError(
            f"extra_args cannot set {', '.join(taken)}: .journal and .control rely on them"
        )
    args = [
        "--protocol",
        options.get("protocol", "auto"),
        "--speed",
        repr(float(options.get("speed", 1.0))),
        "--extruders",
        str(options.get("extruders", 1)),
        "--seed",
        str(options.get("seed", 0)),
    ]
    if options.get("variants"):
        args += ["--variant", str(variants_of(options["variants"]))]
    if "firmware" in options:
        args += ["--firmware", os.fspath(options["firmware"])]
    for name, value in options.get("quirks", {}).items():
        args += ["--quirk", f"{name}={json.dumps(value)}"]  # JSON's true, 2.5, "x" are TOML's
    if "sd_dir" in options:
        args += ["--sd-dir", os.fspath(options["sd_dir"])]
    if options.get("advanced_ok"):
        args.append("--advanced-ok")
    baud = options.get("baud")
    if baud is True:
        args.append("--baud")
    elif baud:
        args += ["--baud", str(int(baud))]
    delays = {
        "--latency-ms": options.get("latency_ms"),
        "--jitter-ms": options.get("jitter_ms"),
        "--boot-delay": options.get("boot_delay"),
    }
    for flag, value in delays.items():
        if value:
            args += [flag, repr(float(value))]
    for table in options.get("faults", ()):
        args += ["--fault-table", json.dumps(dict(table))]
    if "scenario" in options:
        args += ["--scenario", os.fspath(options["scenario"])]
    for name, enabled in options.get("capabilities", {}).items():
        args += ["--capability", f"{name}={int(enabled)}"]
    if "link" in options:
        args += ["--link", os.fspath(options["link"])]
    if options.get("printers", 1) != 1:
        args += ["--printers", str(options["printers"])]
    if options.get("processes", 1) != 1:
        args += ["--processes", str(options["processes"])]
    if "first_number" in options:
        args += ["--first-number", str(options["first_number"])]
    return [*args, *options.get("extra_args", ())]


def start_printer(
    keep_directory: bool = False,
    program: Sequence[str] | None = None,
    **options: Unpack[PrinterOptions],
) -> FakePrinter:
    """Start a printer; stop it with `stop()`. `program` is the command that runs fake-marlin
    (default: this Python's `-m fake_marlin.emulator.cli`); `keep_directory` keeps its journal
    and stderr files."""
    args = command_line(options)
    # A short directory of its own: a Unix socket's path must stay under 108 bytes.
    directory = Path(tempfile.mkdtemp(prefix="fake-marlin-"))
    printers = options.get("printers", 1)
    if "sd_dir" not in options:
        # The card lives in the printer's directory, so it goes with it even after a kill.
        if printers == 1:
            (directory / "sd").mkdir()
        args += ["--sd-dir", str(directory / ("sd" if printers == 1 else "sd-{n}"))]
    link = options.get("link")
    return FakePrinter(
        args, directory, keep_directory, program, None if link is None else Path(link), printers,
        options.get("first_number", 1),
    )


@contextmanager
def running_printer(**options: Unpack[PrinterOptions]) -> Iterator[FakePrinter]:
    """A printer for the length of the block (see PrinterOptions)."""
    printer = start_printer(**options)
    try:
        yield printer
    except BaseException:
        printer.stop(check=False)
        raise
    printer.stop()


# -- a printer in memory, in the test's own trio run -----------------------------------------
class MemoryPrinter:
    """A printer on an in-memory link: `open()` is a host opening the port (the printer resets,
    as on a real board) and gives a trio byte stream; `journal` as FakePrinter's; `server` is
    the printer itself (its model, boots and protocol), for tests that look inside."""

    def __init__(self, link: MemoryLink, server: PrinterServer, journal_text: io.StringIO) -> None:
        self.link = link
        self.server = server
        self._journal_text = journal_text

    def open(self) -> HostEnd:
        return self.link.open_host()

    @property
    def journal(self) -> list[str]:
        return self._journal_text.getvalue().splitlines()


@asynccontextmanager
async def serve_in_memory(config: ServerConfig, printer: Printer,
                          firmware: Firmware | None = None) -> AsyncIterator[MemoryPrinter]:
    """`printer` served with `config` on an in-memory link, for the length of the block (as
    `firmware`, Marlin's without one)."""
    link = MemoryLink()
    journal_text = io.StringIO()
    server = PrinterServer(link, printer, Journal(journal_text), config, firmware=firmware)
    async with trio.open_nursery() as nursery:
        await nursery.start(server.run)
        # Power-on completes before any host opens the port, as on a real desk.
        await trio.testing.wait_all_tasks_blocked()
        yield MemoryPrinter(link, server, journal_text)
        nursery.cancel_scope.cancel()


_NOT_IN_MEMORY = ("speed", "link", "extra_args")  # trio's clock runs it; it has no pty


@asynccontextmanager
async def memory_printer(**options: Unpack[PrinterOptions]) -> AsyncIterator[MemoryPrinter]:
    """A printer in memory with these options (PrinterOptions, less speed, link, extra_args)."""
    unknown = (set(options) - set(PrinterOptions.__annotations__)) | (
        set(options) & set(_NOT_IN_MEMORY)
    )
    if unknown:
        raise TypeError(f"not options of a printer in memory: {', '.join(sorted(unknown))}")
    baud = options.get("baud")
    setup = PrinterSetup(
        protocol=options.get("protocol", "auto"),
        extruders=options.get("extruders", 1),
        baud=None if baud is True or not baud else int(baud),
        baud_from_host=baud is True,
        latency=options.get("latency_ms", 0.0) / 1000,
        jitter=options.get("jitter_ms", 0.0) / 1000,
        boot_delay=options.get("boot_delay", 0.0),
        advanced_ok=options.get("advanced_ok", False),
        firmware=os.fspath(options.get("firmware", "marlin")),
        variants=variants_of(options.get("variants")),
    )
    if "quirks" in options:
        profile = load_profile(setup.firmware)
        setup = dataclasses.replace(setup, quirks=read_quirks(
            TableReader("quirks", "", dict(options["quirks"])), profile.quirks))
    faults = FaultConfig(seed=options.get("seed", 0))
    if "scenario" in options:
        scenario = load(options["scenario"])
        setup, faults = scenario.printer, scenario.faults
    for number, table in enumerate(options.get("faults", ()), start=1):
        faults = add_fault_table(faults, dict(table), f"faults #{number}")
    firmware = setup.make_firmware(seed=faults.seed,
                                   capabilities=dict(options.get("capabilities", {})))
    with tempfile.TemporaryDirectory(prefix="fake-marlin-sd-") as scratch:
        config = firmware.printer_config(setup.extruders, Path(options.get("sd_dir", scratch)))
        async with serve_in_memory(setup.server_config(faults), Printer(config),
                                   firmware) as printer:
            yield printer
