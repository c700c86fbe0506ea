"""`fake-marlin-host`: stream G-code to a printer on a serial port, or send it one command."""

import argparse
import json
import os
import sys
import time

import trio

from fake_marlin import __version__
from fake_marlin.host.codecs import g2core, marlin, ultimaker
from fake_marlin.host.connect import DEFAULT_BAUDRATE, PROTOCOLS, load_job, open_printer
from fake_marlin.host.errors import HostError, RemoteError
from fake_marlin.host.shell import ClientOptions, sole_exception
from fake_marlin.wire.ultimaker_variants import NAMES, PLAIN, VariantError, Variants, parse_variants


def _positive(kind):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be positive, got {text!r}")
        return value

    return parse


def _variants(text: str) -> Variants:
    try:
        return parse_variants(text)
    except VariantError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fake-marlin-host", description="Talk to a 3D printer (real or fake-marlin) on a serial port."
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--protocol", choices=PROTOCOLS, default="ultimaker")
    common.add_argument("--baud", type=_positive(int), default=DEFAULT_BAUDRATE)
    common.add_argument(
        "--window", type=_positive(int), default=3,
        help="Ultimaker packets, g2core lines in flight (default 3); Marlin always has one line in flight",
    )
    common.add_argument(
        "--timeout", type=_positive(float), default=2.0,
        help="seconds of printer silence before an unanswered packet is sent again "
        "(Marlin: before the host asks which line the printer has) (default 2)",
    )
    common.add_argument(
        "--long-timeout", type=_positive(float), default=300.0,
        help="the same while the printer is busy with G28, M400, M109, a full planner (default 300)",
    )
    common.add_argument(
        "--retries", type=_positive(int), default=8, help="transmissions of one packet before giving up"
    )
    common.add_argument(
        "--variant", type=_variants, default=PLAIN, metavar="NAME[,NAME]",
        help="the protocol lab's variants of Ultimaker's protocol, as the printer was given "
        f"them: {', '.join(NAMES)} (docs/protocol-lab.md)",
    )
    common.add_argument(
        "-v", "--verbose", action="store_true",
        help="also show the printer's LOG lines (Marlin: echo, busy, temperature and other lines; "
        "g2core: status and queue reports)",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    print_parser = commands.add_parser("print", parents=[common], help="stream a G-code file")
    port_help = ("serial device (e.g. /dev/ttyACM0 or the emulator's pty), or a network port: "
                 "socket://HOST:PORT (raw TCP) or rfc2217://HOST:PORT")
    print_parser.add_argument("port", help=port_help)
    print_parser.add_argument("file", help="G-code file")
    print_parser.add_argument("--json", action="store_true", help="print a JSON summary instead")
    send_parser = commands.add_parser("send", parents=[common], help="send one command, print the reply")
    send_parser.add_argument("port", help=port_help)
    send_parser.add_argument("gcode", help='the command, e.g. "M105"')
    return parser


class ProgressBar:
    """One self-rewriting line on stderr when it is a terminal; nothing otherwise."""

    def __init__(self, total: int, stats) -> None:
        self.total = total
        self.stats = stats
        self.done = 0
        self._shown_at = 0.0
        self._live = sys.stderr.isatty()

    def update(self, done: int) -> None:
        self.done = done
        now = time.monotonic()
        if self._live and (now - self._shown_at > 0.1 or done == self.total):
            self._shown_at = now
            sys.stderr.write("\r" + self.line())
            sys.stderr.flush()

    def line(self) -> str:
        width = 30
        filled = width * self.done // self.total if self.total else width
        return (
            f"[{'#' * filled}{'.' * (width - filled)}]  {self.done}/{self.total} commands"
            f"  resends: {self.stats.resends}"
        )

    def finish(self, elapsed: float) -> None:
        end = "\r" if self._live else ""
        sys.stderr.write(f"{end}{self.line()}  timeouts: {self.stats.timeouts}  {elapsed:.1f} s\n")


# Marlin lines shown without -v: the rest (echo, busy, temperatures...) is routine.
_MARLIN_SHOWN = frozenset({marlin.LineKind.ERROR, marlin.LineKind.HALTED, marlin.LineKind.ACTION})
# g2core's: its exception reports (alarm, shutdown, job kill...); status reports are routine.
_G2CORE_SHOWN = frozenset({g2core.LineKind.EXCEPTION})


def _line_printer(verbose: bool):
    def show(line: ultimaker.Line | marlin.Line | g2core.Line) -> None:
        if isinstance(line, marlin.Line):
            shown, text = verbose or line.kind in _MARLIN_SHOWN, line.text
        elif isinstance(line, g2core.Line):
            shown, text = verbose or line.kind in _G2CORE_SHOWN, line.text
        else:
            shown, text = verbose or line.kind is not ultimaker.LineKind.LOG, f"{line.kind.value}:{line.text}"
        if shown:
            # Start from a clean line in case a progress bar is being drawn there.
            start = "\r\033[K" if sys.stderr.isatty() else ""
            print(f"{start}printer: {text}", file=sys.stderr)

    return show


def _options(args) -> ClientOptions:
    return ClientOptions(
        window=args.window,
        timeout=args.timeout,
        long_timeout=args.long_timeout,
        max_transmissions=args.retries,
        variants=args.variant,
    )


async def _print(args) -> int:
    job = load_job(args.file, args.protocol)
    async with open_printer(args.port, args.protocol, args.baud, _options(args), _line_printer(args.verbose)) as printer:
        bar = ProgressBar(len(job), printer.stats)
        summary = await printer.print_file(args.file, bar.update)
    if args.json:
        print(json.dumps(summary.as_dict()))
    else:
        bar.finish(summary.elapsed)
    return 0


async def _send(args) -> int:
    async with open_printer(args.port, args.protocol, args.baud, _options(args), _line_printer(args.verbose)) as printer:
        for line in await printer.send(args.gcode):
            print(line)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not args.variant.plain and args.protocol != "ultimaker":
        parser.error(f"--variant {args.variant}: the variants are Ultimaker's; give "
                     "--protocol ultimaker")
    try:
        return trio.run(_print if args.command == "print" else _send, args)
    except BaseException as raised:  # noqa: BLE001 - sorted below, the rest re-raised
        error = sole_exception(raised)
        start = "\n" if sys.stderr.isatty() else ""  # end a progress bar's line
        if isinstance(error, HostError):
            print(f"{start}fake-marlin-host: {error}", file=sys.stderr)
            return 1 if isinstance(error, RemoteError) else 2
        if isinstance(error, KeyboardInterrupt):
            print(f"{start}fake-marlin-host: interrupted", file=sys.stderr)
            return 130
        if isinstance(error, BrokenPipeError):
            # Its reader has gone (`| head`): nothing more can be said; as the shell's SIGPIPE.
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 141
        raise


if __name__ == "__main__":
    sys.exit(main())
