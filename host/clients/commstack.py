"""The trio client for a Printrbot's CommStack: store a job on the printer's SD card, print it.

Uploading, as the ESP pushes a file (Printrhub's PushFileToSDCard): FileOpenForWrite (JSON with
the path, size and no compression), FileSetSize, FileSaveData in 128-byte chunks, one at a
time, FileClose. Then PrintProjectWithID with the path starts the print, and the client follows
it with M27 through RunPrinterGCode until the printer says it is done.

Exactly once: CommStack has no sequence numbers, and a ResponseFailed may answer another frame
(the MK20 answers an undecodable one under the last task), so neither a refusal nor silence says
whether a chunk was stored. fake-marlin's MK20 says the file's length in its answers: after a
refusal or a timeout the client asks (an empty FileSaveData) and sends the chunk again only if
it is not there. FileClose's answer gives the final length; should it be wrong, or a printer not
say, and a chunk go unanswered, the upload starts over (FileOpenForWrite empties the file).
"""

import json
import math
import re
import struct
from collections.abc import Callable, Iterable
from pathlib import Path

import trio

from fake_marlin.host.shell import ByteStream, ClientOptions, PrintSummary
from fake_marlin.host.codecs import marlin
from fake_marlin.host.cores.commstack import CommStackEndpoint, Outcome
from fake_marlin.host.errors import CommandError, PrinterHalted, PrinterNotResponding, RemoteError
from fake_marlin.host.gcode_file import read_job
from fake_marlin.wire.commstack import CHUNK_SIZE, MAX_DATA, Task
from fake_marlin.wire.gcode import strip_comment

UPLOAD_ATTEMPTS = 3
POLL_INTERVAL = 1.0  # seconds between M27 while the printer prints the job
REPORTS = frozenset({"M27", "M105", "M114", "M115", "M20", "M31"})  # harmless to ask twice
_SD_PROGRESS = re.compile(r"SD printing byte (\d+)/(\d+)")


class UploadFailed(RemoteError):
    pass


def check_command(command: str) -> str:
    """A line as it can stand in a file on the card: printable ASCII."""
    if not command or not all(" " <= char <= "~" for char in command):
        raise CommandError(f"{command!r}: a command is printable ASCII")
    return command


