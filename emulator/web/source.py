"""Where the live view gets its data: a FarmSource. LocalFarm reads the printers of this
process; a farm spread over processes reads each process's through the control channel, whose
op calls `watched_detail` there.
"""

from collections.abc import Sequence
from typing import Any, Protocol

import trio

from fake_marlin.emulator.server.lifecycle import PrinterServer
from fake_marlin.emulator.web import snapshot

# Real seconds a printer's wire stays recorded after its page last asked for it: a reload, or
# a page that turns to the next printer and back, finds what was recorded; a page closed for
# longer leaves the printer as if it had never been watched.
WATCH_LEASE = 15.0
SAMPLE_EVERY = 0.5  # real seconds: two pages of one printer sample it once, not twice
ROWS_AT_ONCE = 250  # rows made between checkpoints: 10,000 printers do not stall the others


class FarmSource(Protocol):
    """What the live view reads: every printer's row, and one printer's detail."""

    async def rows(self) -> list[dict[str, Any]]:
        """One row per printer (snapshot.row), in printer number order."""
        ...

    async def detail(self, number: int) -> dict[str, Any] | None:
        """Printer `number`'s page (snapshot.detail), recording its wire for a while from now
        on; None if the farm has no such printer."""
        ...


def clock_speed() -> float:
    """How many of trio's seconds pass in a real second (`--speed`): the view paces itself in
    real time whatever the printers' clock runs at."""
    speed = getattr(trio.lowlevel.current_clock(), "speed", None)
    return float(speed) if isinstance(speed, (int, float)) and speed > 0 else 1.0


def watched_detail(server: PrinterServer, number: int, path: str,
                   lease: float = WATCH_LEASE) -> dict[str, Any]:
    """A printer's detail for a page that watches it: its wire is recorded `lease` real seconds
    more from now, a sample is taken for its plots (at most every SAMPLE_EVERY real seconds),
    and then the snapshot is read. In the process that runs `server`."""
    speed = clock_speed()
    now = trio.current_time()
    watch = server.watch(lease * speed)
    if not watch.samples or now - watch.samples[-1]["t"] >= SAMPLE_EVERY * speed:
        watch.samples.append(snapshot.sample(server, watch, now))
    return snapshot.detail(server, number, path)


class LocalFarm:
    """The printers of this process, as `servers`, their farm numbers and paths (or URLs)."""

    def __init__(self, servers: Sequence[PrinterServer], numbers: Sequence[int],
                 paths: Sequence[str]) -> None:
        if not len(servers) == len(numbers) == len(paths):
            raise ValueError(f"{len(servers)} servers, {len(numbers)} numbers and "
                             f"{len(paths)} paths: one of each per printer")
        self.servers = list(servers)
        self.numbers = list(numbers)
        self.paths = list(paths)
        self._index = {number: index for index, number in enumerate(self.numbers)}

    async def rows(self) -> list[dict[str, Any]]:
        made: list[dict[str, Any]] = []
        for start in range(0, len(self.servers), ROWS_AT_ONCE):
            if start:
                await trio.lowlevel.checkpoint()  # the printers answer their hosts meanwhile
            stop = start + ROWS_AT_ONCE
            made += snapshot.rows(self.servers[start:stop], self.numbers[start:stop],
                                  self.paths[start:stop])
        return made

    async def detail(self, number: int) -> dict[str, Any] | None:
        index = self._index.get(number)
        if index is None:
            return None
        return watched_detail(self.servers[index], number, self.paths[index])


def _check(source: LocalFarm) -> FarmSource:  # LocalFarm is held to the protocol by mypy
    return source
