"""What the live view shows of a printer, read from its PrinterServer as plain JSON-able data.

`rows` gives the farm page one dict per printer, `detail` a printer's page: its row, the wire
tail and the series for its plots. Both only read: the series and the wire are what the server
recorded while the page was watched (PrinterServer.watch, source.watched_detail), sampled by
`sample`. Times are trio's (simulated seconds, as the report's), never the wall clock.
"""

from collections.abc import Iterable, Sequence
from typing import Any

import trio

from fake_marlin.emulator.printer import failures
from fake_marlin.emulator.report.wirelog import show_bytes
from fake_marlin.emulator.server.lifecycle import PrinterServer, Watch

TAIL_LINES = 100  # lines of the wire tail, each way
LINE_CHARS = 240  # a longer line is cut (a binary protocol's bytes run on without a newline)
HEATING_MARGIN = 3.0  # °C from its target: a heater further away is still heating (or cooling)
_PLAIN = frozenset(range(0x20, 0x7F)) - {0x5C}


def rows(servers: Sequence[PrinterServer], numbers: Sequence[int],
         paths: Sequence[str]) -> list[dict[str, Any]]:
    """One row per printer, in the order given."""
    now = trio.current_time()
    return [row(server, number, path, now) for server, number, path in zip(servers, numbers, paths)]


def row(server: PrinterServer, number: int, path: str, now: float | None = None) -> dict[str, Any]:
    """A printer's row of the farm page: who it is, its host, what it is doing, its counts."""
    if now is None:
        now = trio.current_time()
    printer = server.printer
    heaters = failures.heaters(printer)
    temperatures = {name: {"actual": round(heater.temperature(now), 1),
                           "target": round(heater.target, 1)}
                    for name, heater in heaters.items()}
    planner = printer.planner
    queued = planner.moves(now)
    sd = printer.sd
    job = None
    if sd.selected is not None and (sd.printing or sd.selected.position):
        size = len(sd.selected.data)
        job = {"kind": "sd", "file": sd.selected.short or sd.selected.path.name,
               "printing": sd.printing, "position": sd.selected.position, "size": size,
               "percent": round(100.0 * sd.selected.position / size, 1) if size else 100.0}
    speaking = server.speaking
    if printer.halted:
        state = "halted"
    elif not server.booted:
        state = "booting"
    elif speaking == "stk500":
        state = "bootloader"
    elif sd.printing or queued:
        state = "printing"
    elif any(heater.target > 0 and abs(temperatures[name]["actual"] - heater.target)
             > HEATING_MARGIN for name, heater in heaters.items()):
        state = "heating"
    else:
        state = "idle"
    seen = server.seen
    last_error = seen.last_error
    firmware = server.firmware
    return {
        "number": number,
        "path": path,
        "protocol": speaking,  # None: not yet known (booting, or waiting for the host's bytes)
        "protocol_setting": server.config.protocol,
        "firmware": firmware.profile.name,
        "firmware_title": firmware.profile.title,
        "uuid": firmware.identity.uuid,
        "connected": server.host_connected,
        "connects": seen.connects,
        "boots": server.boots,
        "state": state,
        "halted": printer.halted,
        "heaters": temperatures,
        "hotend": temperatures.get("T0"),
        "bed": temperatures["B"],
        "planner": {"queued": queued, "size": planner.max_moves},
        "commands": server.commands,
        "last_command": server.last_command,
        "job": job,
        "resends": seen.refusals,
        "faults": dict(seen.faults_fired),
        "faults_fired": sum(seen.faults_fired.values()),
        "last_error": None if last_error is None else {
            "t": round(last_error[0], 3), "text": last_error[1], "kind": last_error[2]},
        "powered_on": round(seen.powered_on, 4),
        "time": round(now, 4),
    }


def detail(server: PrinterServer, number: int, path: str) -> dict[str, Any]:
    """A printer's page: its row, identity and recent events, and what was recorded while its
    page was watched: the wire tail (the last TAIL_LINES lines each way, in the order they
    crossed) and the series its plots draw."""
    now = trio.current_time()
    watch = server.watching
    identity = server.firmware.identity
    return {
        "row": row(server, number, path, now),
        "identity": {"uuid": identity.uuid, "serial": identity.serial,
                     "machine_name": identity.machine_name},
        "events": [{"t": round(t, 3), "kind": kind, "text": text}
                   for t, kind, text in server.seen.events],
        "watching": None if watch is None else {"since": round(watch.since, 3),
                                                "until": round(watch.until, 3)},
        "tail": [] if watch is None else wire_tail(watch.wire),
        "series": series(() if watch is None else watch.samples),
        "time": round(now, 4),
    }


