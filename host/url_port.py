"""Ports named by URL, for printers on the network, as trio byte streams with close():

- socket://HOST:PORT: raw TCP (ser2net, Marlin's simulator, `fake-marlin --tcp`), through trio.
- rfc2217://HOST:PORT: a serial port over telnet (`fake-marlin --rfc2217`, ser2net with RFC 2217
  on), through pyserial's client, which sets the baud rate and DTR on the far port.

Anything else is a serial device, opened as before (host.serial_port).
"""

import os
from urllib.parse import urlsplit

import serial
import serial.rfc2217
import trio

from fake_marlin.host.errors import ConnectionLost, PortError
from fake_marlin.host.serial_port import SerialPort

CONNECT_TIMEOUT = 10.0  # a host that drops our SYNs would otherwise take minutes to fail
# How long one read waits in pyserial's client before trio gets a word in: a cancelled read
# returns within it, and nothing it read is lost.
READ_TIMEOUT = 0.05
_REFUSAL_LENGTH = 200  # a connection refused with one line of text says why: at most this long


def is_url(port: str) -> bool:
    return "://" in port


async def open_port(port: str, baudrate: int,
                    bytesize: int = 8) -> "SerialPort | TcpPort | Rfc2217Port":
    """The port, opened: a URL (socket://, rfc2217://) or a serial device's path (with
    `bytesize` data bits: 7 for the 7bit variant's line)."""
    if not is_url(port):
        return SerialPort.open(port, baudrate, bytesize)
    scheme = port.partition("://")[0].lower()
    if scheme == "socket":
        return await TcpPort.open(port)
    if scheme == "rfc2217":
        return await Rfc2217Port.open(port, baudrate)
    raise PortError(f"cannot open {port}: unknown kind of URL; use socket://HOST:PORT or "
                    "rfc2217://HOST:PORT, or a serial device's path")


def _address(url: str) -> tuple[str, int]:
    try:
        parts = urlsplit(url)
        host, number = parts.hostname, parts.port
    except ValueError as error:  # a port that is no number, or out of range
        raise PortError(f"cannot open {url}: {error}; expected socket://HOST:PORT") from None
    if not host or number is None or parts.path not in ("", "/"):
        raise PortError(f"cannot open {url}: expected socket://HOST:PORT")
    return host, number


def _reason(error: BaseException) -> str:
    """What went wrong, in the system's words (trio groups one error per address it tried)."""
    causes = [error]
    if isinstance(error.__cause__, BaseExceptionGroup):
        causes = list(error.__cause__.exceptions)
    reasons = []
    for cause in causes:
        if isinstance(cause, OSError) and cause.errno and cause.errno > 0:
            reasons.append(os.strerror(cause.errno))  # trio's own wording names the address
        elif isinstance(cause, OSError) and cause.strerror:
            reasons.append(cause.strerror)  # a resolver error: "Name or service not known"
        else:
            reasons.append(str(cause))
    return "; ".join(dict.fromkeys(reasons))  # each once, in order


