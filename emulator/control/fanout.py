"""One control socket for a farm spread over processes (--processes): the first process's, which
hands each request to the process serving the printer it names, over that process's own control
socket, and gives back its reply. A host's test suite sees one farm: the same requests and
replies as from one process serving every printer.
"""

import json
from collections.abc import Sequence
from dataclasses import dataclass

import trio

from fake_marlin.emulator.control.server import (
    MAX_REQUEST, OPS, ControlError, check_printer_number, check_request, unknown_op,
)


class ChildChannel:
    """A persistent connection to one process's control socket, one request at a time."""

    def __init__(self, path: str, numbers: Sequence[int]) -> None:
        self.path = path
        self.numbers = range(numbers[0], numbers[-1] + 1)
        self._stream: trio.SocketStream | None = None
        self._buffer = b""
        self._lock = trio.Lock()

    def _gone(self) -> ControlError:
        return ControlError(f"the process serving printers {self.numbers[0]} to "
                            f"{self.numbers[-1]} is gone")

    async def ask(self, request: dict) -> object:
        """The result of `request` in that process (ControlError with its error if refused)."""
        async with self._lock:
            try:
                if self._stream is None:
                    self._stream = await trio.open_unix_socket(self.path)
                await self._stream.send_all(json.dumps(request).encode() + b"\n")
                line = await self._line()
            except (OSError, trio.BrokenResourceError, trio.ClosedResourceError):
                self._stream = None
                raise self._gone() from None
        reply = json.loads(line)
        if not reply.get("ok"):
            raise ControlError(reply.get("error", "refused"))
        return reply.get("result")

    async def _line(self) -> bytes:
        assert self._stream is not None
        while b"\n" not in self._buffer:
            data = await self._stream.receive_some(MAX_REQUEST)
            if not data:
                raise trio.BrokenResourceError
            self._buffer += data
        line, self._buffer = self._buffer.split(b"\n", 1)
        return line

    async def aclose(self) -> None:
        if self._stream is not None:
            await self._stream.aclose()
            self._stream = None


@dataclass
class FanOut:
    """A Controller's handle() for the whole farm, over its processes' channels (in order)."""

    channels: list[ChildChannel]

    @property
    def first(self) -> int:
        return self.channels[0].numbers[0]

    @property
    def last(self) -> int:
        return self.channels[-1].numbers[-1]

    async def handle(self, request: object) -> object:
        check_request(request)
        assert isinstance(request, dict)
        op = request["op"]
        if op not in OPS:
            raise ControlError(unknown_op(op))
        if op == "printers":
            return await self.gather(request)
        number = request.get("printer")
        check_printer_number(number, self.first, self.last)
        assert isinstance(number, int)
        return await self.channel(number).ask(request)

    async def gather(self, request: dict) -> list:
        """A request of every printer (its answer a list): each process's answer, in order."""
        found: list = []
        for channel in self.channels:
            part = await channel.ask(request)
            assert isinstance(part, list)
            found += part
        return found

    def channel(self, number: int) -> ChildChannel:
        for channel in self.channels:
            if number in channel.numbers:
                return channel
        raise ControlError(f"no printer {number}")  # numbers are contiguous: cannot happen

    def farm_source(self) -> "RemoteFarm":
        return RemoteFarm(self)

    async def aclose(self) -> None:
        for channel in self.channels:
            await channel.aclose()


@dataclass
class RemoteFarm:
    """The live view's FarmSource (web/source.py) for a farm over processes: each process's
    rows and details, asked over its control channel (ops web_rows and web_detail)."""

    fanout: FanOut

    async def rows(self) -> list[dict]:
        return await self.fanout.gather({"op": "web_rows"})

    async def detail(self, number: int) -> dict | None:
        if not self.fanout.first <= number <= self.fanout.last:
            return None
        found = await self.fanout.channel(number).ask({"op": "web_detail", "printer": number})
        assert found is None or isinstance(found, dict)
        return found
