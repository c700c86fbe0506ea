"""The trio host client: one reader task, one sender task behind a send lock, and a sans-IO core.

The shell is shared; each protocol brings its parser and its core: Ultimaker's go-back-N window
(host/window.py), Marlin's line sender (host/marlin_sender.py).
"""

import math
from collections.abc import AsyncIterator, Callable, Iterable
from contextlib import asynccontextmanager
from dataclasses import asdict, dataclass
from typing import Protocol

import trio

from host.codecs import marlin
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
from host.errors import CommandError, HostError, PrinterHalted
from host.gcode_file import JobCommand, read_job
from host.marlin_sender import MarlinSender
from host.serial_port import SerialPort
from host.window import GoBackNWindow, Ticket

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
        return await self.print_commands([c.text for c in load_job(path, self.protocol)], progress)


class UltimakerClient(_Client):
    protocol = "ultimaker"

    def __init__(
        self,
        stream: ByteStream,
        options: ClientOptions = ClientOptions(),
        on_line: Callable[[Line], None] | None = None,
    ) -> None:
        super().__init__(stream, options, on_line)
        self._parser = FrameParser()
        self._core = self._window = GoBackNWindow(
            window=options.window,
            timeout=options.timeout,
            long_timeout=options.long_timeout,
            received_timeout=options.received_timeout,
            max_transmissions=options.max_transmissions,
        )
        self._response: list[str] = []

    def _feed(self, data: bytes) -> None:
        self._parser.receive_data(data)
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
                if event.kind is LineKind.ERROR and marlin.is_halt_message(event.text):
                    raise PrinterHalted(f"the printer halted: Error:{event.text}")

    def _poll(self, now: float) -> list[bytes]:
        data = [encode_command(t.seq, t.text) for t in self._window.poll(now)]
        self._completed(self._window.take_completed())
        return data


class MarlinClient(_Client):
    """Marlin's ASCII protocol: numbered lines, one in flight (see host/marlin_sender.py)."""

    protocol = "marlin"
    check_command = staticmethod(marlin.check_command)

    def __init__(
        self,
        stream: ByteStream,
        options: ClientOptions = ClientOptions(),
        on_line: Callable[[marlin.Line], None] | None = None,
    ) -> None:
        super().__init__(stream, options, on_line)
        self._parser = marlin.LineParser()
        self._core = self._sender = MarlinSender(
            timeout=options.timeout,
            long_timeout=options.long_timeout,
            received_timeout=options.received_timeout,
            max_transmissions=options.max_transmissions,
        )
        self._response: list[str] = []  # data lines since the last ok

    def _feed(self, data: bytes) -> None:
        now = trio.current_time()
        self._parser.receive_data(data)
        while (event := self._parser.next_event()) is not None:
            self._printer_seen.set()
            self._handle(event, now)
        self.corrupt_frames = self._parser.garbled
        self._completed(self._sender.take_completed())
        self._sender_wake.set()  # deadlines moved, or there is something to send

    def _handle(self, event: marlin.Event, now: float) -> None:
        sender = self._sender
        if isinstance(event, marlin.Ok):
            response = (*self._response, event.text) if event.text else tuple(self._response)
            self._response.clear()
            if event.planner_free is not None:
                self.room = event.planner_free
            sender.on_ok(event, response, now)
        elif isinstance(event, marlin.LineError):
            sender.on_line_error(event.last_line, now)
        elif isinstance(event, marlin.ResendRequest):
            sender.on_resend(event.line, now)
        else:
            sender.on_line(event.kind, event.text, now)
            if event.kind in (marlin.LineKind.DATA, marlin.LineKind.ECHO) and sender.expecting_response:
                self._response.append(event.text)
            else:
                self._on_line(event)

    def _poll(self, now: float) -> list[bytes]:
        data = self._sender.poll(now)
        self._completed(self._sender.take_completed())
        return data

    async def wait_idle(self) -> None:
        """Also confirms the printer holds every line sent (one probe; see marlin_sender)."""
        self._sender.request_verification()
        self._sender_wake.set()
        await super().wait_idle()


PROTOCOLS = ("ultimaker", "marlin", "repetier", "commstack")


def _client_class(protocol: str) -> type[_Client]:
    # The other protocols' clients build on this module's shell, so they are imported here.
    from host.commstack_client import CommStackClient
    from host.repetier_client import RepetierClient

    clients = {
        client.protocol: client
        for client in (UltimakerClient, MarlinClient, RepetierClient, CommStackClient)
    }
    if protocol not in clients:
        raise CommandError(f"unknown protocol {protocol!r}; choose from {', '.join(PROTOCOLS)}")
    return clients[protocol]


def load_job(path: str, protocol: str = "ultimaker") -> list[JobCommand]:
    """Read a job and check every command can be sent, before any is."""
    check = _client_class(protocol).check_command
    job = read_job(path)
    for command in job:
        try:
            check(command.text)
        except CommandError as error:
            raise CommandError(f"{path}:{command.line_number}: {error}") from None
    return job


@asynccontextmanager
async def connect(
    stream: ByteStream,
    protocol: str = "ultimaker",
    options: ClientOptions = ClientOptions(),
    on_line: Callable | None = None,
) -> AsyncIterator[_Client]:
    """A client speaking `protocol` over an open byte stream."""
    client = _client_class(protocol)(stream, options, on_line)
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
    on_line: Callable | None = None,
) -> AsyncIterator[_Client]:
    """Open a serial port (the emulator's pty or a real printer) and talk to the printer on it."""
    _client_class(protocol)
    serial_port = SerialPort.open(port, baudrate)
    try:
        async with connect(serial_port, protocol, options, on_line) as client:
            yield client
    finally:
        serial_port.close()