class CommStackClient:
    protocol = "commstack"
    check_command = staticmethod(check_command)

    def __init__(self, stream: ByteStream, options: ClientOptions = ClientOptions(), on_line=None) -> None:
        self._stream = stream
        self.options = options
        self._endpoint = CommStackEndpoint(options.timeout)
        self._changed = trio.Event()
        self._timer_wake = trio.Event()
        self._send_lock = trio.Lock()
        self.failure = None
        self.completed = 0

    @property
    def stats(self):
        return self._endpoint.stats

    # -- the background task ---------------------------------------------------------------
    async def run(self, cancel_scope: trio.CancelScope) -> None:
        async with trio.open_nursery() as nursery:
            nursery.start_soon(self._read_loop)
            nursery.start_soon(self._timer_loop)

    async def _read_loop(self) -> None:
        while True:
            self._endpoint.receive_data(await self._stream.receive_some(4096))
            await self._flush()
            self._wake()

    async def _timer_loop(self) -> None:
        while True:
            wake = self._timer_wake = trio.Event()
            deadline = self._endpoint.next_deadline()
            with trio.move_on_at(math.inf if deadline is None else deadline):
                await wake.wait()
            await self._flush()
            self._wake()

    async def _flush(self) -> None:
        async with self._send_lock:
            for data in self._endpoint.poll(trio.current_time()):
                await self._stream.send_all(data)

    def _wake(self) -> None:
        self._changed.set()
        self._changed = trio.Event()

    # -- one request ---------------------------------------------------------------------
    async def _exchange(self, task: Task, data: bytes = b"") -> tuple[Outcome, bytes]:
        exchange = self._endpoint.start(task, data)
        await self._flush()
        self._timer_wake.set()
        while exchange.outcome is None:
            await self._changed.wait()
        return exchange.outcome, exchange.answer

    async def _request(
        self, task: Task, data: bytes = b"", retry_on_timeout: bool = True, refused: str | None = None
    ) -> bytes:
        """A request that may go again: until ResponseSuccess, or the retries run out. A
        ResponseFailed is retried too (it may have answered a damaged frame); `refused` says
        what it means when every try is refused."""
        outcome = None
        for attempt in range(self.options.max_transmissions):
            self.stats.resends += attempt > 0
            outcome, answer = await self._exchange(task, data)
            if outcome is Outcome.SUCCESS:
                return answer
            if outcome is Outcome.TIMEOUT and not retry_on_timeout:
                raise PrinterNotResponding(
                    f"no answer to {task.name}; it may or may not have been carried out"
                )
        if outcome is Outcome.FAILED and refused is not None:
            raise UploadFailed(refused)
        what = "refused" if outcome is Outcome.FAILED else "unanswered"
        raise PrinterNotResponding(
            f"{task.name} {what} {self.options.max_transmissions} times; "
            "is a Printrbot (CommStack) on the port?"
        )

    # -- the library API -----------------------------------------------------------------
    async def ping(self) -> int:
        answer = await self._request(Task.PING, struct.pack("<i", 1))
        return struct.unpack("<i", answer[:4].ljust(4, b"\0"))[0]

    async def send(self, command: str) -> tuple[str, ...]:
        """Run one command through RunPrinterGCode; returns what it printed."""
        self.check_command(command)
        answer = await self._request(
            Task.RUN_PRINTER_GCODE, command.encode("ascii") + b"\0",
            retry_on_timeout=command.split()[0].upper() in REPORTS,
        )
        lines = tuple(answer.decode("latin-1").splitlines())
        for line in lines:
            if marlin.is_halt_message(line):
                raise PrinterHalted(f"the printer halted: {line}")
        return lines

    async def upload(self, name: str, content: bytes, progress: Callable[[int], None] | None = None) -> None:
        """Store `content` on the SD card as `name`, exactly."""
        for _ in range(UPLOAD_ATTEMPTS):
            if await self._upload_once(name, content, progress):
                return
        raise UploadFailed(f"could not store {name} intact in {UPLOAD_ATTEMPTS} attempts")

    async def _upload_once(self, name: str, content: bytes, progress) -> bool:
        header = {"localFilePath": name, "showUI": False, "fileSize": len(content), "compression": 1}
        opened = json.dumps(header).encode() + b"\0"
        if len(opened) > MAX_DATA:
            raise CommandError(f"the file name {name!r} is too long for FileOpenForWrite")
        await self._request(
            Task.FILE_OPEN_FOR_WRITE, opened,
            refused=f"the printer cannot open {name} for writing (has it an SD card?)",
        )
        await self._request(Task.FILE_SET_SIZE, struct.pack("<I", len(content)))
        for start in range(0, len(content), CHUNK_SIZE):
            chunk = content[start:start + CHUNK_SIZE]
            if not await self._store_chunk(chunk, start):
                return False
            if progress is not None:
                progress(start + len(chunk))
        length = _length(await self._request(Task.FILE_CLOSE))
        return length is None or length == len(content)

    async def _store_chunk(self, chunk: bytes, offset: int) -> bool:
        """Append `chunk` at `offset`, once; False if the file is not what it should be."""
        for attempt in range(self.options.max_transmissions):
            self.stats.resends += attempt > 0
            outcome, answer = await self._exchange(Task.FILE_SAVE_DATA, chunk)
            if outcome is Outcome.SUCCESS:
                length = _length(answer)
                if length is None or length == offset + len(chunk):
                    return True
            else:
                # Refused (perhaps for another frame) or unanswered: was it stored?
                length = await self._stored_length()
                if length is None:  # a printer that does not say: only a refusal is safe to repeat
                    if outcome is Outcome.TIMEOUT:
                        return False
                    continue
                if length == offset + len(chunk):
                    return True
            if length != offset:
                return False  # neither before nor after this chunk: start over
        return False

    async def _stored_length(self) -> int | None:
        """The open file's length, asked with an empty FileSaveData (None: not told)."""
        for _ in range(self.options.max_transmissions):
            outcome, answer = await self._exchange(Task.FILE_SAVE_DATA, b"")
            if outcome is Outcome.SUCCESS:
                return _length(answer)
        raise PrinterNotResponding("no answer to FileSaveData; is a Printrbot on the port?")

    async def start_print(self, name: str) -> None:
        """PrintProjectWithID, once: a second would print the file again if the first already
        ran, so an answer that is not a success is checked with `M27 C` (which file is selected)
        before the request goes again."""
        for attempt in range(self.options.max_transmissions):
            self.stats.resends += attempt > 0
            outcome, _ = await self._exchange(Task.PRINT_PROJECT_WITH_ID, name.encode() + b"\0")
            if outcome is Outcome.SUCCESS:
                return
            selected = " ".join(await self.send("M27 C"))
            if "Current file:" in selected and Path(name).name in selected.split():
                return
        raise UploadFailed(f"the printer would not print {name}")

    async def wait_for_print(self, progress: Callable[[int], None] | None = None) -> None:
        """Until the printer reports no SD print; `progress` gets the bytes printed so far."""
        while True:
            status = " ".join(await self.send("M27"))
            match = _SD_PROGRESS.search(status)
            if match is None:
                return
            if progress is not None:
                progress(int(match[1]))
            await trio.sleep(POLL_INTERVAL)

    async def print_file(self, path: str, progress: Callable[[int], None] | None = None) -> PrintSummary:
        """Upload the file under its own name, print it, and return once the printer is done."""
        content = Path(path).read_bytes()
        commands = [command.text for command in read_job(path)]
        ends = _command_ends(content)
        return await self._print(Path(path).name, content, len(commands), ends, progress)

    async def print_commands(
        self, commands: Iterable[str], progress: Callable[[int], None] | None = None
    ) -> PrintSummary:
        commands = list(commands)
        content = "".join(command + "\n" for command in commands).encode("ascii")
        return await self._print("job.gcode", content, len(commands), _command_ends(content), progress)

    async def _print(self, name, content, count, ends, progress) -> PrintSummary:
        start = trio.current_time()
        before = self.stats.__dict__.copy()
        await self.upload(name, content)
        await self.start_print(name)

        def printed(position: int) -> None:
            done = sum(1 for end in ends if end <= position)
            if progress is not None:
                progress(done)

        await self.wait_for_print(printed)
        self.completed += count
        if progress is not None:
            progress(count)
        after = self.stats.__dict__
        return PrintSummary(
            commands=count,
            **{key: after[key] - before[key] for key in ("packets_sent", "resends", "timeouts", "rejects", "corrupt_frames", "unconfirmed")},
            elapsed=trio.current_time() - start,
        )


def _length(answer: bytes) -> int | None:
    """The file length fake-marlin's MK20 puts in its answers (a real one sends nothing)."""
    return struct.unpack_from("<I", answer)[0] if len(answer) >= 4 else None


def _command_ends(content: bytes) -> list[int]:
    """Where each command's line ends in the file: the SD position once it has been read."""
    ends, position = [], 0
    for raw in content.splitlines(keepends=True):
        position += len(raw)
        if strip_comment(raw.decode("ascii", "replace")):
            ends.append(position)
    return ends
