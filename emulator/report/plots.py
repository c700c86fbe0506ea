"""The report's figure: four panels on one simulated time axis, drawn by matplotlib as SVG.

Figure objects are drawn without pyplot, so no GUI backend is ever loaded and nothing global
changes in a process that imports this. The SVG is repeatable: no date in its metadata, and
the ids matplotlib makes are salted with a constant instead of a random number, so a report of
the same trace is the same bytes. Text stays text (svg.fonttype none): small, and selectable.

Long traces are thinned to what a screen can show: the planner's room becomes its minimum and
maximum per slice of time once there are more changes than MAX_STEPS, a heater keeps every
n-th sample beyond MAX_SAMPLES, and marks closer than a slice apart are drawn once.
"""

import io
import re
from typing import Any

from fake_marlin.emulator.report.series import Series

MAX_STEPS = 4000
MAX_SAMPLES = 1200
SLICES = 1500  # across the width of the figure
WIDTH = 13.0  # inches, at 72 points an inch in the SVG
COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22")
MARK_COLOURS = {
    "resends": "#d62728", "errors": "#ff7f0e", "disconnects": "#8c564b", "resets": "#111111",
    "connects": "#2ca02c",
}
FAULT_COLOUR = "#9467bd"
STYLE: dict[str, Any] = {
    "svg.hashsalt": "fake-marlin report",
    "svg.fonttype": "none",
    "font.family": ["DejaVu Sans", "sans-serif"],
    "font.size": 10.0,
    "axes.titlesize": 11.0,
    "axes.titleweight": "bold",
    "axes.titlelocation": "left",
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.grid": True,
    "grid.color": "#e4e4e4",
    "grid.linewidth": 0.8,
    "legend.frameon": False,
    "legend.fontsize": 9.0,
}


def figure_svg(series: Series) -> str:
    """The figure as an <svg> element to put inline in a page (no XML prologue)."""
    import matplotlib
    from matplotlib.figure import Figure

    with matplotlib.rc_context(STYLE):  # type: ignore[arg-type]  # keys typed as literals
        rows = [row for row, marks in series.marks.items() if marks]
        mark_height = 0.6 + 0.28 * max(len(rows), 1)
        heights = [2.0, 2.0, 2.6, mark_height]
        figure = Figure(figsize=(WIDTH, sum(heights) + 1.4), layout="constrained")
        rate, room, heat, marks = figure.subplots(
            4, 1, sharex=True, gridspec_kw={"height_ratios": heights}
        )
        _rate(rate, series)
        _room(room, series)
        _temperatures(heat, series)
        _marks(marks, series, rows)
        for axes in (rate, room, heat):
            for reset in series.marks["resets"]:
                axes.axvline(reset.t, color=MARK_COLOURS["resets"], linewidth=0.8, linestyle=":")
        span = max(series.stop - series.start, 1.0)
        # A little room on the left: marks at the very start (the power-up reset) stay visible.
        marks.set_xlim(series.start - span * 0.01, series.start + span * 1.01)
        marks.xaxis.set_major_locator(_time_locator(span))
        marks.xaxis.set_major_formatter(_time_formatter(span))
        marks.set_xlabel("simulated time" + (" (s)" if span < 120 else " (h:mm:ss)"))
        out = io.StringIO()
        figure.savefig(out, format="svg", metadata={"Date": None})
    text = out.getvalue()
    # Its RDF metadata (creator, format) is of no use inline and names outside addresses.
    return re.sub(r"\s*<metadata>.*?</metadata>", "", text[text.index("<svg"):], count=1, flags=re.S)


def _rate(axes, series: Series) -> None:
    width = series.bin_seconds
    axes.set_title("Commands executed per second"
                   + ("" if width == 1 else f" (averaged over {width:g} s)"))
    if any(series.rate):
        times = [*series.rate_t, series.rate_t[-1] + width]
        rates = [*series.rate, series.rate[-1]]
        axes.fill_between(times, rates, step="post", color=COLOURS[0], alpha=0.35, linewidth=0)
        axes.step(times, rates, where="post", color=COLOURS[0], linewidth=1.0)
    else:
        _empty(axes, "no commands were executed")
    axes.set_ylabel("commands/s")
    axes.set_ylim(bottom=0)


def _room(axes, series: Series) -> None:
    """Drawn as the blocks queued (its size less its room), so that filling goes up."""
    size = series.planner or max(series.room, default=0)
    axes.set_title(f"Planner: blocks queued, of {size} (its room is the rest; 0 = starved)")
    axes.set_ylabel("blocks queued")
    if not series.room:
        _empty(axes, "no planner samples")
        return
    times = [*series.room_t, series.stop]
    queued = [size - free for free in (*series.room, series.room[-1])]
    if len(times) <= MAX_STEPS:
        axes.fill_between(times, queued, step="post", color=COLOURS[2], alpha=0.25, linewidth=0)
        axes.step(times, queued, where="post", color=COLOURS[2], linewidth=1.0)
    else:
        edges, lows, highs = _envelope(times, queued, series.start, series.stop)
        axes.fill_between(edges, lows, highs, step="post", color=COLOURS[2], alpha=0.6,
                          linewidth=0, label="least and most queued, per slice")
        axes.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), borderaxespad=0.3)
    axes.set_ylim(0, size * 1.1 + 0.5)


