"""`fake-marlin`: one parser. Without a command it runs printers (printers.py), and its options
are theirs; a command (verify, scenario, bench, report) takes its own options after its name.

Each command's module adds its parser (`configure(commands)`, which sets `run`, the function
that runs it) and imports what it runs only when it runs it: building this parser, which every
printer's start does, costs next to nothing beyond the printer's own imports.
"""

import argparse
import sys

from fake_marlin import __version__
from fake_marlin.emulator.bench import cli as bench
from fake_marlin.emulator.cli import printers, report, scenario, verify
from fake_marlin.emulator.cli.parsing import CommandParser, Commands

PROG = "fake-marlin"


class _Version(argparse.Action):
    """`--version`: the version, and which waits the printer's links use (link/direct_wait.py:
    direct ones only on the trio releases verified), asked only when it is printed."""

    def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS,
                 default: str = argparse.SUPPRESS, help: str | None = None) -> None:
        super().__init__(option_strings, dest, nargs=0, default=default, help=help)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        from fake_marlin.emulator.link.direct_wait import waits_in_use

        print(f"{parser.prog} {__version__}\n{waits_in_use()[1]}")
        parser.exit()


def build_parser() -> CommandParser:
    parser = CommandParser(
        prog=PROG, add_help=False,
        usage=f"{PROG} [OPTION ...]              run printers\n"
        f"       {PROG} COMMAND [ARGUMENT ...]   run a command",
        description="A virtual 3D printer for testing hosts. Without a command, fake-marlin starts "
        "a virtual Marlin printer on a pseudo-terminal (or several, or on TCP) and prints its "
        "path, one line per printer, until it is stopped: the printer options below set it up. "
        "Each command has its own --help.",
    )
    commands = parser.add_subparsers(title="commands", dest="command", metavar="COMMAND", prog=PROG)
    assert isinstance(commands, Commands)
    for configure in (verify.configure, scenario.configure, bench.configure, report.configure):
        configure(commands)
    options = parser.add_argument_group("options")
    options.add_argument("-h", "--help", action="help", help="show this help message and exit")
    options.add_argument("--version", action=_Version,
                         help="show the version, and which waits for the line are in use")
    printers.add_arguments(parser.add_argument_group("printer options (without a command)"))
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        return printers.run(parser, args, argv)
    code: int = args.run(args)
    return code


if __name__ == "__main__":
    sys.exit(main())
