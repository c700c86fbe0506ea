"""The trio shell every host client shares: one reader task, one sender task behind a send lock,
and a sans-IO core. Each protocol brings its core (fake_marlin.host.cores: a HostCore, which
reads the printer's bytes itself) in a thin client (fake_marlin.host.clients).

`Client` is what `open_printer` and `connect` give: `send` a command, `print_commands` or
`print_file` a job, read `stats`. `StreamingClient` adds `submit` and `wait_idle` for the protocols
that stream commands through a `CommandQueue` (Ultimaker, Marlin, Repetier); CommStack stores a
job on the card and prints it instead.
"""

import math
from abc import ABC, abstractmethod
from collections.abc import Awaitable, Callable, Iterable
from dataclasses import asdict, dataclass
from typing import ClassVar, Protocol

import trio

from fake_marlin.host.cores.base import HostCore, PrinterLine, Stats, StreamingCore
from fake_marlin.host.cores.queue import Ticket
from fake_marlin.host.errors import HostError
from fake_marlin.wire.ultimaker_variants import Variants
from fake_marlin.host.gcode_file import checked_job

LineCallback = Callable[[PrinterLine], None]
ProgressCallback = Callable[[int], None]


class ByteStream(Protocol):
    async def receive_some(self, max_bytes: int | None = ...) -> bytes: ...
    async def send_all(self, data: bytes) -> None: ...


@dataclass(frozen=True)
class PrintSummary:
    """What printing a job took."""

    commands: int
    packets_sent: int
    resends: int
    timeouts: int
    rejects: int
    corrupt_frames: int
    unconfirmed: int
    elapsed: float

    def as_dict(self) -> dict[str, int | float]:
        return asdict(self)


@dataclass(frozen=True)
class ClientOptions:
    window: int = 3  # Ultimaker packets in flight; Marlin always has one line in flight
    timeout: float = 2.0  # seconds of silence before an unanswered packet is sent again
    long_timeout: float = 300.0  # the same while the printer is known to be busy
    received_timeout: float = 10.0
    max_transmissions: int = 8
    settle: float = 0.5  # how long to wait for the printer's boot message before sending
    # The protocol lab's variants (Ultimaker only): "ack,crc8", names, or a Variants.
    variants: "str | tuple[str, ...] | Variants" = ()


_COUNTED = ("packets_sent", "resends", "timeouts", "rejects", "unconfirmed")  # summed per job


@dataclass(frozen=True)
class _Snapshot:
    stats: dict[str, int]
    corrupt_frames: int
    time: float


