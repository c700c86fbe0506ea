"""Hosts that speak raw firmware lines over an in-memory stream, for tests: `Terminal` reads
text lines, `RawPort` the exact bytes."""

import re
from contextlib import asynccontextmanager

import trio

OK_LINE = re.compile(rb"(^|\n)ok[^\n]*\n")


class Terminal:
    """A host on the line: raw lines out, text lines back (UTF-8: RRF's degree sign)."""

    def __init__(self, stream) -> None:
        self.stream = stream
        self._buffer = b""
        self.chunks: list[bytes] = []  # every read, to check what arrived together
        self.received = b""  # every byte since the last take()

    async def send(self, line: str) -> None:
        await self.stream.send_all(line.encode() + b"\n")

    async def read_line(self) -> str:
        while b"\n" not in self._buffer:
            chunk = await self.stream.receive_some(4096)
            self.chunks.append(chunk)
            self.received += chunk
            self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\n", 1)
        return line.decode("utf-8")

    async def read_until(self, predicate, timeout: float = 600.0) -> list[str]:
        lines = []
        with trio.fail_after(timeout):
            while True:
                lines.append(await self.read_line())
                if predicate(lines[-1]):
                    return lines

    async def command(self, line: str, timeout: float = 600.0) -> list[str]:
        """Send one line; everything the printer said up to and including its `ok`."""
        await self.send(line)
        return await self.read_until(lambda text: text.startswith("ok"), timeout)

    async def exchange(self, line: str) -> bytes:
        """One line sent; the exact bytes back, up to and including its `ok` line."""
        self.take()
        await self.command(line)
        return self.take()

    async def quiet_for(self, seconds: float) -> list[str]:
        lines = []
        with trio.move_on_after(seconds):
            while True:
                lines.append(await self.read_line())
        return lines

    def take(self) -> bytes:
        data, self.received = self.received, b""
        return data


class RawPort:
    """A host's end of the serial line, in raw bytes: what the printer said, byte for byte."""

    def __init__(self, stream, quiet: float = 3.0) -> None:
        self.stream = stream
        self.buffer = b""
        self.quiet = quiet  # ask()'s default: how long a silence ends an answer

    async def send(self, data: bytes | str) -> None:
        """Bytes as they are; a str as a line."""
        await self.stream.send_all(data if isinstance(data, bytes) else data.encode() + b"\n")

    async def read_until(self, ending: bytes, timeout: float = 600.0) -> bytes:
        """Everything up to and including the first `ending`."""
        with trio.fail_after(timeout):
            while ending not in self.buffer:
                self.buffer += await self.stream.receive_some(4096)
        at = self.buffer.index(ending) + len(ending)
        data, self.buffer = self.buffer[:at], self.buffer[at:]
        return data

    async def quiet_for(self, seconds: float) -> bytes:
        """Everything said until it has been quiet for `seconds`."""
        while True:
            with trio.move_on_after(seconds) as waited:
                self.buffer += await self.stream.receive_some(4096)
            if waited.cancelled_caught:
                data, self.buffer = self.buffer, b""
                return data

    async def ask(self, line: bytes | str, seconds: float | None = None) -> bytes:
        """Send a line; all the printer says until it has been quiet for a while."""
        await self.send(line)
        return await self.quiet_for(self.quiet if seconds is None else seconds)

    async def command(self, line: str, timeout: float = 600.0) -> bytes:
        """Send a line; what the printer says up to and including its `ok` line."""
        await self.send(line)
        return await self.read_until_ok(timeout)

    async def read_until_ok(self, timeout: float = 600.0) -> bytes:
        with trio.fail_after(timeout):
            while (match := OK_LINE.search(self.buffer)) is None:
                self.buffer += await self.stream.receive_some(4096)
        data, self.buffer = self.buffer[:match.end()], self.buffer[match.end():]
        return data


def numbered(n: int, command: str) -> str:
    """`N<n> <command>*<checksum>` as hosts send it."""
    from fake_marlin.emulator.protocols.marlin import xor_checksum

    body = f"N{n} {command}"
    return f"{body}*{xor_checksum(body)}"


@asynccontextmanager
async def greeted_printer(firmware: str, greeting: bytes, tmp_path=None, protocol: str = "marlin"):
    """A printer in memory of `firmware` (an SD card in tmp_path/sd where given) and a RawPort
    on it that has read the board's `greeting`, up to its `echo:SD card ok`."""
    from fake_marlin.testing import memory_printer

    options: dict = {"firmware": firmware, "protocol": protocol}
    if tmp_path is not None:
        (tmp_path / "sd").mkdir()
        options["sd_dir"] = tmp_path / "sd"
    async with memory_printer(**options) as printer:
        port = RawPort(printer.open())
        assert await port.read_until(b"echo:SD card ok\n") == greeting
        yield port, printer
