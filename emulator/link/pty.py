"""A pseudo-terminal standing in for the printer's USB serial port.

The slave side is what hosts open. We keep our own slave fd open so that a host closing the port
does not make reads on the master fail, and we run the master in packet mode (TIOCPKT): a host's
open() flushes its input, which reaches us as a FLUSHREAD notice. That notice, when the device
was opened since the last one (link/opens.py), is the pty's stand-in for the DTR reset a real
board performs when a host opens the port; a host flushing a port it has open resets nothing.
"""

import errno
import fcntl
import os
import struct
import sys
import termios
import tty

import trio

from fake_marlin.emulator.link.base import HostOpened, queue_output
from fake_marlin.emulator.link.direct_wait import DirectWait
from fake_marlin.emulator.link.opens import open_watcher

_TCGETS2 = 0x802C542A  # _IOR('T', 0x2A, struct termios2): reads custom rates such as 250000
_TERMIOS2 = struct.Struct("IIIIB19sII")
_TIOCPKT_DATA = 0
_TIOCPKT_FLUSHREAD = 1


class PtyLink:
    def __init__(self) -> None:
        self._unread: bytes | None = None  # a packet receive_now() read but does not return
        self._open_pty()
        self.connected = True
        self._reconnected = trio.Event()
        self.on_new_path = lambda path: None  # told the new path when the line comes back
        self._pending = bytearray()
        self._output_ready = trio.Event()
        self._emptied = trio.Event()

    def _open_pty(self) -> None:
        self._unread = None  # of the pty before, if any
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        fcntl.ioctl(self._master, termios.TIOCPKT, struct.pack("i", 1))
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self._readable = DirectWait(self._master)
        self._opens = open_watcher()
        self._watch = self._opens.watch(self.path)

    def hang_up(self) -> None:
        """The line goes dead, as when a USB cable is pulled: the host's port fails, and the
        device is gone (it comes back under a new name, as a re-plugged adapter does)."""
        if not self.connected:
            return
        self.connected = False
        self._reconnected = trio.Event()
        self.discard_output()
        trio.lowlevel.notify_closing(self._master)
        self.close()

    def reconnect(self) -> None:
        if self.connected:
            return
        self._open_pty()
        self.connected = True
        self._reconnected.set()
        self._output_ready.set()
        self.on_new_path(self.path)

    def receive_now(self) -> bytes | None:
        """The host's next bytes, waited for here while trio has nothing else to do until they
        come (DirectWait); None where receive() must be awaited instead: trio has something
        due, or what came is no plain data (an open of the port, an error)."""
        if not self.connected or self._unread is not None or not self._readable.waited_directly():
            return None
        try:
            packet = os.read(self._master, 4096)
        except OSError:
            return None  # receive() reads again, and sees to it
        if len(packet) > 1 and packet[0] == _TIOCPKT_DATA:
            return packet[1:]
        self._unread = packet
        return None

    async def receive(self) -> bytes | HostOpened:
        """The next chunk of bytes from the host, or a HostOpened notice."""
        while True:
            if not self.connected:
                await self._reconnected.wait()
                continue
            try:
                if self._unread is not None:
                    await trio.lowlevel.checkpoint()
                    packet, self._unread = self._unread, None
                else:
                    await self._readable.readable()
                    packet = os.read(self._master, 4096)
            except (BlockingIOError, trio.ClosedResourceError):
                continue
            except OSError:
                if not self.connected:
                    continue
                raise
            if not packet:
                continue
            if packet[0] == _TIOCPKT_DATA:
                if len(packet) > 1:
                    return packet[1:]
            elif packet[0] & _TIOCPKT_FLUSHREAD and (
                self._watch is None or self._opens.opened(self._watch)
            ):
                return HostOpened()

    def send(self, data: bytes) -> None:
        """Write bytes for the host, or queue what the pty cannot take now; never blocks the
        printer. Written at once when nothing waits: the common case costs no task hop."""
        if not data or not self.connected:
            return
        if not self._pending:
            try:
                written = os.write(self._master, data)
            except BlockingIOError:
                written = 0
            except OSError as error:
                self._write_failed(error)
                return
            data = data[written:]
            if not data:
                return
        queue_output(self._pending, data)
        self._output_ready.set()

    def host_baud(self) -> int | None:
        """The baud rate the host set on the port (a pty itself never slows down)."""
        if not self.connected:
            return None
        try:
            raw = fcntl.ioctl(self._slave, _TCGETS2, bytes(_TERMIOS2.size))
        except OSError:
            return None
        speed = _TERMIOS2.unpack(raw)[-1]
        return speed or None

    async def drain(self) -> None:
        """Wait until what was sent so far has left for the pty (or was given up)."""
        while self._pending:
            emptied = self._emptied = trio.Event()
            await emptied.wait()

    def discard_output(self) -> None:
        """Forget unsent output: the host that would have read it is gone."""
        self._pending.clear()
        self._emptied.set()

    async def run_writer(self) -> None:
        while True:
            if not self._pending or not self.connected:
                self._output_ready = trio.Event()
                await self._output_ready.wait()
                continue
            try:
                await trio.lowlevel.wait_writable(self._master)
                written = os.write(self._master, self._pending)
            except (BlockingIOError, trio.ClosedResourceError):
                continue
            except OSError as error:
                if self.connected:
                    self._write_failed(error)
                continue
            del self._pending[:written]
            if not self._pending:
                self._emptied.set()

    def _write_failed(self, error: OSError) -> None:
        if error.errno != errno.EIO:
            raise error
        print(f"fake-marlin: write to pty failed: {error}", file=sys.stderr)
        self.discard_output()

    def close(self) -> None:
        self._opens.forget(self._watch)
        self._watch = None
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