class Client(ABC):
    """A printer on a byte stream, through a protocol's sans-IO core (made by `_open`)."""

    protocol: ClassVar[str]
    _core: HostCore
    # Whether the sender waits (up to options.settle) for the printer's greeting first.
    waits_for_greeting: ClassVar[bool] = True

    @staticmethod
    @abstractmethod
    def check_command(command: str) -> object:
        """Raise CommandError if `command` cannot be sent in this protocol."""

    def __init__(
        self,
        stream: ByteStream,
        options: ClientOptions = ClientOptions(),
        on_line: LineCallback | None = None,
    ) -> None:
        self._stream = stream
        self.options = options
        self._on_line: LineCallback = on_line or (lambda line: None)
        self._send_lock = trio.Lock()
        self._changed = trio.Event()  # something the library API waits on may have happened
        self._sender_wake = trio.Event()
        self._printer_seen = trio.Event()
        self.room: int | None = None  # the printer's planner room, where it says
        self.corrupt_frames = 0
        self.completed = 0
        self._on_complete: ProgressCallback = lambda count: None  # told of each completion
        self.failure: HostError | None = None
        self._open(options)

    @abstractmethod
    def _open(self, options: ClientOptions) -> None:
        """Make the protocol's core, `self._core` (once, as the client is made)."""

    @property
    def stats(self) -> Stats:
        return self._core.stats

    def _feed(self, data: bytes) -> None:
        """The printer's bytes: the core handles them, and says what to show the caller."""
        core = self._core
        core.receive_data(data, trio.current_time())
        try:
            while (line := core.next_event()) is not None:
                self._on_line(line)
        finally:
            self.room = core.room
            self.corrupt_frames = core.corrupt_frames
            if core.greeted:
                self._printer_seen.set()
            self._heard()

    def _heard(self) -> None:
        """The core has handled what came: deadlines moved, or there is something to send."""
        self._sender_wake.set()

    def _poll(self, now: float) -> list[bytes]:
        return self._core.poll(now)

    # -- the background tasks -----------------------------------------------------------
    async def run(self, cancel_scope: trio.CancelScope) -> None:
        async with trio.open_nursery() as nursery:
            nursery.start_soon(self._guard, self._read_loop, cancel_scope)
            nursery.start_soon(self._guard, self._send_loop, cancel_scope)

    async def _guard(
        self, loop: Callable[[], Awaitable[None]], cancel_scope: trio.CancelScope
    ) -> None:
        try:
            await loop()
        except HostError as error:
            self.failure = self.failure or error
            cancel_scope.cancel()

    async def _read_loop(self) -> None:
        while True:
            self._feed(await self._stream.receive_some(4096))

    def _notify(self) -> None:
        self._changed.set()
        self._changed = trio.Event()

    async def _send_loop(self) -> None:
        if self.waits_for_greeting:
            with trio.move_on_after(self.options.settle):
                await self._printer_seen.wait()
        while True:
            wake = self._sender_wake = trio.Event()
            async with self._send_lock:
                for data in self._poll(trio.current_time()):
                    await self._stream.send_all(data)
            # poll() may have moved commands out of the backlog, or completed some.
            self._notify()
            deadline = self._core.next_deadline()
            with trio.move_on_at(math.inf if deadline is None else deadline):
                await wake.wait()

    async def _wait_until(self, condition: Callable[[], bool]) -> None:
        while not condition():
            await self._changed.wait()

    def _snapshot(self) -> _Snapshot:
        return _Snapshot(asdict(self.stats), self.corrupt_frames, trio.current_time())

    def _summary(self, since: _Snapshot, commands: int) -> PrintSummary:
        """What printing `commands` cost since the snapshot."""
        now = asdict(self.stats)
        return PrintSummary(
            commands=commands,
            **{key: now[key] - since.stats[key] for key in _COUNTED},
            corrupt_frames=self.corrupt_frames - since.corrupt_frames,
            elapsed=trio.current_time() - since.time,
        )

    # -- the library API ----------------------------------------------------------------
    @abstractmethod
    async def send(self, command: str) -> tuple[str, ...]:
        """Send one command; returns its response data once the printer has executed it."""

    @abstractmethod
    async def print_commands(
        self, commands: Iterable[str], progress: ProgressCallback | None = None
    ) -> PrintSummary:
        """Print these commands; returns once the printer has them all, each exactly once."""

    async def print_file(self, path: str, progress: ProgressCallback | None = None) -> PrintSummary:
        """Print a G-code file (comments and blank lines stripped, every line checked first)."""
        return await self.print_commands(
            [c.text for c in checked_job(path, self.check_command)], progress
        )


class StreamingClient(Client):
    """A client whose core streams commands: they are submitted, streamed and completed."""

    _core: StreamingCore
    # How many completed commands may not have run yet: where an acknowledgement means
    # "queued", it runs ahead of execution by what the printer holds (Repetier).
    acknowledged_ahead: ClassVar[int] = 0

    @property
    def known_run(self) -> int:
        """Commands completed that the printer is sure to have run (or begun): where a host
        that lost the port resumes. What comes after may run twice; nothing is lost."""
        return max(0, self.completed - self.acknowledged_ahead)

    def _heard(self) -> None:
        self._completed(self._core.take_completed())
        super()._heard()

    def _poll(self, now: float) -> list[bytes]:
        data = self._core.poll(now)
        self._completed(self._core.take_completed())
        return data

    def _completed(self, tickets: list[Ticket]) -> None:
        if tickets:
            self.completed += len(tickets)
            self._on_complete(len(tickets))
            self._notify()
            self._sender_wake.set()

    async def submit(self, command: str) -> Ticket:
        """Queue a command, waiting while the backlog is a window long (flow control)."""
        self.check_command(command)
        await self._wait_until(lambda: self._core.backlog < self._core.window)
        ticket = self._core.submit(command)
        self._sender_wake.set()
        return ticket

    async def send(self, command: str) -> tuple[str, ...]:
        ticket = await self.submit(command)
        await self._wait_until(lambda: ticket.done)
        return ticket.response

    async def wait_idle(self) -> None:
        """Until every command submitted has completed."""
        await self._wait_until(lambda: self._core.idle)

    async def print_commands(
        self, commands: Iterable[str], progress: ProgressCallback | None = None
    ) -> PrintSummary:
        since, completed_before = self._snapshot(), self.completed
        if progress is not None:
            self._on_complete = lambda count: progress(self.completed - completed_before)
        try:
            for command in commands:
                await self.submit(command)
            await self.wait_idle()
        finally:
            self._on_complete = lambda count: None
        return self._summary(since, self.completed - completed_before)


def sole_exception(error: BaseException) -> BaseException:
    """The one exception inside (nested) single-member groups, or `error` itself."""
    while isinstance(error, BaseExceptionGroup) and len(error.exceptions) == 1:
        error = error.exceptions[0]
    return error
