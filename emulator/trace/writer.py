"""The wire trace: what crossed the wire and what the printer did, as JSON lines (docs/trace.md).

The printer server calls one method per thing that happened; each queues one record, and
write_queued() writes them once the printer has answered (flush() also pushes them to the file,
after FLUSH_EVERY records and at each fault, refusal, reset and connection). Times are read here,
from trio's clock (simulated, repeatable) and the wall clock (only for the `w` field, which says
how the run went in real time). A trace costs the printer nothing when it is off: the server
only calls in here when one was asked for.
"""

import gzip
import io
import json
import math
import re
import sys
import time
from collections.abc import Callable
from typing import IO, Any

import trio

from fake_marlin.emulator.printer.thermal import AMBIENT
from fake_marlin.emulator.protocols.commstack import FrameRejected
from fake_marlin.emulator.protocols.marlin import LineRejected
from fake_marlin.emulator.protocols.repetier import CommandRejected
from fake_marlin.emulator.protocols.ultimaker import PacketRejected

VERSION = 1
_BYTES_KINDS = frozenset(("in", "out"))
# A printer killed mid-run (the field bug being chased) loses at most this many records: the
# trace is flushed to the file after so many, and at each fault, refusal, reset and connection.
FLUSH_EVERY = 256
SAMPLE_INTERVAL = 1.0  # simulated seconds between heater samples while a heater is in use
_UNIT_TEXT = 80  # a fault's unit is cut to this many characters


class TraceError(Exception):
    """The trace file cannot be written (the user's path)."""


def _text(data: bytes) -> str:
    return data.decode("latin-1")  # byte n is code point n: any byte survives JSON


_NEEDS_DUMPS = re.compile(r'[\x00-\x09\x0b\x0c\x0e-\x1f"\\\x7f-\xff]')


def _quoted(text: str) -> str:
    """`text` as a JSON string: plain text and its line ends cheaply, the rest as json.dumps
    writes it (most records are a line or two of printable ASCII)."""
    if _NEEDS_DUMPS.search(text):
        return json.dumps(text)
    return '"' + text.replace("\r", "\\r").replace("\n", "\\n") + '"'


# Each protocol's refusal event, and why it refused and the number it asked for.
_REJECT_FACTS: dict[type, Callable[[Any], tuple[str, int | None]]] = {
    LineRejected: lambda event: (event.error.name.lower().replace("_", " "), event.resend),
    PacketRejected: lambda event: (event.reason.name.lower().replace("_", " "), event.expected),
    CommandRejected: lambda event: (event.reason, event.resend),
    FrameRejected: lambda event: (event.reason, None),
}
REJECTIONS = frozenset(_REJECT_FACTS)  # what watch_rejects looks for in a protocol's events


def reject_facts(event: object) -> tuple[str, int | None] | None:
    """Why a protocol event refused what it got, and the number it asked for; None for an
    event that refuses nothing."""
    facts = _REJECT_FACTS.get(type(event))
    return None if facts is None else facts(event)


