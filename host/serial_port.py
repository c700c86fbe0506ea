"""A serial port as a trio byte stream: pyserial opens and configures it, trio moves the bytes."""

import errno
import os
import termios

import serial
import trio

from fake_marlin.host.errors import ConnectionLost, PortError


PTY_DIRECTORY = "/dev/pts/"


class SerialPort:
    def __init__(self, device: serial.Serial, path: str) -> None:
        self._device = device
        self.path = path
        self._fd = device.fileno()
        os.set_blocking(self._fd, False)

    @classmethod
    def open(cls, path: str, baudrate: int, bytesize: int = 8) -> "SerialPort":
        if os.path.realpath(path).startswith(PTY_DIRECTORY):
            # A pseudo-terminal carries whole bytes whatever its character size (the emulator
            # keeps 7 bits of them itself), and Linux refuses CS7 on one that has had a custom
            # rate such as 250000 set (EINVAL): only a real UART is given another size.
            bytesize = serial.EIGHTBITS
        try:
            device = serial.Serial(path, baudrate, bytesize=bytesize, timeout=0, exclusive=True)
        except serial.SerialException as error:
            if error.errno:
                reason = os.strerror(error.errno)
            elif f"({errno.ENOTTY}," in str(error):
                reason = "not a serial port"
            else:
                reason = str(error)
            raise PortError(f"cannot open {path}: {reason}") from None
        except (OSError, ValueError, termios.error) as error:
            raise PortError(f"cannot open {path}: {error}") from None
        return cls(device, path)

    async def receive_some(self, max_bytes: int | None = 4096) -> bytes:
        while True:
            await trio.lowlevel.wait_readable(self._fd)
            try:
                data = os.read(self._fd, max_bytes or 4096)
            except BlockingIOError:
                continue
            except OSError as error:
                raise ConnectionLost(f"lost the connection to {self.path}: {error.strerror}") from None
            if not data:
                raise ConnectionLost(f"lost the connection to {self.path}: the other side closed it")
            return data

    async def send_all(self, data: bytes) -> None:
        # Written at once, as a port nearly always takes it: waiting for it to be writable
        # first costs a trip through trio's scheduler per write (a quarter of our Ultimaker
        # host's CPU). Only a full port is waited for.
        await trio.lowlevel.checkpoint_if_cancelled()
        view = memoryview(data)
        while view:
            try:
                written = os.write(self._fd, view)
            except BlockingIOError:
                await trio.lowlevel.wait_writable(self._fd)
                continue
            except OSError as error:
                raise ConnectionLost(f"lost the connection to {self.path}: {error.strerror}") from None
            view = view[written:]

    def close(self) -> None:
        try:
            trio.lowlevel.notify_closing(self._fd)
        except RuntimeError:
            pass  # not inside trio: nobody can be waiting on it
        self._device.close()
