"""A trace turned into what the report plots: series on simulated time, and marks.

Plain lists, no plotting: the tests look at these, and plots.py draws them.
"""

import re
from dataclasses import dataclass, field

from fake_marlin.emulator.report.reader import Trace
from fake_marlin.emulator.report.wirelog import describe

# Bin widths for commands per second, in simulated seconds: the smallest that keeps a trace
# to at most MAX_BINS bins, so an hour's print is as readable as a minute's.
BIN_WIDTHS = (1.0, 2.0, 5.0, 10.0, 15.0, 30.0, 60.0, 120.0, 300.0, 600.0, 1800.0, 3600.0)
MAX_BINS = 600
# A line the printer sent that reports an error: Marlin's and Repetier's `Error:`, the
# Ultimaker protocol's `ProtoError:`.
ERROR_LINE = re.compile(r"(?:Proto)?Error:")


@dataclass(frozen=True)
class Mark:
    t: float
    label: str  # what a person reads for it, as the wire log says it (wirelog.describe)


@dataclass
class Heater:
    t: list[float] = field(default_factory=list)
    current: list[float] = field(default_factory=list)
    target: list[float] = field(default_factory=list)


@dataclass
class Series:
    start: float
    stop: float
    planner: int | None  # blocks the planner holds, from the begin record
    bin_seconds: float
    rate_t: list[float]  # start of each bin
    rate: list[float]  # commands executed per simulated second in that bin
    room_t: list[float]
    room: list[int]  # free planner blocks from room_t[i] on
    heaters: dict[str, Heater]  # in the order T0, T1, ..., B
    # Rows of marks, in the order the report shows them: resends, errors, then one row per
    # fault kind in order of first firing, then disconnects, resets, connects.
    marks: dict[str, list[Mark]]


def bin_width(duration: float) -> float:
    for width in BIN_WIDTHS:
        if duration / width <= MAX_BINS:
            return width
    return max(BIN_WIDTHS[-1], duration / MAX_BINS)  # a trace of years: still MAX_BINS bins


def build_series(trace: Trace) -> Series:
    start = float(trace.begin["t"])
    stop = max(start, float(trace.records[-1]["t"])) if trace.records else start
    width = bin_width(stop - start)
    bins = [0] * (int((stop - start) // width) + 1)
    room_t: list[float] = []
    room: list[int] = []
    heaters: dict[str, Heater] = {}
    resends: list[Mark] = []
    errors: list[Mark] = []
    faults: dict[str, list[Mark]] = {}
    resets: list[Mark] = []
    connects: list[Mark] = []
    disconnects: list[Mark] = []
    pending = ""  # the printer's output since its last newline
    for record in trace.records:
        t = float(record["t"])
        match record["k"]:
            case "cmd":
                bins[min(int((t - start) // width), len(bins) - 1)] += 1
            case "room":
                room_t.append(t)
                room.append(int(record["v"]))
            case "temp":
                heater = heaters.setdefault(record["h"], Heater())
                heater.t.append(t)
                heater.current.append(float(record["c"]))
                heater.target.append(float(record["s"]))
            case "reject":
                resends.append(Mark(t, describe(record)))
            case "out":
                *lines, pending = (pending + record["b"]).split("\n")
                errors += [Mark(t, line.strip()) for line in lines if ERROR_LINE.match(line.strip())]
            case "fault":
                faults.setdefault(record["f"], []).append(Mark(t, describe(record)))
            case "reset":
                resets.append(Mark(t, describe(record)))
                pending = ""
            case "connect":
                connects.append(Mark(t, describe(record)))
            case "disconnect":
                disconnects.append(Mark(t, describe(record)))
    marks = {"resends": resends, "errors": errors}
    marks.update((f"fault: {kind}", found) for kind, found in faults.items())
    marks.update({"disconnects": disconnects, "resets": resets, "connects": connects})
    planner = trace.begin.get("planner")
    return Series(
        start=start, stop=stop, planner=planner if isinstance(planner, int) else None,
        bin_seconds=width, rate_t=[start + i * width for i in range(len(bins))],
        rate=[count / width for count in bins], room_t=room_t, room=room,
        heaters=dict(sorted(heaters.items(), key=lambda item: _heater_order(item[0]))),
        marks=marks,
    )


def _heater_order(name: str) -> tuple[int, int, str]:
    """T0, T1, ... first in number order, then the bed, then anything else by name."""
    if name[:1] == "T" and name[1:].isdigit():
        return (0, int(name[1:]), name)
    return (1 if name == "B" else 2, 0, name)