class TcpPort:
    """A raw TCP connection to a printer (socket://HOST:PORT)."""

    def __init__(self, stream: trio.SocketStream, where: str) -> None:
        self._stream = stream
        self.path = where
        self._first_words = b""  # what the other side said first, to explain a refusal
        self._received = 0

    @classmethod
    async def open(cls, url: str) -> "TcpPort":
        host, number = _address(url)
        where = f"[{host}]:{number}" if ":" in host else f"{host}:{number}"
        with trio.move_on_after(CONNECT_TIMEOUT):
            try:
                # trio's SocketStream turns Nagle's algorithm off: lines go out at once.
                return cls(await trio.open_tcp_stream(host, number), where)
            except OSError as error:
                raise PortError(f"cannot connect to {where}: {_reason(error)}") from None
        raise PortError(f"cannot connect to {where}: no answer in {CONNECT_TIMEOUT:g} s")

    def _lost(self, why: str) -> ConnectionLost:
        said = self._first_words.decode("ascii", "replace").strip()
        if self._received <= _REFUSAL_LENGTH and said and "\n" not in said:
            # One line, then the close: a refusal (ours, ser2net's "port in use"), which says
            # why better than we can.
            why += f", saying: {said}"
        return ConnectionLost(f"lost the connection to {self.path}: {why}")

    async def receive_some(self, max_bytes: int | None = 4096) -> bytes:
        try:
            data = await self._stream.receive_some(max_bytes or 4096)
        except (trio.BrokenResourceError, trio.ClosedResourceError) as error:
            raise self._lost(_reason(error.__cause__ or error)) from None
        if not data:
            raise self._lost("the other side closed it")
        if self._received < _REFUSAL_LENGTH:
            self._first_words += data[: _REFUSAL_LENGTH - self._received]
        self._received += len(data)
        return data

    async def send_all(self, data: bytes) -> None:
        try:
            await self._stream.send_all(data)
        except (trio.BrokenResourceError, trio.ClosedResourceError) as error:
            raise self._lost(_reason(error.__cause__ or error)) from None

    def close(self) -> None:
        self._stream.socket.close()


class Rfc2217Port:
    """A serial port over RFC 2217 (rfc2217://HOST:PORT), through pyserial's client. It reads
    the socket in a thread of its own; our reads and writes wait for it in trio's threads."""

    def __init__(self, device: serial.rfc2217.Serial, url: str) -> None:
        self._device = device
        self.path = url

    @classmethod
    async def open(cls, url: str, baudrate: int) -> "Rfc2217Port":
        def connect() -> serial.rfc2217.Serial:
            device = serial.serial_for_url(url, baudrate, timeout=READ_TIMEOUT)
            assert isinstance(device, serial.rfc2217.Serial)  # what rfc2217:// URLs open
            return device

        try:
            device = await trio.to_thread.run_sync(connect)
        except serial.SerialException as error:
            raise PortError(f"cannot open {url}: {_open_failure(error)}") from None
        except (OSError, ValueError) as error:
            raise PortError(f"cannot open {url}: {error}") from None
        return cls(device, url)

    def _read(self, max_bytes: int) -> bytes:
        data = self._device.read(1)  # waits up to READ_TIMEOUT
        waiting = self._device.in_waiting
        if data and waiting and max_bytes > 1:
            data += self._device.read(min(waiting, max_bytes - 1))
        return data

    async def receive_some(self, max_bytes: int | None = 4096) -> bytes:
        while True:
            try:
                # Not abandoned on cancel: what the thread read would be lost with it.
                data = await trio.to_thread.run_sync(self._read, max_bytes or 4096)
            except (serial.SerialException, OSError) as error:
                raise ConnectionLost(
                    f"lost the connection to {self.path}: {_lost(error)}"
                ) from None
            if data:
                return data

    async def send_all(self, data: bytes) -> None:
        try:
            await trio.to_thread.run_sync(self._device.write, data)
        except (serial.SerialException, OSError) as error:
            raise ConnectionLost(f"lost the connection to {self.path}: {_lost(error)}") from None

    def close(self) -> None:
        try:
            self._device.close()  # joins pyserial's reader, which the socket's close ends
        except (serial.SerialException, OSError):
            pass


def _lost(error: Exception) -> str:
    if "reader thread died" in str(error):  # how pyserial's client says the socket closed
        return "the other side closed it"
    return str(error)


def _open_failure(error: serial.SerialException) -> str:
    text = str(error)
    context = error.__context__
    if isinstance(context, OSError) and "Could not open port" in text:
        return str(context.strerror or context)  # "Connection refused", not pyserial's wrapping
    if "does not seem to support RFC2217" in text:
        # What a raw TCP port does, and what our printer's refusal of a second host looks like.
        return ("no RFC 2217 answer (a raw TCP port? then use socket://; or another host "
                "already has the printer)")
    return text
