"""Opening a printer: the client for a protocol, over a byte stream or a serial port."""

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import trio

from fake_marlin.host.clients.commstack import CommStackClient
from fake_marlin.host.clients.g2core import G2coreClient
from fake_marlin.host.clients.marlin import MarlinClient
from fake_marlin.host.clients.repetier import RepetierClient
from fake_marlin.host.clients.ultimaker import UltimakerClient
from fake_marlin.host.errors import CommandError, UsageError
from fake_marlin.host.gcode_file import JobCommand, checked_job
from fake_marlin.host.shell import ByteStream, Client, ClientOptions, LineCallback, sole_exception
from fake_marlin.host.url_port import open_port
from fake_marlin.wire.ultimaker_variants import VariantError, variants_of

DEFAULT_BAUDRATE = 250000
_CLIENTS: dict[str, type[Client]] = {
    client.protocol: client
    for client in (UltimakerClient, MarlinClient, RepetierClient, CommStackClient, G2coreClient)
}
PROTOCOLS = tuple(_CLIENTS)


def _client_class(protocol: str, options: ClientOptions = ClientOptions()) -> type[Client]:
    if protocol not in _CLIENTS:
        raise CommandError(f"unknown protocol {protocol!r}; choose from {', '.join(PROTOCOLS)}")
    try:
        variants = variants_of(options.variants)
    except VariantError as error:
        raise UsageError(str(error)) from None
    if not variants.plain and protocol != "ultimaker":
        raise UsageError(f"protocol variants ({variants}) are Ultimaker's; {protocol} has none")
    return _CLIENTS[protocol]


def load_job(path: str, protocol: str = "ultimaker") -> list[JobCommand]:
    """Read a job and check every command can be sent, before any is."""
    return checked_job(path, _client_class(protocol).check_command)


@asynccontextmanager
async def connect(
    stream: ByteStream,
    protocol: str = "ultimaker",
    options: ClientOptions = ClientOptions(),
    on_line: LineCallback | None = None,
) -> AsyncIterator[Client]:
    """A client speaking `protocol` over an open byte stream."""
    client = _client_class(protocol, options)(stream, options, on_line)
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


@asynccontextmanager
async def open_printer(
    port: str,
    protocol: str = "ultimaker",
    baudrate: int = DEFAULT_BAUDRATE,
    options: ClientOptions = ClientOptions(),
    on_line: LineCallback | None = None,
) -> AsyncIterator[Client]:
    """Open a serial port (the emulator's pty or a real printer), or a network port by URL
    (socket://HOST:PORT, rfc2217://HOST:PORT), and talk to the printer on it."""
    _client_class(protocol, options)
    serial_port = await open_port(port, baudrate, variants_of(options.variants).data_bits)
    try:
        async with connect(serial_port, protocol, options, on_line) as client:
            yield client
    finally:
        serial_port.close()
