"""The trio client for a Printrbot's CommStack: store a job on the printer's SD card, print it.

Uploading, as the ESP pushes a file (Printrhub's PushFileToSDCard): FileOpenForWrite (JSON with
the path, size and no compression), FileSetSize, FileSaveData in chunks one at a time (the ESP's
128 bytes once the line has shown it carries them, down to 8 while it damages them), FileClose.
Then a Ping of the host's own (so that the MK20's pings stop, and any later one means it booted
again), and PrintProjectWithID with the path starts the print; the client follows it with M27
through RunPrinterGCode until the printer says it is done (`Not SD printing`; an answer that is
neither that nor its progress, such as a late answer to `M27 C` or one damaged past the
checksum, is asked again), and reports a ping since the Ping's answer as a restart. The rules
that make each step happen exactly once are sans-IO, in fake_marlin.host.cores.commstack; this
client carries their requests to the endpoint and the replies back, and keeps what they share
over the connection (a commstack.Connection).
"""

import math
import re
import struct
from collections.abc import Iterable
from pathlib import Path
from typing import TypeVar

import trio

from fake_marlin.host.cores import commstack
from fake_marlin.host.cores.commstack import (
    CommStackCore,
    CommStackStats,
    Connection,
    Result,
    Steps,
)
from fake_marlin.host.errors import PrinterNotResponding, PrinterReset
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
# A printer printing from its card runs each request after the command in hand, which may take
# minutes (a dwell, heating, a feed rate damaged past the checksum into F3): it is given up on
# only after this many long timeouts (the options') without an answer. The print goes on
# regardless of the host.
PRINT_PATIENCE = 3
_SD_PROGRESS = re.compile(r"SD printing byte (\d+)/(\d+)")
_SD_DONE = "Not SD printing"
# After "Not SD printing", how long to listen for the pings of a printer that restarted (the MK20
# says nothing else as it boots): three of its 5 s intervals, in case the first pings are lost.
BOOT_PINGS_WITHIN = 16.0
T = TypeVar("T")


class CommStackClient(Client):
    protocol = "commstack"
    waits_for_greeting = False  # the MK20 greets nobody; the ESP starts asking at once
    check_command = staticmethod(commstack.check_command)

    _core: CommStackCore

    def _open(self, options: ClientOptions) -> None:
        self._core = CommStackCore(options.timeout)
        self._connection = Connection()

    @property
    def stats(self) -> CommStackStats:
        return self._core.stats

    def _heard(self) -> None:
        self._notify()  # an exchange may have ended
        super()._heard()  # and the MK20's pings want answers

    async def _run(self, steps: Steps[T]) -> T:
        """Carry a sans-IO procedure's requests to the printer, one at a time."""
        try:
            request = next(steps)
            while True:
                self.stats.resends += request.resend
                exchange = self._core.start(request.task, request.data)
                self._sender_wake.set()
                await self._wait_until(lambda: exchange.outcome is not None)
                assert exchange.outcome is not None
                request = steps.send(Result(exchange.outcome, exchange.answer))
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
        await self._run(
            commstack.upload(
                name, content, self.options.max_transmissions, progress, self._connection
            )
        )

    async def start_print(self, name: str) -> None:
        """Start printing `name` from the card, once."""
        await self._run(
            commstack.start_print(
                name, self.options.max_transmissions, self._connection, self._patience()
            )
        )

    async def wait_for_print(self, progress: ProgressCallback | None = None) -> None:
        """Until the printer reports no SD print; `progress` gets the bytes printed so far.

        A printer that is printing may answer nothing for long (PRINT_PATIENCE)."""
        tries, patience = self.options.max_transmissions, self._patience()
        # Late M27 C answers first.
        await self._run(commstack.sync(self._connection, tries, patience))
        unclear = 0
        while True:
            status = " ".join(await self._run(commstack.run_gcode("M27", tries, patience)))
            if _SD_DONE in status:
                return
            match = _SD_PROGRESS.search(status)
            if match is not None:
                unclear = 0
                if progress is not None:
                    progress(int(match[1]))
            else:  # a late answer to another command, or one damaged past the checksum
                unclear += 1
                if unclear >= tries:
                    raise PrinterNotResponding(f"M27 answered {status!r}, {tries} times running")
            await trio.sleep(POLL_INTERVAL)

    def _patience(self) -> int:
        """Tries that may go unanswered while the printer is known to be busy (printing)."""
        return math.ceil(PRINT_PATIENCE * self.options.long_timeout / self.options.timeout)

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
        await self._run(
            commstack.store_and_print(
                name, content, self.options.max_transmissions, None, self._connection,
                self._patience(),
            )
        )
        ends = _command_ends(content)

        def printed(position: int) -> None:
            if progress is not None:
                progress(sum(1 for end in ends if end <= position))

        await self.wait_for_print(printed)
        # A print that stopped because the printer restarted also ends in "Not SD printing".
        # store_and_print's handshake made the MK20 stop pinging before the print began: a
        # ping since then is a boot, not a repeat of one whose answer was lost.
        with trio.move_on_after(BOOT_PINGS_WITHIN):
            await self._wait_until(lambda: self._core.printer_restarted)
        if self._core.printer_restarted:
            raise PrinterReset(
                "the printer restarted during the print (it pinged as it booted): what it had "
                "not printed yet is lost"
            )
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
