"""The trio host client: one reader task, one sender task behind a send lock, and the window."""

import math
from collections.abc import AsyncIterator, Callable, Iterable
from contextlib import asynccontextmanager
from dataclasses import asdict, dataclass
from typing import Protocol

import trio

from host.codecs.ultimaker import (
    Ack,
    CorruptFrame,
    FrameParser,
    Line,
    LineKind,
    Reject,
    RoomInfo,
    check_command,
    encode_command,
)
from host.errors import CommandError, HostError
from host.gcode_file import JobCommand, read_job
from host.serial_port import SerialPort
from host.window import GoBackNWindow, Ticket

PROTOCOLS = ("ultimaker",)
DEFAULT_BAUDRATE = 250000


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
    window: int = 3
    timeout: float = 2.0  # seconds of silence before an unanswered packet is sent again
    long_timeout: float = 300.0  # the same while the printer is known to be busy
    received_timeout: float = 10.0
    max_transmissions: int = 8
    settle: float = 0.5  # how long to wait for the printer's boot message before sending


class UltimakerClient:
    def __init__(
        self,
        stream: ByteStream,
        options: ClientOptions = ClientOptions(),
        on_line: Callable[[Line], None] | None = None,
    ) -> None:
        self._stream = stream
        self.options = options
        self._on_line = on_line or (lambda line: None)
        self._parser = FrameParser()
        self._window = GoBackNWindow(
            window=options.window,
            timeout=options.timeout,
            long_timeout=options.long_timeout,
            received_timeout=options.received_timeout,
            max_transmissions=options.max_transmissions,
        )
        self._send_lock = trio.Lock()
        self._changed = trio.Event()  # a command completed or left the backlog
        self._sender_wake = trio.Event()
        self._printer_seen = trio.Event()
        self._response: list[str] = []
        self._on_complete: Callable[[int], None] = lambda count: None
        self.room: int | None = None
        self.corrupt_frames = 0
        self.completed = 0
        self.failure: HostError | None = None

    @property
    def stats(self):
        return self._window.stats

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
            self._parser.receive_data(await self._stream.receive_some(4096))
            while (event := self._parser.next_event()) is not None:
                self._handle(event)

    def _handle(self, event) -> None:
        now = trio.current_time()
        if isinstance(event, Ack):
            done = self._window.on_ack(event.seq, event.room, tuple(self._response), now)
            self._response.clear()
            self.room = event.room
            self._completed(done)
        elif isinstance(event, Reject):
            self.room = event.room
            self._window.on_reject(event.seq, event.room, now)
            self._sender_wake.set()
        elif isinstance(event, RoomInfo):
            self.room = event.room
            self._window.heard(now, event.room)
            self._printer_seen.set()
            self._sender_wake.set()  # deadlines moved
        elif isinstance(event, CorruptFrame):
            self.corrupt_frames += 1
        else:
            self._window.heard(now)
            if event.kind is LineKind.RESPONSE:
                self._response.append(event.text)
            else:
                if event.kind is LineKind.LOG:
                    self._printer_seen.set()
                self._on_line(event)

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
                for transmit in self._window.poll(trio.current_time()):
                    await self._stream.send_all(encode_command(transmit.seq, transmit.text))
            # poll() may have moved commands out of the backlog, or completed some.
            self._notify()
            deadline = self._window.next_deadline()
            with trio.move_on_at(math.inf if deadline is None else deadline):
                await wake.wait()

    async def _wait_until(self, condition: Callable[[], bool]) -> None:
        while not condition():
            await self._changed.wait()

    # -- the library API ----------------------------------------------------------------
    async def submit(self, command: str) -> Ticket:
        """Queue a command, waiting while the backlog is a window long (flow control)."""
        check_command(command)
        await self._wait_until(lambda: self._window.backlog < self._window.window)
        ticket = self._window.submit(command)
        self._sender_wake.set()
        return ticket

    async def send(self, command: str) -> tuple[str, ...]:
        """Send one command; returns its response data once the printer has executed it."""
        ticket = await self.submit(command)
        await self._wait_until(lambda: ticket.done)
        return ticket.response

    async def wait_idle(self) -> None:
        await self._wait_until(lambda: self._window.idle)

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
        return await self.print_commands([c.text for c in load_job(path)], progress)


def load_job(path: str) -> list[JobCommand]:
    """Read a job and check every command can be sent, before any is."""
    job = read_job(path)
    for command in job:
        try:
            check_command(command.text)
        except CommandError as error:
            raise CommandError(f"{path}:{command.line_number}: {error}") from None
    return job


@asynccontextmanager
async def connect(
    stream: ByteStream,
    protocol: str = "ultimaker",
    options: ClientOptions = ClientOptions(),
    on_line: Callable[[Line], None] | None = None,
) -> AsyncIterator[UltimakerClient]:
    """A client speaking `protocol` over an open byte stream."""
    if protocol not in PROTOCOLS:
        raise CommandError(f"unknown protocol {protocol!r}; choose from {', '.join(PROTOCOLS)}")
    client = UltimakerClient(stream, options, on_line)
    try:
        async with trio.open_nursery() as nursery:
            nursery.start_soon(client.run, nursery.cancel_scope)
            try:
                yield client
            finally:
                nursery.cancel_scope.cancel()
    except BaseExceptionGroup as group:
        # The caller's own error (or Ctrl-C) comes back as itself, not wrapped in a group.
        raise sole_exception(group) from None
    if client.failure is not None:
        raise client.failure


def sole_exception(error: BaseException) -> BaseException:
    """The one exception inside (nested) single-member groups, or `error` itself."""
    while isinstance(error, BaseExceptionGroup) and len(error.exceptions) == 1:
        error = error.exceptions[0]
    return error


@asynccontextmanager
async def open_printer(
    port: str,
    protocol: str = "ultimaker",
    baudrate: int = DEFAULT_BAUDRATE,
    options: ClientOptions = ClientOptions(),
    on_line: Callable[[Line], None] | None = None,
) -> AsyncIterator[UltimakerClient]:
    """Open a serial port (the emulator's pty or a real printer) and talk to the printer on it."""
    if protocol not in PROTOCOLS:
        raise CommandError(f"unknown protocol {protocol!r}; choose from {', '.join(PROTOCOLS)}")
    serial_port = SerialPort.open(port, baudrate)
    try:
        async with connect(serial_port, protocol, options, on_line) as client:
            yield client
    finally:
        serial_port.close()
