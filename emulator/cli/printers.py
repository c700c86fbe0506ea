"""`fake-marlin` without a command: run virtual printers, each on a pseudo-terminal."""

import argparse
import contextlib
import json
import os
import signal
import sys
import tempfile
import tomllib
from collections.abc import Sequence
from pathlib import Path

import trio

from fake_marlin.emulator.control.server import Controller, check_control_path, serve_control
from fake_marlin.emulator.faults.layer import FaultConfig, parse_fault
from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.cli.links import (
    Address,
    LinkError,
    add_link_arguments,
    check_link_arguments,
    make_link,
    tcp_address,
)
from fake_marlin.emulator.link.pty import PtyLink
from fake_marlin.emulator.link.tcp import TcpLink
from fake_marlin.emulator.firmware import Profile, load_profile, shipped
from fake_marlin.emulator.firmware.quirks import KINDS as QUIRK_KINDS, NAMES as QUIRK_NAMES
from fake_marlin.emulator.firmware.quirks import read_quirks
from fake_marlin.emulator.printer.eeprom import EepromFileError
from fake_marlin.emulator.printer.model import Printer
from fake_marlin.emulator.tables import TableError, TableReader
from fake_marlin.emulator.cli.farm import (
    MAX_FIRST_NUMBER,
    MAX_PRINTERS,
    MAX_PROCESSES,
    PrinterPlan,
    check_patterns,
    copies,
    numbered,
    read_farm,
)
from fake_marlin.emulator.cli.limits import explain, files_needed, pty_problem, raise_file_limit
from fake_marlin.emulator.cli.parsing import whole_number
from fake_marlin.emulator.cli.processes import serve_processes
from fake_marlin.emulator.cli.web import WebUnavailable, said
from fake_marlin.emulator.scenario.definition import PrinterSetup, ScenarioError, add_fault_table
from fake_marlin.emulator.scenario.definition import load as load_scenario
from fake_marlin.emulator.server.clock import ScaledClock
from fake_marlin.emulator.server.flash_file import FlashFile, FlashFileError
from fake_marlin.emulator.trace.writer import Trace, TraceError
from fake_marlin.emulator.server.lifecycle import PROTOCOLS, PrinterServer
from fake_marlin.wire.ultimaker_variants import NAMES, PLAIN, VariantError, Variants, parse_variants


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def _non_negative_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be zero or more, got {text!r}")
    return value


def _capability(text: str) -> tuple[str, bool]:
    name, _, value = text.partition("=")
    if not name or not name.replace("_", "").isalnum() or value not in ("0", "1"):
        raise argparse.ArgumentTypeError(f"expected NAME=0 or NAME=1, got {text!r}")
    return name.upper(), value == "1"


def _variants(text: str) -> Variants:
    try:
        return parse_variants(text)
    except VariantError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def _baud(text: str) -> int | str:
    if text == "host":
        return text
    if not text.isdigit() or int(text) <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive whole number or `host`, got {text!r}")
    return int(text)


def _slice(text: str) -> slice:
    start, _, stop = text.partition(":")
    if not start.isdigit() or not stop.isdigit() or int(start) >= int(stop):
        raise argparse.ArgumentTypeError(f"expected START:STOP, got {text!r}")
    return slice(int(start), int(stop))


