"""`fake-marlin`: run a virtual printer on a pseudo-terminal."""

import argparse
import contextlib
import os
import signal
import sys
import tempfile
from pathlib import Path

import trio

from emulator.clock import ScaledClock
from emulator.faults import FaultConfig, parse_fault
from emulator.journal import Journal
from emulator.link.pty import PtyLink
from emulator.printer.model import DEFAULT_CAPABILITIES, Printer, PrinterConfig
from emulator.server import PROTOCOLS, PrinterServer, ServerConfig


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


def _extruder_count(text: str) -> int:
    if not text.isdigit() or not 1 <= int(text) <= 8:
        raise argparse.ArgumentTypeError(f"must be a whole number from 1 to 8, got {text!r}")
    return int(text)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fake-marlin",
        description="Start a virtual Marlin printer on a pseudo-terminal and print its /dev/pts path.",
    )
    parser.add_argument(
        "--protocol", choices=PROTOCOLS, default="auto",
        help="wire protocol; auto (default) decides from each connection's first bytes",
    )
    parser.add_argument("--link", metavar="PATH", help="also make PATH a symlink to the pty")
    parser.add_argument("--journal", metavar="FILE", help="append each executed command to FILE")
    parser.add_argument(
        "--speed", type=_positive_float, default=1.0, metavar="X",
        help="run simulated printer time X times faster than real time (default 1)",
    )
    parser.add_argument("--extruders", type=_extruder_count, default=1, metavar="N")
    parser.add_argument(
        "--sd-dir", metavar="DIR",
        help="directory that backs the SD card (default: a temporary one, removed at exit)",
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
    parser.add_argument("--seed", type=int, default=0, help="seed for random faults (default 0)")
    parser.add_argument(
        "--boot-delay", type=_non_negative_float, default=0.0, metavar="SECONDS",
        help="simulated time a reset takes before the printer answers (default 0)",
    )
    return parser


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


async def _serve_until_signalled(server: PrinterServer, path: str) -> None:
    with trio.open_signal_receiver(signal.SIGINT, signal.SIGTERM, signal.SIGHUP) as signals:
        async with trio.open_nursery() as nursery:
            await nursery.start(server.run)
            print(path, flush=True)
            async for _ in signals:
                nursery.cancel_scope.cancel()
                break


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    faults = FaultConfig(seed=args.seed)
    for spec in args.fault:
        try:
            faults = parse_fault(spec, faults)
        except ValueError as error:
            parser.error(f"argument --fault: {error}")
    # Until trio takes over the signals (and in case one lands before it does), a SIGTERM or
    # SIGHUP must unwind like Ctrl-C so that the symlink is removed.
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGHUP, _interrupt)
    try:
        journal = Journal.open(args.journal)
    except OSError as error:
        print(f"fake-marlin: cannot open journal {args.journal}: {error.strerror}", file=sys.stderr)
        return 2
    link = PtyLink()
    symlink = _Symlink(args.link, link.path)
    try:
        symlink.create()
    except OSError as error:
        print(f"fake-marlin: cannot create link {args.link}: {error.strerror or error}", file=sys.stderr)
        link.close()
        return 2
    try:
        with contextlib.ExitStack() as cleanup:
            sd_dir = Path(args.sd_dir) if args.sd_dir else Path(
                cleanup.enter_context(tempfile.TemporaryDirectory(prefix="fake-marlin-sd-"))
            )
            capabilities = dict(DEFAULT_CAPABILITIES)
            capabilities.update(args.capability)
            config = PrinterConfig(
                extruders=args.extruders, sd_dir=sd_dir, capabilities=tuple(capabilities.items())
            )
            server_config = ServerConfig(
                protocol=args.protocol,
                boot_delay=args.boot_delay,
                advanced_ok=args.advanced_ok,
                faults=faults,
            )
            server = PrinterServer(link, Printer(config), journal, server_config)
            trio.run(_serve_until_signalled, server, link.path, clock=ScaledClock(args.speed))
    except KeyboardInterrupt:
        pass
    finally:
        symlink.remove()
        journal.close()
        link.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
