"""The trio shell every host client shares: one reader task, one sender task behind a send lock,
and a sans-IO core. Each protocol brings its parser and its core (fake_marlin.host.cores) in a thin
client (fake_marlin.host.clients)."""

import math
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from typing import Protocol

import trio

from fake_marlin.host.codecs.ultimaker import check_command
from fake_marlin.host.cores.queue import Ticket
from fake_marlin.host.errors import HostError
from fake_marlin.host.gcode_file import checked_job

class ByteStream(Protocol):
    async def receive_some(self, max_bytes: int = ...) -> bytes: ...
    async def send_all(self, data: bytes) -> None: ...


@dataclass(frozen=True)
class PrintSummary:
    commands: int
    packets_sent: int
    resends: int
    timeouts: int
    rejects: int
    corrupt_frames: int
    unconfirmed: int
    elapsed: float

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class ClientOptions:
    window: int = 3  # Ultimaker packets in flight; Marlin always has one line in flight
    timeout: float = 2.0  # seconds of silence before an unanswered packet is sent again
    long_timeout: float = 300.0  # the same while the printer is known to be busy
    received_timeout: float = 10.0
    max_transmissions: int = 8
    settle: float = 0.5  # how long to wait for the printer's boot message before sending


class _Client:
    """The shell. A subclass sets `_core` (submit, backlog, window, idle, next_deadline, stats)
    and implements `_feed` (bytes from the printer) and `_poll` (bytes to write now)."""

    check_command = staticmethod(check_command)

    def __init__(self, stream: ByteStream, options: ClientOptions, on_line: Callable | None) -> None:
        self._stream = stream
        self.options = options
        self._on_line = on_line or (lambda line: None)
        self._send_lock = trio.Lock()
        self._changed = trio.Event()  # a command completed or left the backlog
        self._sender_wake = trio.Event()
        self._printer_seen = trio.Event()
        self._on_complete: Callable[[int], None] = lambda count: None
        self.room: int | None = None
        self.corrupt_frames = 0
        self.completed = 0
        self.failure: HostError | None = None

    @property
    def stats(self):
        return self._core.stats

    # -- the background tasks -----------------------------------------------------------
    async def run(self, cancel_scope: trio.CancelScope) -> None:
        async with trio.open_nursery() as nursery:
            nursery.start_soon(self._guard, self._read_loop, cancel_scope)
            nursery.start_soon(self._guard, self._send_loop, cancel_scope)

    async def _guard(self, loop, cancel_scope: trio.CancelScope) -> None:
        try:
            await loop()
        except HostError as error:
            self.failure = self.failure or error
            cancel_scope.cancel()

    async def _read_loop(self) -> None:
        while True:
            self._feed(await self._stream.receive_some(4096))

    def _feed(self, data: bytes) -> None:
        raise NotImplementedError

    def _poll(self, now: float) -> list[bytes]:
        raise NotImplementedError

    def _completed(self, tickets: list[Ticket]) -> None:
        if tickets:
            self.completed += len(tickets)
            self._on_complete(len(tickets))
            self._notify()
            self._sender_wake.set()

    def _notify(self) -> None:
        self._changed.set()
        self._changed = trio.Event()

    async def _send_loop(self) -> None:
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

    # -- the library API ----------------------------------------------------------------
    async def submit(self, command: str) -> Ticket:
        """Queue a command, waiting while the backlog is a window long (flow control)."""
        self.check_command(command)
        await self._wait_until(lambda: self._core.backlog < self._core.window)
        ticket = self._core.submit(command)
        self._sender_wake.set()
        return ticket

    async def send(self, command: str) -> tuple[str, ...]:
        """Send one command; returns its response data once the printer has executed it."""
        ticket = await self.submit(command)
        await self._wait_until(lambda: ticket.done)
        return ticket.response

    async def wait_idle(self) -> None:
        await self._wait_until(lambda: self._core.idle)

    async def print_commands(
        self, commands: Iterable[str], progress: Callable[[int], None] | None = None
    ) -> PrintSummary:
        """Stream commands; returns once every one has been acknowledged."""
        start = trio.current_time()
        before = asdict(self.stats)
        corrupt_before, completed_before = self.corrupt_frames, self.completed
        if progress is not None:
            self._on_complete = lambda count: progress(self.completed - completed_before)
        try:
            for command in commands:
                await self.submit(command)
            await self.wait_idle()
        finally:
            self._on_complete = lambda count: None
        after = asdict(self.stats)
        return PrintSummary(
            commands=self.completed - completed_before,
            packets_sent=after["packets_sent"] - before["packets_sent"],
            resends=after["resends"] - before["resends"],
            timeouts=after["timeouts"] - before["timeouts"],
            rejects=after["rejects"] - before["rejects"],
            corrupt_frames=self.corrupt_frames - corrupt_before,
            unconfirmed=after["unconfirmed"] - before["unconfirmed"],
            elapsed=trio.current_time() - start,
        )

    async def print_file(self, path: str, progress: Callable[[int], None] | None = None) -> PrintSummary:
        return await self.print_commands([c.text for c in checked_job(path, self.check_command)], progress)


def sole_exception(error: BaseException) -> BaseException:
    """The one exception inside (nested) single-member groups, or `error` itself."""
    while isinstance(error, BaseExceptionGroup) and len(error.exceptions) == 1:
        error = error.exceptions[0]
    return error