def _json_table(text: str) -> dict[str, object]:
    try:
        table = json.loads(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"not JSON: {error}") from None
    if not isinstance(table, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object, got {text!r}")
    return table


def _quirk(text: str) -> tuple[str, object]:
    name, equals, value = text.partition("=")
    if name not in QUIRK_NAMES:
        raise argparse.ArgumentTypeError(f"no quirk {name!r}: one of {', '.join(QUIRK_NAMES)}")
    if not equals:
        return name, True
    if QUIRK_KINDS.get(name) is str:
        return name, value  # as typed: `password=1234` is the text 1234
    try:
        return name, tomllib.loads(f"value = {value}")["value"]  # 1, 2.5, true, "text"
    except tomllib.TOMLDecodeError:
        return name, value  # a bare word: a string (a password)


def add_arguments(parser: argparse._ActionsContainer) -> None:
    """The printer's options, on `fake-marlin`'s parser (main.py) or a group of it."""
    parser.add_argument(
        "--firmware", metavar="NAME|FILE", default="marlin",
        help="the firmware it is: marlin (default; Marlin 2.1), marlin-1.1, prusa, klipper, "
        "reprapfirmware, smoothieware, repetier, ultimaker2, g2core, or a profile file "
        "(FILE.toml, which may extend one of them); `--firmware list` lists them. See "
        "docs/firmwares.md",
    )
    parser.add_argument(
        "--quirk", action="append", default=[], metavar="NAME[=VALUE]", type=_quirk,
        help="switch on one of the firmware's quirks (repeatable), e.g. ok_before_output or "
        "drop_ok_every=50; see docs/firmwares.md for the list",
    )
    parser.add_argument(
        "--protocol", choices=PROTOCOLS, default="auto",
        help="wire protocol; auto (default) decides from each connection's first bytes, among "
        "those the firmware speaks",
    )
    parser.add_argument(
        "--variant", type=_variants, default=PLAIN, metavar="NAME[,NAME]",
        help="with --protocol ultimaker: the protocol lab's variants of it, "
        f"{', '.join(NAMES)} (comma-separated; the host must be given the same; see "
        "docs/protocol-lab.md)",
    )
    parser.add_argument("--link", metavar="PATH", help="also make PATH a symlink to the pty "
                        "(with --printers, a pattern with {n}: /tmp/printer-{n})")
    parser.add_argument("--journal", metavar="FILE", help="append each executed command to FILE "
                        "(with --printers, a pattern with {n})")
    add_link_arguments(parser)
    parser.add_argument(
        "--printers", type=whole_number(1, MAX_PRINTERS), default=1, metavar="N",
        help="serve N independent printers from this process, one pty each; their paths are "
        "printed one per line, in order (default 1)",
    )
    parser.add_argument(
        "--processes", type=whole_number(1, MAX_PROCESSES), metavar="K",
        help="spread the printers over K processes, on as many cores (default 1): numbers, "
        "paths, ports and seeds as if one process served them, one --control socket for all; "
        "see docs/farm.md",
    )
    parser.add_argument(
        "--first-number", type=whole_number(1, MAX_FIRST_NUMBER), metavar="N",
        help="this process serves printers N, N+1, ... of a larger farm (default 1): their "
        "numbers, {n} paths, seeds and identities (UUID, serial, machine name) follow, so that "
        "no two printers of the farm share them; TCP ports still count from the port given",
    )
    # A child of --processes: serve only these printers of the plan (processes.py).
    parser.add_argument("--slice", type=_slice, help=argparse.SUPPRESS)
    parser.add_argument(
        "--farm", metavar="FILE",
        help="serve the printers a farm file describes (TOML: [[printer]] tables with count, "
        "protocol, scenario, faults, link, journal, tcp...; see docs/farm.md)",
    )
    parser.add_argument(
        "--speed", type=_positive_float, default=1.0, metavar="X",
        help="run simulated printer time X times faster than real time (default 1)",
    )
    parser.add_argument("--extruders", type=whole_number(1, 8), default=1, metavar="N")
    parser.add_argument(
        "--sd-dir", metavar="DIR",
        help="directory that backs the SD card (default: a temporary one, removed at exit; "
        "with --printers, a pattern with {n}, made if missing)",
    )
    parser.add_argument(
        "--flash-file", metavar="FILE",
        help="keep the board's 256 KiB flash (what avrdude writes through the bootloader) in "
        "FILE across runs, created erased if missing (default: in memory, erased at start; with "
        "--printers, a pattern with {n}; see docs/bootloader.md)",
    )
    parser.add_argument(
        "--eeprom-file", metavar="FILE",
        help="keep the settings M500 stores in FILE (JSON) across resets and runs, created at "
        "the first M500 (default: in memory, kept across resets only; with --printers, a "
        "pattern with {n})",
    )
    parser.add_argument(
        "--trace", metavar="FILE",
        help="write a wire trace to FILE: every byte each way, commands, planner room, heaters, "
        "faults and resets, as JSON lines (gzip if FILE ends in .gz; with several printers, a "
        "pattern with {n}); `fake-marlin report FILE` shows it, see docs/trace.md",
    )
    parser.add_argument(
        "--advanced-ok", action="store_true", help="Marlin's ADVANCED_OK: `ok N.. P.. B..`"
    )
    parser.add_argument(
        "--capability", action="append", default=[], metavar="NAME=0|1", type=_capability,
        help="set one M115 capability (repeatable), e.g. AUTOREPORT_TEMP=0",
    )
    parser.add_argument(
        "--fault", action="append", default=[], metavar="DIRECTION:KIND=RATE",
        help="damage the line, e.g. to-printer:bit-errors=1e-4 or to-host:drop-bytes=0.001 "
        "(repeatable)",
    )
    parser.add_argument(
        "--fault-table", action="append", default=[], metavar="JSON", type=_json_table,
        help='a fault as a scenario\'s [[fault]] table, in JSON (repeatable), e.g. '
        '\'{"kind": "drop", "direction": "to-host", "nth": 3}\'',
    )
    parser.add_argument("--seed", type=int, default=0, help="seed for random faults (default 0)")
    parser.add_argument(
        "--scenario", metavar="FILE",
        help="take the printer's settings and faults from a scenario file (its job is not run)",
    )
    parser.add_argument(
        "--baud", metavar="RATE", type=_baud, nargs="?", const="host",
        help="pace the line: each byte costs 10/RATE s each way; without RATE (or `host`), at the "
        "rate the host set on the port; default: no pacing",
    )
    parser.add_argument("--latency-ms", type=_non_negative_float, default=0.0, metavar="MS",
                        help="delay each way, in milliseconds (default 0)")
    parser.add_argument("--jitter-ms", type=_non_negative_float, default=0.0, metavar="MS",
                        help="plus up to this much at random, order kept (default 0)")
    parser.add_argument("--control", metavar="SOCKET",
                        help="serve the control channel (JSON lines) on this Unix socket")
    parser.add_argument(
        "--web", type=tcp_address, metavar="[HOST:]PORT",
        help="serve a live view of the printers on http://HOST:PORT/ (HOST 127.0.0.1 unless "
        "given; PORT 0 takes a free one; the address is said on stderr): one row per printer, "
        "and each printer's page with its wire and plots; see docs/web.md",
    )
    parser.add_argument(
        "--boot-delay", type=_non_negative_float, default=0.0, metavar="SECONDS",
        help="simulated time a reset takes before the printer answers (default 0)",
    )


class _Symlink:
    def __init__(self, path: str | None, target: str) -> None:
        self.path = path
        self.target = target

    def create(self) -> None:
        if self.path is None:
            return
        if os.path.lexists(self.path):
            if not os.path.islink(self.path):
                raise OSError(f"{self.path} exists and is not a symlink; refusing to replace it")
            os.unlink(self.path)
        os.symlink(self.target, self.path)

    def remove(self) -> None:
        if self.path and os.path.islink(self.path) and os.readlink(self.path) == self.target:
            os.unlink(self.path)

    def retarget(self, target: str) -> None:
        """The pty came back under a new name (a `disconnect` fault): the link follows it."""
        if self.path and os.path.islink(self.path) and os.readlink(self.path) == self.target:
            os.unlink(self.path)
            os.symlink(target, self.path)
        self.target = target


async def _serve_until_signalled(printers: list["_Running"], control: str | None,
                                 web: Address | None, child: bool) -> None:
    with trio.open_signal_receiver(signal.SIGINT, signal.SIGTERM, signal.SIGHUP) as signals:
        async with trio.open_nursery() as nursery:
            stop = _Stop(nursery.cancel_scope)
            for printer in printers:
                await nursery.start(stop.run, printer.server)
            servers = [printer.server for printer in printers]
            numbers = [printer.plan.number for printer in printers]
            if control:
                await nursery.start(serve_control, control, Controller(servers, numbers))
            if web is not None:
                from fake_marlin.emulator.cli.web import start_web
                from fake_marlin.emulator.web.source import LocalFarm  # hypercorn, when asked

                paths = [printer.link.path for printer in printers]
                await start_web(nursery, web, LocalFarm(servers, numbers, paths))
            if child:
                nursery.start_soon(_stop_when_parent_goes, stop)
            # Every printer is up before any path is printed: a farm's host may open them all
            # as soon as it reads the list.
            print("\n".join(printer.link.path for printer in printers), flush=True)
            async for _ in signals:
                stop()
                break


class _Stop:
    """Stops every printer of the process, then the rest (control channel, live view). Each
    printer runs in a cancel scope of its own, which catches its own cancellation, and the
    nursery's is cancelled only when they have all ended: the nursery then has no exception
    group of thousands of Cancelled to take apart, which took longer than the rest of a stop."""

    def __init__(self, nursery_scope: trio.CancelScope) -> None:
        self._nursery_scope = nursery_scope
        self._scopes: list[trio.CancelScope] = []
        self._running = 0

    async def run(self, server: PrinterServer, task_status=trio.TASK_STATUS_IGNORED) -> None:
        self._running += 1
        try:
            with trio.CancelScope() as scope:
                self._scopes.append(scope)
                await server.run(task_status=task_status)
        finally:
            self._running -= 1
            if not self._running:
                self._nursery_scope.cancel()

    def __call__(self) -> None:
        for scope in self._scopes:
            scope.cancel()
        if not self._running:
            self._nursery_scope.cancel()


async def _stop_when_parent_goes(stop: _Stop) -> None:
    """A --processes child: its standard input is a pipe from the farm's first process, which
    closes when that process ends, however it ends."""
    stream = trio.lowlevel.FdStream(os.dup(sys.stdin.fileno()))
    async with stream:
        while await stream.receive_some(4096):
            pass
    stop()


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _plans(parser: argparse.ArgumentParser, args: argparse.Namespace) -> tuple[list[PrinterPlan], int]:
    """What to serve: the farm file's printers, or --printers copies of the one the flags say;
    and over how many processes."""
    plans, processes = _printer_plans(parser, args)
    processes = args.processes or processes or 1
    if processes > len(plans):
        parser.error(f"argument --processes: {processes} processes for {len(plans)} printer(s): "
                     "at most one process each")
    return plans, processes


def _printer_plans(parser: argparse.ArgumentParser,
                   args: argparse.Namespace) -> tuple[list[PrinterPlan], int | None]:
    if args.farm:
        given = [flag for flag, value in (
            ("--printers", args.printers != 1), ("--scenario", args.scenario),
            ("--link", args.link), ("--journal", args.journal), ("--sd-dir", args.sd_dir),
            ("--tcp", args.tcp), ("--rfc2217", args.rfc2217), ("--fault", args.fault),
            ("--eeprom-file", args.eeprom_file),
            ("--fault-table", args.fault_table),
            ("--firmware", args.firmware != "marlin"), ("--quirk", args.quirk),
            ("--variant", not args.variant.plain),
        ) if value]
        if given:
            parser.error(f"argument --farm: {given[0]} goes in the farm file's [[printer]] tables")
        try:
            farm = read_farm(args.farm, args.first_number)
        except ScenarioError as error:
            parser.error(f"argument --farm: {error}")
        return farm.plans, farm.processes
    try:
        profile = load_profile(args.firmware)
        quirks = None
        if args.quirk:
            quirks = read_quirks(TableReader("--quirk", "", dict(args.quirk)), profile.quirks)
    except TableError as error:
        parser.error(f"argument --firmware: {error}" if not args.quirk or "--quirk" not in str(error)
                     else f"argument {error}")
    if args.protocol != "auto" and args.protocol not in profile.protocols:
        parser.error(f"argument --protocol: firmware {profile.name} speaks "
                     f"{', '.join(profile.protocols)}, not {args.protocol}")
    if not args.variant.plain and args.protocol != "ultimaker":
        parser.error(f"argument --variant: the variants ({args.variant}) are Ultimaker's protocol's: "
                     "give --protocol ultimaker (auto never guesses a variant)")
    setup = PrinterSetup(
        protocol=args.protocol, extruders=args.extruders, boot_delay=args.boot_delay,
        advanced_ok=args.advanced_ok, latency=args.latency_ms / 1000, jitter=args.jitter_ms / 1000,
        baud=args.baud if isinstance(args.baud, int) else None, baud_from_host=args.baud == "host",
        firmware=args.firmware, quirks=quirks, variants=args.variant,
    )
    faults = FaultConfig(seed=args.seed)
    if args.scenario:
        try:
            scenario = load_scenario(args.scenario)
        except ScenarioError as error:
            parser.error(f"argument --scenario: {error}")
        setup, faults = scenario.printer, scenario.faults
    for spec in args.fault:
        try:
            faults = parse_fault(spec, faults)
        except ValueError as error:
            parser.error(f"argument --fault: {error}")
    for number, table in enumerate(args.fault_table, start=1):
        try:
            faults = add_fault_table(faults, table, f"--fault-table #{number}")
        except ScenarioError as error:
            parser.error(f"argument {error}")
    if args.printers > 1:
        for flag, value in (("--link", args.link), ("--journal", args.journal),
                            ("--sd-dir", args.sd_dir), ("--eeprom-file", args.eeprom_file)):
            if value and "{n}" not in value:
                parser.error(f"argument {flag}: with --printers, put {{n}} in it (the printer's "
                             f"number, from 1), e.g. {flag} /tmp/printer-{{n}}")
    elif args.sd_dir and "{n}" not in args.sd_dir and not os.path.isdir(args.sd_dir):
        parser.error(f"argument --sd-dir: no directory {args.sd_dir}")
    base = PrinterPlan(
        1, setup, faults, args.link, args.journal, args.sd_dir,
        tcp=args.tcp, rfc2217=args.rfc2217, eeprom_file=args.eeprom_file,
    )
    # Printer N of a farm is the same printer whichever process serves it: its seed is the
    # farm's + N - 1, as in one process of N printers.
    first = args.first_number or 1
    return copies(base, args.printers, first, seed_from=first - 1), None


class _Running:
    """One printer of this process and what it holds open: its link, symlink, journal, card."""

    def __init__(self, plan: PrinterPlan, capabilities: dict[str, bool], in_farm: bool,
                 cleanup: contextlib.ExitStack, flash_file: str | None = None,
                 trace_file: str | None = None, speed: float = 1.0,
                 profiles: dict[str, Profile] | None = None) -> None:
        self.plan = plan
        profiles = {} if profiles is None else profiles
        flash = FlashFile.open(flash_file) if flash_file else None
        if flash is not None:
            cleanup.callback(flash.close)
        self.journal = Journal.open(plan.journal)
        cleanup.callback(self.journal.close)
        trace = None
        if trace_file:
            trace = Trace.open(trace_file, plan.setup.protocol, speed, plan.faults.seed,
                               printer=plan.number)
            cleanup.callback(trace.close)
        self.link: PtyLink | TcpLink = make_link(plan.tcp, plan.rfc2217) or PtyLink()
        cleanup.callback(self.link.close)
        self.symlink = _Symlink(plan.link, self.link.path)
        self.symlink.create()
        cleanup.callback(self.symlink.remove)

        def new_path(path: str) -> None:
            self.symlink.retarget(path)
            # The line came back on a new pty: say where, as at start (which printer, in a farm).
            print(path if not in_farm else f"printer {plan.number}: {path}", flush=True)

        self.link.on_new_path = new_path
        if plan.sd_dir:
            os.makedirs(plan.sd_dir, exist_ok=True)
            sd_dir = Path(plan.sd_dir)
        else:
            sd_dir = Path(cleanup.enter_context(tempfile.TemporaryDirectory(prefix="fake-marlin-sd-")))
        # One profile for all the printers of a firmware: parsing it is most of a start.
        profile = profiles.get(plan.setup.firmware)
        if profile is None:
            profile = profiles[plan.setup.firmware] = load_profile(plan.setup.firmware)
        firmware = plan.setup.make_firmware(plan.number, plan.faults.seed, plan.uuid, plan.serial,
                                            plan.machine_name, capabilities, profile)
        config = firmware.printer_config(plan.setup.extruders, sd_dir,
                                         Path(plan.eeprom_file) if plan.eeprom_file else None)
        self.server = PrinterServer(
            self.link, Printer(config), self.journal, plan.setup.server_config(plan.faults),
            memory=flash.memory if flash else None, flash_changed=flash.save if flash else None,
            trace=trace, firmware=firmware,
        )


def list_firmwares() -> int:
    """`--firmware list`: the shipped profiles, one a line."""
    for name in shipped():
        profile = load_profile(name)
        print(f"{name:<16} {profile.title} ({', '.join(profile.protocols)})")
    print("\nOr a profile file of your own: --firmware ./my-printer.toml "
          "(`extends = \"marlin\"` and what differs; docs/firmwares.md)")
    return 0


def run(parser: argparse.ArgumentParser, args: argparse.Namespace,
        argv: Sequence[str] = ()) -> int:
    """Serve the printers `args` describe until a signal; `parser` reports what is wrong in
    them (main.py's, with the printer options); `argv`, the arguments, are a --processes
    farm's children's too."""
    if args.firmware == "list":
        return list_firmwares()
    check_link_arguments(parser, args)
    plans, processes = _plans(parser, args)
    try:
        check_patterns(plans)
    except ScenarioError as error:
        parser.error(str(error))
    if args.flash_file and (args.farm or len(plans) > 1 and "{n}" not in args.flash_file):
        parser.error("argument --flash-file: " + (
            "not with --farm: a farm's printers keep their flash in memory" if args.farm else
            "with --printers, put {n} in it (the printer's number, from 1)"))
    if args.trace and len(plans) > 1 and "{n}" not in args.trace:
        parser.error("argument --trace: with several printers, put {n} in it (the printer's "
                     "number, from 1)")
    if args.control and (problem := check_control_path(args.control)):
        parser.error(f"argument --control: {problem}")
    in_farm = len(plans) > 1
    web = args.web
    if args.slice is not None:  # a child of --processes: its part of the farm
        if args.slice.stop > len(plans):
            parser.error(f"argument --slice: the farm has {len(plans)} printers")
        plans, web = plans[args.slice], None
    elif problem := pty_problem(sum(1 for plan in plans if not plan.tcp and not plan.rfc2217)):
        print(f"fake-marlin: {problem}", file=sys.stderr)
        return 2
    farm_parent = processes > 1 and args.slice is None
    if not farm_parent and (problem := raise_file_limit(_files_needed(plans, args))):
        print(f"fake-marlin: {problem}", file=sys.stderr)
        return 2
    # Until trio takes over the signals (and in case one lands before it does), a SIGTERM or
    # SIGHUP must unwind like Ctrl-C so that the symlinks are removed.
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGHUP, _interrupt)
    if farm_parent:
        return serve_processes(argv, plans, processes, args.control, web)
    capabilities = dict(args.capability)  # over the firmware's own
    profiles: dict[str, Profile] = {}
    with contextlib.ExitStack() as cleanup:
        printers = []
        for plan in plans:
            try:
                printers.append(_Running(plan, capabilities, in_farm, cleanup,
                                         numbered(args.flash_file, plan.number),
                                         numbered(args.trace, plan.number), args.speed,
                                         profiles))
            except (LinkError, FlashFileError, TraceError, EepromFileError) as error:
                print(f"fake-marlin: {error}", file=sys.stderr)
                return 2
            except OSError as error:
                what = (f"journal {error.filename}" if error.filename == plan.journal
                        else f"link {plan.link}" if plan.link else "a pty")
                print(f"fake-marlin: cannot create {what}: "
                      f"{explain(error) or error.strerror or error}", file=sys.stderr)
                return 2
        code = 0
        try:
            try:
                trio.run(_serve_until_signalled, printers, args.control, web,
                         args.slice is not None, clock=ScaledClock(args.speed))
            except* WebUnavailable as group:
                code = said(group)
        except KeyboardInterrupt:
            pass
    return code


def _files_needed(plans: list[PrinterPlan], args: argparse.Namespace) -> int:
    sockets = sum(1 for plan in plans if plan.tcp or plan.rfc2217)
    files = sum(1 for plan in plans if plan.journal) + (len(plans) if args.trace else 0)
    return files_needed(len(plans) - sockets, sockets, files)
