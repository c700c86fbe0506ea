"""An in-memory link: the printer on one end, a host's byte stream on the other.

Used to run the printer and a host in one process (tests on trio's autojump clock, scenarios),
a Link (link.base) as PtyLink is.
"""

import math

import trio

from fake_marlin.emulator.link.base import HostOpened
from fake_marlin.host.errors import (
    ConnectionLost,  # the in-memory host end fails as a serial port does
)


class MemoryLink:
    def __init__(self) -> None:
        self._inbound_send, self._inbound = trio.open_memory_channel[bytes | HostOpened](math.inf)
        self._outbound = bytearray()
        self._outbound_ready = trio.Event()
        self.baud: int | None = None  # what a host "set on the port"
        self.connected = True
        self.generation = 0  # a host's end dies with the line it was opened on
        self.host = HostEnd(self)

    # -- the printer's side (as PtyLink) -------------------------------------------------
    async def receive(self) -> bytes | HostOpened:
        return await self._inbound.receive()

    def hang_up(self) -> None:
        """The line goes dead: the host's end fails until a host opens the port again."""
        self.connected = False
        self.generation += 1
        self._outbound.clear()
        self._outbound_ready.set()

    def reconnect(self) -> None:
        self.connected = True

    def send(self, data: bytes) -> None:
        if data and self.connected:
            self._outbound += data
            self._outbound_ready.set()

    def host_baud(self) -> int | None:
        return self.baud

    async def drain(self) -> None:
        await trio.lowlevel.checkpoint()

    def discard_output(self) -> None:
        self._outbound.clear()

    async def run_writer(self) -> None:
        await trio.sleep_forever()

    # -- the host's side ---------------------------------------------------------------
    def open_host(self) -> "HostEnd":
        """A host opens the port: stale output is flushed and the printer is told (resets)."""
        if not self.connected:
            raise ConnectionLost("the port is gone: the line hung up")
        self._outbound.clear()
        self.host = HostEnd(self)
        self._inbound_send.send_nowait(HostOpened())
        return self.host


class HostEnd:
    """The host's end, a trio byte stream (receive_some / send_all)."""

    def __init__(self, link: MemoryLink) -> None:
        self._link = link
        self._generation = link.generation

    def _check(self) -> None:
        if self._generation != self._link.generation:
            raise ConnectionLost("lost the connection: the line hung up")

    async def send_all(self, data: bytes) -> None:
        await trio.lowlevel.checkpoint()
        self._check()
        if data:
            self._link._inbound_send.send_nowait(bytes(data))

    async def receive_some(self, max_bytes: int = 4096) -> bytes:
        link = self._link
        self._check()
        while not link._outbound:
            link._outbound_ready = trio.Event()
            await link._outbound_ready.wait()
            self._check()
        data = bytes(link._outbound[:max_bytes])
        del link._outbound[:max_bytes]
        return data
