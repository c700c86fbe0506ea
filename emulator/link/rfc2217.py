"""The printer on an RFC 2217 port: a serial port over telnet, which pyserial opens as
rfc2217://HOST:PORT, setting the baud rate and the modem lines from afar as on a local port.

pyserial's own server half, serial.rfc2217.PortManager, does the telnet and COM-PORT-OPTION
negotiation: it takes them out of the incoming bytes (filter()), answers them, and applies what
the client sets to a "serial port", here a stand-in (_PortSettings) that records it. The rest
is TcpLink's: one host at a time, output buffered and bounded, hang_up() and reconnect().

When the printer resets (receive() says HostOpened):
- on a DTR pulse: DTR dropped and raised again, as pyserial scripts and the Arduino IDE reset
  a board; the reset comes with the rise.
- on a new connection, once the client has set the port up: pyserial's open() negotiates, sets
  the baud rate and DTR, then purges the receive buffer and then the transmit buffer, waiting for
  the server's answer each time. The reset comes with the transmit purge, as the pty's comes
  with the open's flush: the baud rate is known by then (host_baud(), which paces the line), and
  the greeting cannot be lost to the client's own purge of its receive buffer, which is done.
  A client that purges nothing resets the printer with its first byte, or after OPEN_SECONDS.
"""

import sys
import time

import serial
import trio
from serial.rfc2217 import IAC, PortManager

from fake_marlin.emulator.link.base import HostOpened
from fake_marlin.emulator.link.tcp import Host, TcpLink

# Real seconds, not the printer's (perhaps faster) simulated ones: the client's negotiation runs
# on the wall clock. pyserial's takes a few tenths of a second.
OPEN_SECONDS = 1.0


class _PortSettings:
    """The serial port pyserial's PortManager configures: it records what the client sets, and
    tells the link of a rising DTR and of purges."""

    def __init__(self, link: "Rfc2217Link", host: "_Rfc2217Host") -> None:
        self._link, self._host = link, host
        self._baudrate = 9600  # what a client reads back before it sets one
        self.baud_set = False
        self.bytesize = serial.EIGHTBITS
        self.parity = serial.PARITY_NONE
        self.stopbits = serial.STOPBITS_ONE
        self.xonxoff = self.rtscts = self.break_condition = False
        self.rts = True
        # Raised, as pyserial raises it on open: only a drop and a rise again is a pulse.
        self._dtr = True
        # The lines the printer's end drives, as a USB serial adapter reports them.
        self.cts = self.dsr = True
        self.ri = self.cd = False

    @property
    def baudrate(self) -> int:
        return self._baudrate

    @baudrate.setter
    def baudrate(self, value: int) -> None:
        self._baudrate, self.baud_set = int(value), True

    @property
    def dtr(self) -> bool:
        return self._dtr

    @dtr.setter
    def dtr(self, value: bool) -> None:
        rising = value and not self._dtr
        self._dtr = bool(value)
        if rising:
            self._link._reset(self._host)

    def reset_input_buffer(self) -> None:
        """Purge what came from the device (the printer) and was not yet sent to the client."""
        if self._host.announced:
            self._link.discard_output()

    def reset_output_buffer(self) -> None:
        """Purge what the client sent and the device did not take yet: the printer takes it
        all at once. pyserial's open() ends with this purge: its port is set up."""
        if not self._host.opened:
            self._link._reset(self._host)


class _Rfc2217Host(Host):
    def __init__(self, sock: trio.socket.SocketType, peer: str, link: "Rfc2217Link") -> None:
        super().__init__(sock, peer)
        self.opened = False  # a HostOpened is queued (or was returned) for this connection
        self.incoming = bytearray()  # filtered bytes not yet queued for receive()
        self.settings = _PortSettings(link, self)
        self._link = link
        self.manager: PortManager | None = None  # once this is the link's host: see start()

    def start(self) -> PortManager:
        """Start the telnet negotiation: PortManager sends its opening requests at once. (The
        stub wants pyserial Serials; PortManager only uses the attributes _PortSettings has,
        and the connection's write().)"""
        self.manager = PortManager(self.settings, self)  # type: ignore[arg-type]
        return self.manager

    def write(self, data: bytes) -> None:
        """PortManager's telnet answers, ahead of the printer's output."""
        if self is self._link._host:
            self._link._control += data
            self._link._output_ready.set()


class Rfc2217Link(TcpLink):
    """A Link (link.base) on an RFC 2217 port; see the module's docstring."""

    scheme = "rfc2217"

    def _new_host(self, sock: trio.socket.SocketType, peer: str) -> Host:
        return _Rfc2217Host(sock, peer, self)

    def _opened(self, host: Host, nursery: trio.Nursery) -> None:
        # Telnet negotiation starts; the reset waits for the client to set the port up.
        assert isinstance(host, _Rfc2217Host)
        host.start()
        nursery.start_soon(self._open_anyway, host)

    async def _open_anyway(self, host: Host) -> None:
        await trio.to_thread.run_sync(time.sleep, OPEN_SECONDS, abandon_on_cancel=True)
        if isinstance(host, _Rfc2217Host) and not host.opened:
            self._reset(host)

    def _incoming(self, host: Host, data: bytes) -> None:
        assert isinstance(host, _Rfc2217Host) and host.manager is not None
        try:
            for byte in host.manager.filter(data):
                if not host.opened:
                    self._reset(host)  # a client that sets nothing up: its first byte
                host.incoming += byte
        except Exception as error:  # noqa: BLE001 - PortManager trips on malformed options
            print(f"fake-marlin: dropped the host at {host.peer} on {self.path}: bad telnet "
                  f"negotiation ({type(error).__name__}: {error})", file=sys.stderr)
            self._drop(host)
            return
        self._flush(host)

    def _flush(self, host: "_Rfc2217Host") -> None:
        if host.incoming:
            self._events.append(bytes(host.incoming))
            host.incoming.clear()

    def _reset(self, host: "_Rfc2217Host") -> None:
        """The board resets here: what the client sent before this belongs to the old boot."""
        if host is not self._host:
            return
        self._flush(host)
        self._events.append(HostOpened())
        host.opened = True
        self._wake_receiver()

    def _encode(self, host: Host, data: bytes) -> bytes:
        if IAC not in data:  # escape() goes byte by byte, and text has no 0xFF to double
            return data
        assert isinstance(host, _Rfc2217Host) and host.manager is not None
        return b"".join(host.manager.escape(data))

    def host_baud(self) -> int | None:
        """The baud rate the client set on the port."""
        host = self._host
        if isinstance(host, _Rfc2217Host) and host.settings.baud_set:
            return host.settings.baudrate
        return None

