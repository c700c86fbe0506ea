"""The printer on a TCP port, raw bytes both ways: what ser2net serves for a real printer's serial
port, and what Marlin's own simulator serves on port 8099. Hosts reach it as socket://HOST:PORT
(pyserial, our host) or HOST:PORT (printcore).

Binding happens in the constructor, with the standard library, so a program knows the real port
(port 0 picks a free one) and can report a taken one before trio starts; `path` then says where,
as socket://HOST:PORT. Everything after that runs in trio, in `run_writer()`, which the printer
server runs for as long as the printer does: it accepts hosts and carries the printer's output.

What the pty's open is to PtyLink, a new connection is here: the board resets (receive() says
HostOpened), then the host's bytes follow. One host at a time, as one program holds a serial
port: a second is told why and closed, and the first carries on. When the host goes, the
printer runs on, its output going nowhere, until the next one connects. hang_up() is the line
going dead: the host is dropped and the port refuses connections until reconnect(), which
listens on the same port again (the path stays the same, and is announced anew as the pty's
new path is).
"""

import errno
import os
import socket
import sys
from collections import deque
from collections.abc import Callable

import trio

from fake_marlin.emulator.link.base import HostOpened, queue_output

REFUSAL = b"fake-marlin: this printer already has a host connected\n"
_CHUNK = 4096
_BACKLOG = 8
# A refused client is given this long to read the refusal and close its end first (our close
# with its bytes unread would reset the connection, and the message could be lost with it).
_REFUSAL_SECONDS = 2.0
# A host that vanishes without closing (powered off, cable pulled) would otherwise hold the
# printer for ever, and every later host would be refused: keepalive finds it in ~25 s when
# the line is quiet, and the user timeout (ms) in 30 s when the printer's output goes unanswered.
_KEEPALIVE = (
    ("TCP_KEEPIDLE", 10), ("TCP_KEEPINTVL", 5), ("TCP_KEEPCNT", 3), ("TCP_USER_TIMEOUT", 30_000),
)
# accept() errors that are the client's doing (it gave up before we took it): not ours to report.
_CLIENT_GAVE_UP = {errno.ECONNABORTED, errno.EPROTO, errno.ECONNRESET}


class LinkError(Exception):
    """The link cannot be set up as asked (a port taken, a host name unknown)."""


def host_port(host: str, port: int) -> str:
    """HOST:PORT, with an IPv6 address in brackets as URLs write it."""
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def _bind(family: int, address: tuple[object, ...]) -> socket.socket:
    listener = socket.socket(family, socket.SOCK_STREAM)
    try:
        # Lets a restarted printer (or reconnect()) take its port while old connections to it
        # are still in TIME_WAIT; it never lets two listeners share one (SO_REUSEPORT would).
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind(address)
        listener.listen(_BACKLOG)
    except OSError:
        listener.close()
        raise
    return listener


def listen(host: str, port: int) -> socket.socket:
    """A listening socket on HOST:PORT, or LinkError saying why not."""
    where = host_port(host, port)
    if not 0 <= port <= 65535:
        raise LinkError(f"cannot listen on {where}: a port is 0 to 65535")
    try:
        found = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
        # A name with both (localhost): IPv4, which every host can reach (printcore only it).
        found.sort(key=lambda info: info[0] != socket.AF_INET)
        family, _, _, _, address = found[0]
        return _bind(family, address)
    except OSError as error:
        raise LinkError(f"cannot listen on {where}: {error.strerror or error}") from None


def _close(sock: trio.socket.SocketType) -> None:
    try:
        sock.close()
    except RuntimeError:  # outside trio (the CLI closes its link after trio.run): nobody waits
        os.close(sock.detach())


def _tune(sock: trio.socket.SocketType) -> None:
    # The printer's answers are short lines a host waits for: Nagle's algorithm would hold each
    # back until the last one is acknowledged.
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
    for name, value in _KEEPALIVE:
        if hasattr(socket, name):
            sock.setsockopt(socket.IPPROTO_TCP, getattr(socket, name), value)