def sample(server: PrinterServer, watch: Watch, now: float) -> dict[str, Any]:
    """What a watched printer's plots need at `now`, as one sample (the caller keeps it)."""
    printer = server.printer
    heaters = failures.heaters(printer)
    return {"t": round(now, 4), "commands": server.commands,
            "queued": printer.planner.moves(now), "size": printer.planner.max_moves,
            "heaters": {name: (round(heater.temperature(now), 2), round(heater.target, 1))
                        for name, heater in heaters.items()}}


def series(samples: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """The samples as columns: times, commands per second (between one sample and the one
    before it; None for the first), blocks queued in the planner, and each heater's
    temperature and target."""
    t: list[float] = []
    rate: list[float | None] = []
    queued: list[int] = []
    heaters: dict[str, dict[str, list[float]]] = {}
    size = 0
    before: dict[str, Any] | None = None
    for one in samples:
        t.append(one["t"])
        if before is None or one["t"] <= before["t"]:
            rate.append(None)  # the first sample has no rate: nothing before it
        else:
            rate.append(round((one["commands"] - before["commands"]) / (one["t"] - before["t"]), 2))
        queued.append(one["queued"])
        size = one["size"]
        for name, (actual, target) in one["heaters"].items():
            heater = heaters.setdefault(name, {"actual": [], "target": []})
            heater["actual"].append(actual)
            heater["target"].append(target)
        before = one
    return {"t": t, "rate": rate, "queued": queued, "planner_size": size, "heaters": heaters}


def wire_tail(wire: Iterable[tuple[float, str, bytes]],
              per_direction: int = TAIL_LINES) -> list[dict[str, Any]]:
    """The recorded reads and writes as lines, each with the time its end crossed and its
    direction ("in": to the printer, "out": to the host); the last `per_direction` lines each
    way, in the order they crossed. A line the recording began in the middle of is left out;
    one not yet ended is shown as it is so far (`partial`)."""
    lines: list[tuple[float, str, bytes, bool]] = []
    pending = {"in": bytearray(), "out": bytearray()}
    begun = {"in": False, "out": False}
    pending_t = {"in": 0.0, "out": 0.0}
    chunks = list(wire)
    maxlen = getattr(wire, "maxlen", None)
    if maxlen is None or len(chunks) < maxlen:
        begun = {"in": True, "out": True}  # nothing was dropped: the first line is whole
    for t, direction, data in chunks:
        buffer = pending[direction]
        start = 0
        while True:
            end = data.find(b"\n", start)
            if end < 0:
                buffer += data[start:]
                pending_t[direction] = t
                if len(buffer) > LINE_CHARS:  # no line ends here (binary): cut it into lines
                    if begun[direction]:
                        lines.append((t, direction, bytes(buffer), False))
                    begun[direction] = True
                    buffer.clear()
                break
            buffer += data[start:end + 1]
            if begun[direction]:
                lines.append((t, direction, bytes(buffer), False))
            begun[direction] = True
            buffer.clear()
            start = end + 1
    for direction, buffer in pending.items():
        if buffer and begun[direction]:
            lines.append((pending_t[direction], direction, bytes(buffer), True))
    lines.sort(key=lambda line: line[0])  # stable: lines of one moment stay in crossing order
    kept = {"in": 0, "out": 0}
    shown: list[dict[str, Any]] = []
    for t, direction, data, partial in reversed(lines):
        if kept[direction] < per_direction:
            kept[direction] += 1
            shown.append({"t": round(t, 4), "dir": direction, "text": show(data),
                          **({"partial": True} if partial else {})})
    shown.reverse()
    return shown


def show(data: bytes) -> str:
    """A line as the report's wire log spells bytes (printable ASCII as it is, \\xNN else),
    without its line end, cut at LINE_CHARS."""
    if data.endswith(b"\n"):
        data = data[:-1]
    if data.endswith(b"\r"):
        data = data[:-1]
    cut = len(data) > LINE_CHARS
    data = data[:LINE_CHARS]
    if _PLAIN.issuperset(data):
        text = data.decode("ascii")
    else:
        text = show_bytes(data.decode("latin-1"))
    return text + " …" if cut else text