class Trace:
    def __init__(self, stream: IO[str], facts: dict[str, object], path: str = "") -> None:
        self._stream = stream
        self._path = path
        self._broken = False  # a write failed (a full disk): the printer runs on untraced
        self._facts = {"version": VERSION, **facts}  # for the `begin` record
        self._origin = 0.0  # trio time at power-on: `t` counts from there
        self._wall_origin = time.monotonic()
        self._room: int | None = None
        self._targets: tuple[float, ...] = ()  # the heaters' targets at the last sample
        self._in_use = False  # a heater was in use at the last sample
        self._next_sample = -math.inf
        self.commands = self.bytes_in_count = self.bytes_out_count = 0
        self._closed = False
        self._last = 0.0
        self._unflushed = 0
        self._queued: list[tuple[float, float, str, object]] = []

    @classmethod
    def open(cls, path: str, protocol: str, speed: float, seed: int, scenario: str | None = None,
             printer: int = 1, planner: int = 15) -> "Trace":
        """A trace into `path` (gzip-compressed if it ends in .gz), of a printer so set up;
        TraceError if it cannot be written."""
        try:
            if path.endswith(".gz"):
                # mtime=0: no date in the gzip header.
                raw = gzip.GzipFile(path, "wb", mtime=0)
                stream: IO[str] = io.TextIOWrapper(raw, encoding="utf-8")
            else:
                stream = open(path, "w", encoding="utf-8")
        except OSError as error:
            raise TraceError(f"cannot write the trace {path}: {error.strerror or error}") from None
        return cls(stream, {"protocol": protocol, "speed": speed, "seed": seed,
                            "scenario": scenario, "printer": printer, "planner": planner}, path)

    # -- records ---------------------------------------------------------------------------
    # A record is queued with its times and what it says, and written by write_queued(), which
    # the server calls once the printer has answered the read (or said what it says on its
    # own): the formatting and the file write then overlap with the host's own work on that
    # answer instead of delaying it.
    def _queue(self, kind: str, payload: object) -> None:
        try:
            self._last = now = trio.current_time() - self._origin
        except RuntimeError:  # closed after trio.run returned: at the last moment it saw
            now = self._last
        self._queued.append((now, time.monotonic() - self._wall_origin, kind, payload))

    def write_queued(self) -> None:
        queued, self._queued = self._queued, []
        if self._broken or not queued:
            return
        lines = []
        for now, wall, kind, payload in queued:
            if kind in _BYTES_KINDS:
                fields = f',"b":{_quoted(_text(payload))}'  # type: ignore[arg-type]
            elif kind == "cmd":
                fields = f',"c":{_quoted(payload)}'  # type: ignore[arg-type]
            else:
                fields = payload  # type: ignore[assignment]
            lines.append(f'{{"t":{now:.6f},"w":{wall:.3f},"k":"{kind}"{fields}}}\n')
        try:
            self._stream.write("".join(lines))
        except OSError as error:
            self._give_up(error)
            return
        self._unflushed += len(lines)
        if self._unflushed >= FLUSH_EVERY:
            self.flush()

    def flush(self) -> None:
        self.write_queued()
        self._unflushed = 0
        if self._broken:
            return
        try:
            self._stream.flush()
        except OSError as error:
            self._give_up(error)

    def _give_up(self, error: OSError) -> None:
        """The printer must not die of its trace: say so once, and trace no more."""
        self._broken = True
        print(f"fake-marlin: cannot write the trace {self._path}: {error.strerror or error}; "
              "tracing stopped, the printer runs on", file=sys.stderr)

    def begin(self) -> None:
        """The printer powers on: `t` counts from now."""
        self._origin = trio.current_time()
        self._queue("begin", "," + json.dumps(self._facts, separators=(",", ":"))[1:-1])

    def bytes_in(self, data: bytes) -> None:
        self.bytes_in_count += len(data)
        self._queue("in", data)

    def bytes_out(self, data: bytes) -> None:
        self.bytes_out_count += len(data)
        self._queue("out", data)

    def command(self, text: str) -> None:
        self.commands += 1
        self._queue("cmd", text)

    def room(self, free: int) -> None:
        if free != self._room:
            self._room = free
            self._queue("room", f',"v":{free}')

    def heaters_due(self, now: float, targets: tuple[float, ...]) -> bool:
        """Whether to sample the heaters now: a target changed, or a sample is due while a
        heater is in use (its target set, or not yet back at room temperature)."""
        if targets != self._targets:
            return True
        return now >= self._next_sample and self._in_use

    def heaters(self, now: float, readings: list[tuple[str, float, float]]) -> None:
        for name, current, target in readings:
            self._queue("temp", f',"h":"{name}","c":{current:.2f},"s":{target:g}')
        self._targets = tuple(target for _, _, target in readings)
        self._in_use = heaters_in_use(readings)
        self._next_sample = now + SAMPLE_INTERVAL

    def fault(self, kind: str, direction: str | None, count: int | None = None,
              unit: bytes | None = None) -> None:
        fields = f',"f":{json.dumps(kind)},"dir":{json.dumps(direction)}'
        if count is not None:
            fields += f',"n":{count}'
        if unit is not None:
            fields += f',"u":{json.dumps(_text(unit[:_UNIT_TEXT]))}'
        self._queue("fault", fields)
        self.flush()

    def reject(self, event: object) -> None:
        facts = reject_facts(event)
        if facts is not None:
            why, resend = facts
            self._queue("reject", f',"why":{json.dumps(why)},"resend":{json.dumps(resend)}')
            self.flush()

    def reset(self, why: str) -> None:
        self._room = None
        self._queue("reset", f',"why":{json.dumps(why)}')
        self.flush()

    def connect(self) -> None:
        self._queue("connect", "")
        self.flush()

    def disconnect(self, seconds: float) -> None:
        self._queue("disconnect", f',"seconds":{seconds:g}')
        self.flush()

    def verdict(self, facts: dict[str, object]) -> None:
        self._queue("verdict", "," + json.dumps(facts, separators=(",", ":"))[1:-1])

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._queue("end", f',"commands":{self.commands},"bytes_in":{self.bytes_in_count},'
                           f'"bytes_out":{self.bytes_out_count}')
        self.write_queued()
        try:
            self._stream.close()
        except OSError as error:
            if not self._broken:
                self._give_up(error)


def heater_readings(printer, now: float) -> list[tuple[str, float, float]]:
    heaters = [(f"T{index}", heater) for index, heater in enumerate(printer.hotends)]
    heaters.append(("B", printer.bed))
    return [(name, heater.temperature(now), heater.target) for name, heater in heaters]


def heaters_in_use(readings: list[tuple[str, float, float]]) -> bool:
    """Whether any heater has a target or is still away from room temperature."""
    return any(target > 0 or abs(current - AMBIENT) > 0.5 for _, current, target in readings)
