"""What a session is to the printer server that makes one for each boot, and the clock it
gives a machine with timers."""

import math
from collections.abc import Callable, Iterable
from typing import Any, Protocol

import trio

from fake_marlin.emulator.printer.statements import Statement
from fake_marlin.emulator.protocols.base import TimedMachine


class Session(Protocol):
    """One boot of the printer speaking one protocol (or its bootloader) to the host.

    PrinterServer boots it, feeds it what the host sends, runs it until the next reset, and
    hands it what the printer says on its own and the faults that block its queue.
    """

    def boot(self) -> None:
        """What the printer says as it starts, before it reads anything."""

    def feed(self, data: bytes) -> None:
        """Bytes from the host, as they arrive."""

    async def run(self) -> None:
        """What the session does in its own time, until the reset that ends it cancels it."""

    def announce(self, statements: Iterable[Statement]) -> None:
        """What the firmware says on its own (a fault, a kill, the control channel's)."""

    def block_queue(self, seconds: float, nursery: trio.Nursery) -> None:
        """The command queue takes nothing for `seconds` (a queue-full fault)."""


class HandsOver(Protocol):
    """A session that hands the connection to another once the host's bytes say which (the
    protocol detector; the bootloader, to the firmware)."""

    def boot(self) -> None: ...

    def feed(self, data: bytes) -> None: ...

    async def run(self) -> None: ...

    @property
    def active(self) -> Session | None:
        """The session that speaks for the printer now; None while none does yet."""


class MachineClock:
    """Tells a TimedMachine the time: once the session has fed it bytes and read the events
    (`tell`: what it read happened now), and whenever its next deadline comes (`run`). After
    each, `after` handles what a timer may have made (the machine's events and words);
    `running` says whether the firmware's timers run at all now (not while it is halted)."""

    def __init__(
        self,
        machine: TimedMachine[Any, Any],
        after: Callable[[], object],
        running: Callable[[], bool] = lambda: True,
    ) -> None:
        self.machine = machine
        self._after = after
        self._running = running
        self._changed = trio.Event()

    def tell(self) -> None:
        """It is now: what the machine read happened now, and its deadlines may have moved."""
        self.machine.time_passed(trio.current_time())
        self._after()
        self._changed.set()

    def changed(self) -> None:
        """The session's state changed (what `running` says, say): look at the deadline again."""
        self._changed.set()

    async def run(self) -> None:
        while True:
            changed = self._changed = trio.Event()
            deadline = self.machine.next_deadline() if self._running() else None
            with trio.move_on_at(math.inf if deadline is None else deadline):
                await changed.wait()
                continue
            self.tell()
