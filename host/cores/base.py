"""What every host core is: one protocol's host side as a sans-IO state machine.

A core takes the printer's bytes (`receive_data`, with the time they came), says what the
printer printed for the caller (`next_event`, drained after each `receive_data`: the bytes are
handled there, one event at a time), gives the bytes to write (`poll`, with the time now) and
when it wants to be polled unasked (`next_deadline`). No I/O, no clock, no trio: the shell
(fake_marlin.host.shell) moves the bytes and the time. A core that streams commands is also a
`StreamingCore`: the caller submits commands and takes back the tickets completed.

One core per protocol: UltimakerCore, MarlinCore, RepetierCore, G2coreCore (streaming) and
CommStackCore.
"""

from typing import Any, ClassVar, Protocol

from fake_marlin.host.codecs import g2core, marlin, ultimaker
from fake_marlin.host.cores.queue import Ticket

# A line the printer printed that is not a command's response data (Repetier's are Marlin's).
PrinterLine = ultimaker.Line | marlin.Line | g2core.Line


class Stats(Protocol):
    """What every core counts: a dataclass with these fields, and perhaps more."""

    __dataclass_fields__: ClassVar[dict[str, Any]]
    packets_sent: int
    resends: int
    timeouts: int
    rejects: int
    unconfirmed: int


class HostCore(Protocol):
    @property
    def stats(self) -> Stats: ...

    @property
    def greeted(self) -> bool:
        """The printer has said it is there (what it says once it has booted)."""
        ...

    @property
    def room(self) -> int | None:
        """The planner room the printer last stated, where its protocol says it."""
        ...

    @property
    def corrupt_frames(self) -> int:
        """Frames or lines that came damaged, and were dropped."""
        ...

    def receive_data(self, data: bytes, now: float) -> None:
        """Bytes from the printer, come at `now`; handled as next_event() is drained."""

    def next_event(self) -> PrinterLine | None:
        """The next line for the caller (None: the bytes received are all handled). Raises
        a RemoteError (PrinterHalted, PrinterReset...) where the printer's words end the
        session."""

    def poll(self, now: float) -> list[bytes]:
        """Handle the timers due by `now`; return what to write now, in order."""

    def next_deadline(self) -> float | None:
        """When to poll again if nothing comes (None: only once something does)."""


class StreamingCore(HostCore, Protocol):
    """A core whose caller streams commands through it (a CommandQueue with a window)."""

    @property
    def backlog(self) -> int: ...

    @property
    def window(self) -> int:
        """Commands the caller may keep in the backlog: flow control for submit()."""
        ...

    @property
    def idle(self) -> bool:
        """Everything submitted has completed."""
        ...

    def submit(self, text: str) -> Ticket: ...

    def take_completed(self) -> list[Ticket]:
        """Tickets completed since the last call, oldest first, each handed over once."""