def _temperatures(axes, series: Series) -> None:
    axes.set_title("Heaters: temperature (solid) against target (dashed)")
    axes.set_ylabel("°C")
    if not series.heaters:
        _empty(axes, "no heater samples")
        return
    for number, (name, heater) in enumerate(series.heaters.items()):
        colour = COLOURS[(number + 1) % len(COLOURS)]
        step = max(1, len(heater.t) // MAX_SAMPLES)
        times, current = heater.t[::step], heater.current[::step]
        if times[-1] != heater.t[-1]:
            times, current = [*times, heater.t[-1]], [*current, heater.current[-1]]
        axes.plot(times, current, color=colour, linewidth=1.4, label=name)
        # A target holds until it is changed: drawn on to the end of the trace.
        target_t, target = _changes([*heater.t, series.stop], [*heater.target, heater.target[-1]])
        axes.step(target_t, target, where="post", color=colour, linewidth=1.0, linestyle="--",
                  label=f"{name} target")
    axes.set_ylim(bottom=0)
    axes.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), borderaxespad=0.3)


def _marks(axes, series: Series, rows: list[str]) -> None:
    axes.set_title("Marks: resends, errors, faults, resets")
    axes.grid(False)
    axes.grid(True, axis="x")
    if not rows:
        _empty(axes, "nothing went wrong: no resends, errors, faults or resets")
        axes.set_yticks([])
        return
    slice_seconds = max(series.stop - series.start, 1.0) / SLICES
    for y, row in enumerate(rows):
        shown = sorted({round(mark.t / slice_seconds) * slice_seconds for mark in series.marks[row]})
        colour = MARK_COLOURS.get(row, FAULT_COLOUR)
        axes.scatter(shown, [y] * len(shown), marker="|", s=190, color=colour, linewidths=2.2)
    axes.set_yticks(range(len(rows)), [f"{row} ({len(series.marks[row])})" for row in rows])
    axes.set_ylim(len(rows) - 0.4, -0.6)
    axes.tick_params(axis="y", length=0)


def _empty(axes, text: str) -> None:
    axes.text(0.5, 0.5, text, transform=axes.transAxes, ha="center", va="center",
              color="#777777", fontstyle="italic")


def _changes(times: list[float], values: list[float]) -> tuple[list[float], list[float]]:
    """Only the points where a step series changes (and its last point)."""
    kept_t: list[float] = []
    kept_v: list[float] = []
    for i, (t, v) in enumerate(zip(times, values)):
        if i == 0 or v != kept_v[-1] or i == len(times) - 1:
            kept_t.append(t)
            kept_v.append(v)
    return kept_t, kept_v


def _envelope(
    times: list[float], values: list[int], start: float, stop: float
) -> tuple[list[float], list[int], list[int]]:
    """A step series as the least and most it held in each of SLICES slices of time."""
    width = max(stop - start, 1e-9) / SLICES
    lows: list[int | None] = [None] * SLICES
    highs: list[int | None] = [None] * SLICES
    held = values[0]
    position = 0
    for i in range(SLICES):
        end = start + (i + 1) * width
        low = high = held  # what it held when the slice began
        while position < len(times) and times[position] < end:
            held = values[position]
            low, high = min(low, held), max(high, held)
            position += 1
        lows[i], highs[i] = low, high
    edges = [start + i * width for i in range(SLICES)] + [stop]
    return edges, [*lows, lows[-1]], [*highs, highs[-1]]  # type: ignore[list-item]


# Tick spacings that read as round times: seconds, then minutes, then hours.
TICKS = (0.1, 0.2, 0.5, 1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 14400,
         21600, 43200, 86400)


def _time_locator(span: float):
    from matplotlib.ticker import MultipleLocator

    return MultipleLocator(next((tick for tick in TICKS if span / tick <= 12), TICKS[-1]))


def _time_formatter(span: float):
    from matplotlib.ticker import FuncFormatter

    def seconds(value: float, _position: object) -> str:
        if span < 120:
            return f"{value:g}"
        whole = int(round(value))
        sign, whole = ("-", -whole) if whole < 0 else ("", whole)
        hours, rest = divmod(whole, 3600)
        return f"{sign}{hours}:{rest // 60:02d}:{rest % 60:02d}"

    return FuncFormatter(seconds)

