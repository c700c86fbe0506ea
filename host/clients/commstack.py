"""The trio client for a Printrbot's CommStack: store a job on the printer's SD card, print it.

Uploading, as the ESP pushes a file (Printrhub's PushFileToSDCard): FileOpenForWrite (JSON with
the path, size and no compression), FileSetSize, FileSaveData in 128-byte chunks, one at a
time, FileClose. Then PrintProjectWithID with the path starts the print, and the client follows
it with M27 through RunPrinterGCode until the printer says it is done. The rules that make each
step happen exactly once are sans-IO, in fake_marlin.host.cores.commstack; this client carries
their requests to the endpoint and the replies back.
"""

import re
import struct
from collections.abc import Iterable
from pathlib import Path
from typing import TypeVar

import trio

from fake_marlin.host.cores import commstack
from fake_marlin.host.cores.commstack import CommStackEndpoint, CommStackStats, Reply, Steps
from fake_marlin.host.gcode_file import read_job
from fake_marlin.host.shell import (
    Client,
    ClientOptions,
    PrintSummary,
    ProgressCallback,
)
from fake_marlin.wire.commstack import Task
from fake_marlin.wire.gcode import strip_comment

POLL_INTERVAL = 1.0  # seconds between M27 while the printer prints the job
_SD_PROGRESS = re.compile(r"SD printing byte (\d+)/(\d+)")
T = TypeVar("T")


class CommStackClient(Client):
    protocol = "commstack"
    waits_for_greeting = False  # the MK20 greets nobody; the ESP starts asking at once
    check_command = staticmethod(commstack.check_command)

    def _open(self, options: ClientOptions) -> None:
        self._endpoint = CommStackEndpoint(options.timeout)

    @property
    def stats(self) -> CommStackStats:
        return self._endpoint.stats

    # -- the shell's hooks ------------------------------------------------------------------
    def _feed(self, data: bytes) -> None:
        self._endpoint.receive_data(data)
        self.corrupt_frames = self._endpoint.stats.corrupt_frames
        self._notify()  # an exchange may have ended
        self._sender_wake.set()  # the MK20's pings want answers

    def _poll(self, now: float) -> list[bytes]:
        return self._endpoint.poll(now)

    def _next_deadline(self) -> float | None:
        return self._endpoint.next_deadline()

    async def _run(self, steps: Steps[T]) -> T:
        """Carry a sans-IO procedure's requests to the printer, one at a time."""
        try:
            request = next(steps)
            while True:
                self.stats.resends += request.resend
                exchange = self._endpoint.start(request.task, request.data)
                self._sender_wake.set()
                await self._wait_until(lambda: exchange.outcome is not None)
                assert exchange.outcome is not None
                request = steps.send(Reply(exchange.outcome, exchange.answer))
        except StopIteration as done:
            result: T = done.value
            return result

    # -- the library API -----------------------------------------------------------------
    async def ping(self) -> int:
        answer = await self._run(
            commstack.request(Task.PING, struct.pack("<i", 1), self.options.max_transmissions)
        )
        return int(struct.unpack("<i", answer[:4].ljust(4, b"\0"))[0])

    async def send(self, command: str) -> tuple[str, ...]:
        """Run one command through RunPrinterGCode; returns what it printed."""
        return await self._run(commstack.run_gcode(command, self.options.max_transmissions))

    async def upload(
        self, name: str, content: bytes, progress: ProgressCallback | None = None
    ) -> None:
        """Store `content` on the SD card as `name`, exactly."""
        await self._run(commstack.upload(name, content, self.options.max_transmissions, progress))

    async def start_print(self, name: str) -> None:
        """Start printing `name` from the card, once."""
        await self._run(commstack.start_print(name, self.options.max_transmissions))

    async def wait_for_print(self, progress: ProgressCallback | None = None) -> None:
        """Until the printer reports no SD print; `progress` gets the bytes printed so far."""
        while True:
            status = " ".join(await self.send("M27"))
            match = _SD_PROGRESS.search(status)
            if match is None:
                return
            if progress is not None:
                progress(int(match[1]))
            await trio.sleep(POLL_INTERVAL)

    async def print_file(self, path: str, progress: ProgressCallback | None = None) -> PrintSummary:
        """Upload the file under its own name, print it, and return once the printer is done."""
        content = Path(path).read_bytes()
        commands = [command.text for command in read_job(path)]
        return await self._print(Path(path).name, content, len(commands), progress)

    async def print_commands(
        self, commands: Iterable[str], progress: ProgressCallback | None = None
    ) -> PrintSummary:
        commands = list(commands)
        content = "".join(command + "\n" for command in commands).encode("ascii")
        return await self._print("job.gcode", content, len(commands), progress)

    async def _print(
        self, name: str, content: bytes, count: int, progress: ProgressCallback | None
    ) -> PrintSummary:
        since = self._snapshot()
        await self.upload(name, content)
        await self.start_print(name)
        ends = _command_ends(content)

        def printed(position: int) -> None:
            if progress is not None:
                progress(sum(1 for end in ends if end <= position))

        await self.wait_for_print(printed)
        self.completed += count
        if progress is not None:
            progress(count)
        return self._summary(since, count)


def _command_ends(content: bytes) -> list[int]:
    """Where each command's line ends in the file: the SD position once it has been read."""
    ends, position = [], 0
    for raw in content.splitlines(keepends=True):
        position += len(raw)
        if strip_comment(raw.decode("ascii", "replace")):
            ends.append(position)
    return ends
