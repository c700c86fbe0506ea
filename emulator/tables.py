"""Typed reading of TOML files (scenarios, farm files, firmware profiles): every mistake is
reported with the file, the key and the problem, never as a traceback."""

import tomllib
from pathlib import Path
from typing import Self


class TableError(Exception):
    """A file that cannot be used; the message names the file, key and problem."""


class TableReader:
    """Typed access to one table of the file, with errors that say where (as `error`)."""

    error: type[TableError] = TableError

    def __init__(self, path: Path | str, where: str, table: dict) -> None:
        self.path, self.where, self.table = path, where, table
        self._used: set[str] = set()

    def fail(self, key: str, problem: str):
        raise self.error(f"{self.path}: {self.where}{key}: {problem}".replace(": : ", ": "))

    def get(self, key: str, kinds, default=None, choices=None, minimum=None, maximum=None):
        self._used.add(key)
        if key not in self.table:
            return default
        value = self.table[key]
        kinds = kinds if isinstance(kinds, tuple) else (kinds,)
        if isinstance(value, bool) and bool not in kinds or not isinstance(value, kinds):
            names = " or ".join(kind.__name__.replace("str", "a string").replace("float", "a number")
                                .replace("int", "a whole number").replace("bool", "true or false")
                                .replace("list", "a list") for kind in kinds)
            self.fail(key, f"must be {names}, not {value!r}")
        if choices is not None and value not in choices:
            self.fail(key, f"must be one of {', '.join(map(repr, choices))}, not {value!r}")
        if minimum is not None and value < minimum:
            self.fail(key, f"must be at least {minimum}, not {value!r}")
        if maximum is not None and value > maximum:
            self.fail(key, f"must be at most {maximum}, not {value!r}")
        return value

    def table_at(self, key: str) -> Self:
        value = self.get(key, dict, {})
        return type(self)(self.path, f"[{key}] ", value)

    def finish(self) -> None:
        unknown = sorted(set(self.table) - self._used)
        if unknown:
            self.fail(unknown[0], "is not a key this table knows")


def read_toml(path: Path, error: type[TableError] = TableError) -> dict:
    """A TOML file's tables, or `error` saying why it cannot be read."""
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as problem:
        raise error(f"{path}: cannot read: {problem.strerror}") from None
    except UnicodeDecodeError:
        raise error(f"{path}: not UTF-8 text") from None
    except tomllib.TOMLDecodeError as problem:
        raise error(f"{path}: not valid TOML: {problem}") from None
