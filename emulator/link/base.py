"""What a link is to the printer server: PtyLink and MemoryLink both are one."""

from dataclasses import dataclass
from typing import Protocol


# What the printer may keep unsent while nobody reads the port; past it the oldest bytes go,
# as they would on a wire nobody listens to.
MAX_PENDING_OUTPUT = 1 << 20


def queue_output(pending: bytearray, data: bytes) -> None:
    """Add `data` to a link's unsent output, keeping at most MAX_PENDING_OUTPUT bytes."""
    pending += data
    overflow = len(pending) - MAX_PENDING_OUTPUT
    if overflow > 0:
        del pending[:overflow]


@dataclass(frozen=True)
class HostOpened:
    """A host (re)opened the port."""


class Link(Protocol):
    """The printer's end of the line to its host, as PrinterServer uses it."""

    async def receive(self) -> bytes | HostOpened:
        """The next chunk of bytes from the host, or a HostOpened notice."""

    def send(self, data: bytes) -> None:
        """Queue bytes for the host; never blocks the printer."""

    async def run_writer(self) -> None:
        """Carry what was sent to the host, for as long as the printer runs."""

    async def drain(self) -> None:
        """Wait until what was sent so far has left (or was given up)."""

    def discard_output(self) -> None:
        """Forget unsent output: the host that would have read it is gone."""

    def host_baud(self) -> int | None:
        """The baud rate the host set on the port, if it can be known."""

    def hang_up(self) -> None:
        """The line goes dead: the host's end fails until the line comes back."""

    def reconnect(self) -> None:
        """The line comes back after a hang_up()."""
