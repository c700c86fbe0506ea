"""Read a trace (docs/trace.md): JSON lines, plain or gzip-compressed.

A trace that cannot be read is a TraceError whose message is one line naming the file and the
line: a person gets told what is wrong with their file, never a traceback. Records of kinds
this version does not know are skipped (a newer writer may add kinds), and counted.
"""

import gzip
import json
import math
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

VERSION = 1

# The keys each known kind must carry, with the JSON types they may have.
_NUMBER = (int, float)
REQUIRED: dict[str, dict[str, tuple[type, ...]]] = {
    "begin": {"version": (int,)},
    "in": {"b": (str,)},
    "out": {"b": (str,)},
    "cmd": {"c": (str,)},
    "room": {"v": _NUMBER},
    "temp": {"h": (str,), "c": _NUMBER, "s": _NUMBER},
    "fault": {"f": (str,)},
    "reject": {},
    "reset": {},
    "connect": {},
    "disconnect": {},
    "verdict": {"passed": (bool,)},
    "end": {},
}
KINDS = tuple(REQUIRED)
# Keys a kind may leave out, but whose values must have these types when they are there.
OPTIONAL: dict[str, dict[str, tuple[type, ...]]] = {
    "verdict": {"host": (dict, type(None)), "missing": (list, type(None)),
                "duplicated": (list, type(None))},
}


class TraceError(Exception):
    """The file is no trace this version can read; str() is one line for a person."""


@dataclass
class Trace:
    path: Path
    begin: dict[str, Any]
    records: list[dict[str, Any]]  # every known record after `begin`, `end` included, in order
    end: dict[str, Any] | None = None  # None: the writer stopped before its last line
    verdict: dict[str, Any] | None = None
    skipped: dict[str, int] = field(default_factory=dict)  # unknown kind -> how many
    # Why the file stops short, when a printer killed mid-write left a cut record or a cut
    # compressed stream: what came before is read and shown, with this said.
    cut_short: str | None = None

    @property
    def name(self) -> str:
        """The file's name without .gz, .jsonl and .trace: what a report is called after."""
        name = self.path.name
        for suffix in (".gz", ".jsonl", ".json", ".trace"):
            name = name.removesuffix(suffix)
        return name or "trace"


def read_trace(path: str | Path) -> Trace:
    path = Path(path)
    begin: dict[str, Any] | None = None
    trace: Trace | None = None
    number = 0
    cut: list[str] = []
    last_t = -math.inf
    for number, record in _records(path, cut):
        kind = record["k"]
        if record["t"] < last_t:
            raise TraceError(f"{path}:{number}: a {kind!r} record at {record['t']} s, before "
                             f"the record above it ({last_t} s): time never goes back in a trace")
        last_t = record["t"]
        if begin is None:
            if kind != "begin":
                raise TraceError(f"{path}:{number}: not a fake-marlin trace (the first record is "
                                 f"{kind!r}, not 'begin')")
            if record["version"] != VERSION:
                raise TraceError(f"{path}:{number}: trace version {record['version']}; this "
                                 f"fake-marlin reads version {VERSION}")
            begin = record
            trace = Trace(path, begin, [])
            continue
        assert trace is not None
        if kind not in REQUIRED:
            trace.skipped[kind] = trace.skipped.get(kind, 0) + 1
            continue
        if trace.end is not None:
            raise TraceError(f"{path}:{number}: a {kind!r} record after the 'end' record")
        trace.records.append(record)
        if kind == "end":
            trace.end = record
        elif kind == "verdict":
            trace.verdict = record
    if trace is None:
        if cut:
            raise TraceError(cut[0])
        raise TraceError(f"{path}: empty: no records at all")
    trace.cut_short = cut[0] if cut else None
    return trace


def _records(path: Path, cut: list[str]) -> Iterator[tuple[int, dict[str, Any]]]:
    """(line number, record) for every line, checked against REQUIRED for the known kinds.
    A file cut short (a last line without its line end, a compressed stream that stops) ends
    the records, and `cut` gets the reason."""
    number = 0
    try:
        with _open(path) as file:
            for number, raw in enumerate(file, 1):
                if not raw.endswith(b"\n"):
                    cut.append(f"{path}:{number}: the file ends in the middle of a record "
                               "(was the writer stopped?)")
                    return
                if raw.strip():
                    yield number, _parse(path, number, raw)
    except OSError as error:  # also gzip's BadGzipFile
        where = f"{path}:{number + 1}" if number else str(path)
        raise TraceError(f"{where}: cannot read: {error.strerror or error}") from None
    except (EOFError, zlib.error) as error:
        cut.append(f"{path}:{number + 1}: the compressed file is cut short or damaged ({error})")


def _open(path: Path) -> Any:
    with open(path, "rb") as probe:
        compressed = probe.read(2) == b"\x1f\x8b"
    return gzip.open(path, "rb") if compressed else open(path, "rb")


def _parse(path: Path, number: int, raw: bytes) -> dict[str, Any]:
    try:
        record = json.loads(raw)
    except UnicodeDecodeError:
        raise TraceError(f"{path}:{number}: not UTF-8 text") from None
    except ValueError as error:
        raise TraceError(f"{path}:{number}: not JSON ({error.args[0].split(':')[0]})") from None
    if not isinstance(record, dict):
        raise TraceError(f"{path}:{number}: not a JSON object")
    kind = record.get("k")
    if not isinstance(kind, str):
        raise TraceError(f"{path}:{number}: a record without its kind ('k')")
    if not isinstance(record.get("t"), _NUMBER) or isinstance(record.get("t"), bool):
        raise TraceError(f"{path}:{number}: a {kind!r} record without its time ('t')")
    if not math.isfinite(record["t"]):
        raise TraceError(f"{path}:{number}: a {kind!r} record at no real time ({record['t']})")
    for key, types in OPTIONAL.get(kind, {}).items():
        if key in record and not isinstance(record[key], types):
            raise TraceError(f"{path}:{number}: a {kind!r} record whose {key!r} is "
                             f"not {_describe(types)}")
    for key, types in REQUIRED.get(kind, {}).items():
        value = record.get(key)
        if not isinstance(value, types) or (isinstance(value, bool) and bool not in types):
            raise TraceError(f"{path}:{number}: a {kind!r} record whose {key!r} is "
                             f"{'missing' if key not in record else 'not ' + _describe(types)}")
    return record


def _describe(types: tuple[type, ...]) -> str:
    names = {int: "a number", float: "a number", str: "text", bool: "true or false",
             dict: "an object", list: "a list"}
    return " or ".join(dict.fromkeys(names.get(t, "null") for t in types))
