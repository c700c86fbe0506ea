"""A host that speaks raw Marlin lines over an in-memory stream, for tests."""

import trio


class Terminal:
    def __init__(self, stream) -> None:
        self.stream = stream
        self._buffer = b""
        self.chunks: list[bytes] = []  # every read, to check what arrived together

    async def send(self, line: str) -> None:
        await self.stream.send_all(line.encode() + b"\n")

    async def read_line(self) -> str:
        while b"\n" not in self._buffer:
            chunk = await self.stream.receive_some(4096)
            self.chunks.append(chunk)
            self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\n", 1)
        return line.decode("ascii")

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

    async def quiet_for(self, seconds: float) -> list[str]:
        lines = []
        with trio.move_on_after(seconds):
            while True:
                lines.append(await self.read_line())
        return lines


def numbered(n: int, command: str) -> str:
    """`N<n> <command>*<checksum>` as hosts send it."""
    from fake_marlin.emulator.protocols.marlin import xor_checksum

    body = f"N{n} {command}"
    return f"{body}*{xor_checksum(body)}"
