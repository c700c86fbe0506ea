"""The bench's G-code jobs, and how long the printer model takes to print them.

Every line of a job is distinct (the extruder position only grows), so a host driver can count
the job lines it sent as a set, and a resend is never counted twice.
"""

import math

from fake_marlin.emulator.printer.model import PrinterConfig
from fake_marlin.emulator.printer.planner import move_time

SHORT_SEGMENT = 0.4  # mm: the throughput worst case, a curve cut as finely as slicers cut it
SHORT_FEED = 6000  # mm/min
ROW = 100  # short segments per zig-zag row (40 mm)
LONG_MOVE = 200.0  # mm, for the simulated-hour job: long, realistic straight moves
LONG_FEED = 3000  # mm/min


def short_moves(count: int) -> list[str]:
    """`count` moves of 0.4 mm, zig-zagging in rows of 40 mm, extruding as they go."""
    job = []
    for index in range(count):
        row, column = divmod(index, ROW)
        step = column + 1 if row % 2 == 0 else ROW - column - 1
        x = 10 + SHORT_SEGMENT * step
        y = 10 + SHORT_SEGMENT * row
        e = 0.02 * (index + 1)
        job.append(f"G1 X{x:.1f} Y{y:.1f} E{e:.3f} F{SHORT_FEED}")
    return job


def long_moves(count: int) -> list[str]:
    """`count` moves of 200 mm back and forth at 50 mm/s, then M400: the job has run when the
    host is done (Marlin acknowledges a move once it is planned, M400 once the planner is
    empty)."""
    job = []
    for index in range(count):
        x = 10 + LONG_MOVE * ((index + 1) % 2)
        y = 10 + 0.2 * (index // 2)
        job.append(f"G1 X{x:.1f} Y{y:.1f} E{0.5 * (index + 1):.1f} F{LONG_FEED}")
    return [*job, "M400"]


def long_moves_for(seconds: float) -> int:
    """How many long moves take about this much simulated time."""
    sample = 100
    return max(1, round(seconds * sample / simulated_seconds(long_moves(sample))))


def simulated_seconds(job: list[str]) -> float:
    """The motion time of a job of straight G1 moves from the origin, as the printer model
    plans it with its default settings (fake_marlin.emulator.printer.motion): each move enters
    and leaves at the junction speed, so the moves simply add up. The job is the bench's own,
    so its lines are read with a split, not a G-code parser."""
    config = PrinterConfig()
    position = [0.0, 0.0, 0.0, 0.0]
    feed = config.default_feedrate
    total = 0.0
    for line in job:
        words = line.split()
        if not words or words[0] != "G1":
            continue
        target = list(position)
        for word in words[1:]:
            axis, value = word[0], float(word[1:])
            if axis == "F":
                feed = value
            elif axis in "XYZE":
                target["XYZE".index(axis)] = value
        deltas = [abs(b - a) for a, b in zip(position, target)]
        distance = math.hypot(*deltas[:3]) or deltas[3]
        speed = feed / 60
        for delta, limit in zip(deltas, config.max_feedrate):
            if delta > 0:
                speed = min(speed, limit * distance / delta)
        total += move_time(distance, speed, config.acceleration, config.junction_speed)
        position = target
    return total
