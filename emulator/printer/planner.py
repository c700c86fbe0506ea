"""A 16-block motion planner in simulated time.

Blocks run back to back; each takes the time of a trapezoidal speed profile. The planner never
reads a clock: every question is asked at a time `now` that the caller supplies.
"""

import math
from collections import deque
from typing import NamedTuple

BLOCK_BUFFER_SIZE = 16
MAX_MOVES = BLOCK_BUFFER_SIZE - 1  # a ring buffer keeps one slot free
HOLD_SPAN = 1e9  # s: a feedhold moves the held blocks this far on, until it is released


class Block(NamedTuple):  # a tuple: a planner makes one per move (a frozen dataclass costs 2.5x)
    start: float
    end: float
    origin: tuple[float, ...]
    target: tuple[float, ...]


_new_block = tuple.__new__


def move_time(distance: float, speed: float, acceleration: float, junction_speed: float) -> float:
    """Seconds for `distance` mm at up to `speed` mm/s, entering and leaving at junction_speed."""
    if distance <= 0 or speed <= 0:
        return 0.0
    entry = junction_speed if junction_speed < speed else speed  # min(), without the call
    ramp = (speed * speed - entry * entry) / (2 * acceleration)
    if 2 * ramp <= distance:
        return 2 * (speed - entry) / acceleration + (distance - 2 * ramp) / speed
    peak = math.sqrt(entry * entry + acceleration * distance)
    return 2 * (peak - entry) / acceleration


class Planner:
    def __init__(self, max_moves: int = MAX_MOVES) -> None:
        self._blocks: deque[Block] = deque()
        self.max_moves = max_moves  # Marlin's 16-block ring holds 15; g2core's pool 48

    def _retire(self, now: float) -> None:
        while self._blocks and self._blocks[0].end <= now:
            self._blocks.popleft()

    def moves(self, now: float) -> int:
        self._retire(now)
        return len(self._blocks)

    def held(self) -> int:
        """Blocks held, finished or not: an upper bound of moves(now) at any time."""
        return len(self._blocks)

    def room(self, now: float) -> int:
        return self.max_moves - self.moves(now)

    def next_change(self, now: float) -> float | None:
        """When the oldest planned move finishes (and room grows), or None if idle."""
        self._retire(now)
        return self._blocks[0].end if self._blocks else None

    def drained_at(self, now: float) -> float:
        """When every planned move will have finished."""
        self._retire(now)
        return max(now, self._blocks[-1].end) if self._blocks else now

    def add(self, now: float, duration: float, origin: tuple[float, ...], target: tuple[float, ...]) -> Block:
        blocks = self._blocks
        self._retire(now)
        if len(blocks) >= self.max_moves:
            raise RuntimeError("planner is full")  # the caller must wait for next_change()
        start = max(now, blocks[-1].end) if blocks else now
        # tuple.__new__ rather than Block(): the NamedTuple's own __new__ is a Python call.
        block = _new_block(Block, (start, start + duration, origin, target))
        blocks.append(block)
        return block

    def add_all(self, moves: list[tuple[float, float, tuple[float, ...], tuple[float, ...]]]
                ) -> None:
        """add() for each (now, duration, origin, target), in order of time, in one call: a
        batch of plain moves that the planner has room for, all together, at the first one's
        time. Retiring at the last one's time only leaves what retiring at each would: blocks
        end in order, and the last ends after its own time."""
        if not moves:
            return
        blocks = self._blocks
        self._retire(moves[0][0])
        if len(blocks) + len(moves) > self.max_moves:
            raise RuntimeError("planner is full")  # the caller admitted more than it has room for
        end = blocks[-1].end if blocks else -math.inf
        for now, duration, origin, target in moves:
            start = now if now > end else end
            end = start + duration
            blocks.append(_new_block(Block, (start, end, origin, target)))
        self._retire(moves[-1][0])

    def stepper_position(self, now: float, planned: tuple[float, ...]) -> tuple[float, ...]:
        """Where the steppers are now: along the move in progress, or `planned` when idle."""
        self._retire(now)
        if not self._blocks:
            return planned
        block = self._blocks[0]
        if now <= block.start:
            return block.origin
        fraction = (now - block.start) / (block.end - block.start)
        return tuple(a + (b - a) * fraction for a, b in zip(block.origin, block.target))

    def stall(self, now: float, seconds: float) -> None:
        """The steppers stop for `seconds` (a driver fault): every planned move runs later."""
        self._retire(now)
        self._blocks = deque(
            Block(max(block.start, now) + seconds, block.end + seconds, block.origin, block.target)
            for block in self._blocks
        )

    def hold(self, now: float) -> None:
        """A feedhold: the steppers stop where they are now, until release(). (The move in
        progress is cut here, its rest runs after the hold.)"""
        self._retire(now)
        blocks = self._blocks
        if blocks and blocks[0].start < now:
            first = blocks[0]
            here = self.stepper_position(now, first.target)
            blocks[0] = Block(now, first.end, here, first.target)
        self.stall(now, HOLD_SPAN)

    def release(self, now: float, held_since: float) -> None:
        """The end of a hold begun at `held_since`: the moves held run on from now."""
        self.stall(now, -(HOLD_SPAN - (now - held_since)))

    def clear(self) -> None:
        self._blocks.clear()