class Host:
    """One connected host."""

    def __init__(self, sock: trio.socket.SocketType, peer: str) -> None:
        self.socket = sock
        self.peer = peer
        self.announced = False  # receive() has said HostOpened for it: output now goes to it


class TcpLink:
    """A Link (link.base) on a TCP port; see the module's docstring."""

    scheme = "socket"

    def __init__(self, host: str = "127.0.0.1", port: int = 0) -> None:
        listener = listen(host, port)
        # reconnect() binds this very address again (the real port, when 0 was asked for).
        self._family, self._address = listener.family, listener.getsockname()
        self.host, self.port = host, int(self._address[1])
        self.path = f"{self.scheme}://{host_port(host, self.port)}"
        self._listener: trio.socket.SocketType | None = trio.socket.from_stdlib_socket(listener)
        self.on_new_path: Callable[[str], None] = lambda path: None  # told when the line is back
        self.connected = True  # the line is up (hang_up() takes it down)
        self._line_up = trio.Event()
        self._host: Host | None = None
        self._events: deque[bytes | HostOpened] = deque()  # what receive() returns next
        self._arrived = trio.Event()
        self._receiving = trio.CancelScope()
        self._pending = bytearray()  # the printer's output, not yet handed to the socket
        self._control = bytearray()  # the link's own bytes for the host (RFC 2217's telnet)
        self._wire = b""  # handed to the socket, being sent: goes whole, or with the host
        self._output_ready = trio.Event()
        self._emptied = trio.Event()

    @property
    def has_host(self) -> bool:
        """Whether a host is connected now (the live view's "host" column)."""
        return self._host is not None

    # -- what a subclass (Rfc2217Link) changes ---------------------------------------------
    def _new_host(self, sock: trio.socket.SocketType, peer: str) -> Host:
        return Host(sock, peer)

    def _opened(self, host: Host, nursery: trio.Nursery) -> None:
        """A host connected: on a raw port, that is the reset."""
        self._events.append(HostOpened())

    def _incoming(self, host: Host, data: bytes) -> None:
        self._events.append(data)

    def _encode(self, host: Host, data: bytes) -> bytes:
        return data

    # -- the printer's side ------------------------------------------------------------------
    async def receive(self) -> bytes | HostOpened:
        """The next chunk of bytes from the host, or a HostOpened notice."""
        while True:
            if self._events:
                item = self._events.popleft()
                if isinstance(item, HostOpened) and self._host is not None:
                    self._host.announced = True
                return item
            host = self._host
            if host is None:
                self._arrived = trio.Event()
                await self._arrived.wait()
                continue
            data = b""
            with trio.CancelScope() as self._receiving:  # cancelled when an event comes first
                try:
                    data = await host.socket.recv(_CHUNK)
                except trio.ClosedResourceError:
                    continue  # dropped meanwhile (hang_up, or a failed send)
                except OSError:
                    pass  # reset by the peer: gone, as when it closes
            if self._receiving.cancelled_caught or host is not self._host:
                continue
            if data:
                self._incoming(host, data)
            else:
                self._drop(host)

    def send(self, data: bytes) -> None:
        """Queue bytes for the host; never blocks the printer. Nobody connected: nobody hears."""
        host = self._host
        if not data or host is None or not host.announced:
            return
        queue_output(self._pending, data)
        self._output_ready.set()

    def host_baud(self) -> int | None:
        """A TCP port has no baud rate."""
        return None

    async def drain(self) -> None:
        """Wait until what was sent so far has left for the socket (or was given up)."""
        while self._pending or self._wire:
            emptied = self._emptied = trio.Event()
            await emptied.wait()

    def discard_output(self) -> None:
        """Forget unsent output: the host that would have read it is gone."""
        self._pending.clear()
        self._emptied.set()

    def hang_up(self) -> None:
        """The line goes dead: the host is dropped and connections are refused until
        reconnect()."""
        if not self.connected:
            return
        self.connected = False
        self._line_up = trio.Event()
        if self._host is not None:
            self._drop(self._host)
        if self._listener is not None:
            _close(self._listener)  # wakes the accept loop, which waits for the line
            self._listener = None

    def reconnect(self) -> None:
        if self.connected:
            return
        self.connected = True
        self._line_up.set()

    async def run_writer(self) -> None:
        """Accept hosts and carry the printer's output, for as long as the printer runs."""
        async with trio.open_nursery() as nursery:
            nursery.start_soon(self._accept_hosts, nursery)
            await self._write()

    def close(self) -> None:
        if self._host is not None:
            _close(self._host.socket)
            self._host = None
        if self._listener is not None:
            _close(self._listener)
            self._listener = None

    # -- inside ------------------------------------------------------------------------------
    def _wake_receiver(self) -> None:
        self._arrived.set()
        self._receiving.cancel()

    def _drop(self, host: Host) -> None:
        """The host is gone (it closed, failed, or the line hung up): so is all it had coming."""
        if host is not self._host:
            return
        self._host = None
        self._events.clear()
        self._pending.clear()
        self._control.clear()
        self._wire = b""
        self._emptied.set()
        _close(host.socket)
        self._wake_receiver()

    async def _accept_hosts(self, nursery: trio.Nursery) -> None:
        back = False  # the line came back: say where, once listening again
        complained = False
        while True:
            if not self.connected:
                await self._line_up.wait()
                back = True
                continue
            if self._listener is None:
                try:
                    self._listener = trio.socket.from_stdlib_socket(
                        _bind(self._family, self._address)
                    )
                except OSError as error:
                    if not complained:
                        print(f"fake-marlin: cannot listen on {self.path} again: "
                              f"{error.strerror}; retrying", file=sys.stderr)
                        complained = True
                    await trio.sleep(1)
                    continue
            if back:
                back = complained = False
                self.on_new_path(self.path)
            try:
                sock, address = await self._listener.accept()
            except trio.ClosedResourceError:
                continue  # hang_up() closed it
            except OSError as error:
                if error.errno not in _CLIENT_GAVE_UP:  # out of file descriptors, say
                    print(f"fake-marlin: cannot accept a host on {self.path}: "
                          f"{error.strerror}", file=sys.stderr)
                    await trio.sleep(0.5)
                continue
            if self._host is not None or not self.connected:
                nursery.start_soon(self._refuse, sock)
                continue
            try:
                _tune(sock)
            except OSError:
                _close(sock)  # gone already
                continue
            self._host = host = self._new_host(sock, host_port(str(address[0]), int(address[1])))
            self._events.clear()
            self._pending.clear()
            self._control.clear()
            self._wire = b""
            self._opened(host, nursery)
            self._wake_receiver()
            self._output_ready.set()

    async def _refuse(self, sock: trio.socket.SocketType) -> None:
        with trio.move_on_after(_REFUSAL_SECONDS):
            try:
                await sock.send(REFUSAL)  # a few bytes: the kernel takes them at once
                sock.shutdown(socket.SHUT_WR)
                while await sock.recv(_CHUNK):
                    pass  # whatever it sent meanwhile, until it closes
            except OSError:
                pass
        _close(sock)

    def _has_output(self) -> bool:
        return bool(self._wire or self._pending or self._control)

    async def _write(self) -> None:
        while True:
            host = self._host
            if host is None or not self._has_output():
                self._output_ready = trio.Event()
                await self._output_ready.wait()
                continue
            if not self._wire:
                data = bytes(self._pending[:_CHUNK])
                del self._pending[:_CHUNK]
                self._wire = bytes(self._control) + self._encode(host, data)
                self._control.clear()
            try:
                sent = await host.socket.send(self._wire)
            except trio.ClosedResourceError:
                continue  # dropped meanwhile
            except OSError:
                self._drop(host)  # the host is gone (reset, broken pipe)
                continue
            self._wire = self._wire[sent:]
            if not self._wire and not self._pending:
                self._emptied.set()
