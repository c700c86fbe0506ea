"""What a session is to the printer server that makes one for each boot."""

from collections.abc import Iterable
from typing import Protocol

import trio


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

    def announce(self, lines: Iterable[str]) -> None:
        """Lines the firmware prints on its own (a fault, a kill, the control channel's)."""

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
