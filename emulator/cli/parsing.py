"""The parser class of `fake-marlin` and of each of its commands: argparse's, with three changes.

- A command parses its arguments as its own program would: an argument it does not know is its
  error, told with its usage (`fake-marlin scenario run: error: unrecognized arguments: --x`),
  where argparse leaves it to the parser above, which would print the printer's usage instead.
- A command's name comes first: the options before it are the program's without a command (the
  printer's), which a command does not take, so `fake-marlin --protocol marlin verify ...` is
  an error, not a printer started nor an option quietly dropped.
- `one_line_errors=True` (the bench's) makes an error one line, with no usage block:
  `fake-marlin bench: error: MESSAGE (see fake-marlin bench --help)`.

    commands = parser.add_subparsers(...)           # on a CommandParser: Commands
    assert isinstance(commands, Commands)           # (for the type checker)
    bench = commands.add_parser("bench", one_line_errors=True, help=...)
"""

import argparse
import sys
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING, Any, NoReturn

if TYPE_CHECKING:
    _SubParsers = argparse._SubParsersAction[argparse.ArgumentParser]
else:  # not subscriptable at run time
    _SubParsers = argparse._SubParsersAction


def whole_number(low: int, high: int) -> "Callable[[str], int]":
    """An argparse type: a whole number from `low` to `high`, or the error saying so."""
    def parse(text: str) -> int:
        if not text.isdigit() or not low <= int(text) <= high:
            raise argparse.ArgumentTypeError(f"must be a whole number from {low} to {high:,}, "
                                             f"got {text!r}")
        return int(text)
    return parse


class CommandParser(argparse.ArgumentParser):
    def __init__(self, *args: Any, one_line_errors: bool = False, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.one_line_errors = one_line_errors
        self.register("action", "parsers", Commands)  # what add_subparsers() makes
        self.arguments: list[str] = []  # what parse_args() was given, for Commands

    def parse_known_args(self, args: Iterable[str] | None = None, namespace: Any = None) -> Any:
        self.arguments = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def error(self, message: str) -> NoReturn:
        if self.one_line_errors:
            self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")
        super().error(message)


class Commands(_SubParsers):
    """The commands of a CommandParser; their parsers are CommandParsers too (add_subparsers()
    gives them the class of the parser it is called on)."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: str | Sequence[Any] | None,
        option_string: str | None = None,
    ) -> None:
        assert isinstance(values, list) and values  # nargs=PARSER: the name, then the rest
        name, *rest = values
        given = parser.arguments if isinstance(parser, CommandParser) else values
        if len(given) > len(values):  # the command takes all that follows its name: not all
            parser.error(f"{given[0]} is a printer option, and `{parser.prog} {name}` runs no "
                         f"printer: its own options go after its name (see {parser.prog} {name} "
                         "--help)")
        # argparse has checked the name against the choices; parse_args(), where argparse
        # calls parse_known_args(), makes an argument the command does not know its own error.
        command = self.choices[name].parse_args(rest)
        for key, value in vars(command).items():
            setattr(namespace, key, value)
        if self.dest is not argparse.SUPPRESS:
            setattr(namespace, self.dest, name)
