"""How the line behaves in time: baud-rate pacing, latency with jitter, and stalls.

Each direction is a Pipe that delivers bytes in order (a serial line never reorders), no
sooner than latency plus jitter after they were sent, and no faster than the baud rate
allows: each byte costs 10 bit times (start, 8 data, stop), 9 on a 7-bit line. With nothing configured and
no stall pending, bytes pass straight through.
"""

import functools
import math
import random
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import trio


@dataclass(frozen=True)
class LinkConditions:
    baud: int | None = None  # None: no pacing
    latency: float = 0.0  # seconds, fixed part
    jitter: float = 0.0  # seconds, up to this much more, uniformly
    data_bits: int = 8  # per character; with a start and a stop bit around them

    @property
    def active(self) -> bool:
        return bool(self.baud) or self.latency > 0 or self.jitter > 0


class Pipe:
    def __init__(self, deliver: Callable[[bytes], None], conditions: LinkConditions, seed: int = 0) -> None:
        self._deliver = deliver
        self.conditions = conditions
        self._seed = seed
        # (start, byte time, bytes): the first byte has come at start + byte time, the last at
        # start + len * byte time.
        self._queue: deque[tuple[float, float, bytes]] = deque()
        self._free_at = -math.inf  # when the last queued byte will have arrived
        self._changed = trio.Event()
        self.baud: int | None = conditions.baud
        self._delays = conditions.latency > 0 or conditions.jitter > 0

    @functools.cached_property
    def _random(self) -> random.Random:
        """Made when it first draws (jitter or latency): the same draws as one made at once,
        without a Mersenne Twister's 2.5 KB in each of a farm's thousands of pipes."""
        return random.Random(self._seed)

    @property
    def passes_through(self) -> bool:
        """Bytes put now would be delivered at once: nothing on the way, no pacing, no delay.
        (Nothing queued also means the last delivery is done: a stall waits in the queue.)"""
        # self.baud, not the conditions': it may be the rate the host set (baud_from_host).
        return not self._queue and not self.baud and not self._delays

    def put(self, data: bytes, pause: float = 0.0) -> None:
        now = trio.current_time()
        if not pause and self.passes_through and self._free_at <= now:
            self._deliver(data)
            return
        start = max(now + self.conditions.latency + self._random.uniform(0, self.conditions.jitter),
                    self._free_at)
        if pause:
            start = max(start, now + pause)
        byte_time = (self.conditions.data_bits + 2) / self.baud if self.baud else 0.0
        self._free_at = start + len(data) * byte_time
        self._queue.append((start, byte_time, data))
        self._changed.set()

    def clear(self) -> None:
        """The connection is gone: bytes still on the wire are lost."""
        self._queue.clear()
        self._free_at = -math.inf

    async def run(self) -> None:
        while True:
            changed = self._changed = trio.Event()
            if not self._queue:
                await changed.wait()
                continue
            start, byte_time, data = self._queue[0]
            come = _bytes_come(start, byte_time, len(data), trio.current_time())
            if come == len(data):
                self._queue.popleft()
                self._deliver(data)
            elif come:
                # A UART hands the firmware each byte as it comes: what has come goes ahead of
                # the rest. (Two packets a host writes at once: the first is read a packet's
                # time before the second has come.)
                self._queue[0] = (start + come * byte_time, byte_time, data[come:])
                self._deliver(data[:come])
            else:
                with trio.move_on_at(start + byte_time):  # when the next byte has come
                    await changed.wait()


def _bytes_come(start: float, byte_time: float, size: int, now: float) -> int:
    """How many of `size` bytes sent from `start`, one per byte_time, have come by `now`: byte
    k has come once start + k * byte_time <= now (the very sum the wait for it uses)."""
    if byte_time == 0:
        return size if start <= now else 0
    come = min(size, max(0, int((now - start) / byte_time)))
    while come < size and start + (come + 1) * byte_time <= now:
        come += 1
    while come > 0 and start + come * byte_time > now:
        come -= 1
    return come
