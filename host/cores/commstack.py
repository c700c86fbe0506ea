"""The ESP's end of CommStack, sans-IO: the exchange of one request at a time, and the rules
that store a file on the printer's card and print it exactly once.

`CommStackEndpoint` is the wire's state machine: one request in flight, its answer matched by task
(CommStack has no sequence numbers), and the MK20's own pings answered.

What an exchange can end in (Exchange.outcome):
- SUCCESS / FAILED: a ResponseSuccess / ResponseFailed for the task in flight. A ResponseFailed
  comes for a request whose data checksum was wrong (it did nothing), but also, from the MK20,
  for a frame it could not decode at all, under the task of the last good packet: it does not
  prove which request failed. So retrying a request that is not idempotent (file data) can store
  it twice; the client checks an upload's length at the end for that reason.
- TIMEOUT: no answer for `timeout` seconds. The request may have been lost, or its answer.

The rules above the exchange (`run_gcode`, `upload`, `start_print`) are generators: each yields
the next `Request` and is sent the `Reply` it got, so that the client only carries requests to
the endpoint and replies back, and a test can play the printer's part with no I/O at all.

Exactly once: neither a refusal nor silence says whether a chunk was stored. fake-marlin's MK20
says the file's length in its answers: after a refusal or a timeout the uploader asks (an empty
FileSaveData) and sends the chunk again only if it is not there. FileClose's answer gives the
final length; should it be wrong, or a printer not say, and a chunk go unanswered, the upload
starts over (FileOpenForWrite empties the file). A print request whose answer is lost is checked
with `M27 C` (which file is selected) before it is sent again.
"""

import json
import struct
from collections.abc import Callable, Generator
from dataclasses import dataclass
from enum import Enum, auto
from pathlib import PurePath
from typing import TypeVar

from fake_marlin.host.codecs.marlin import is_halt_message
from fake_marlin.host.errors import CommandError, PrinterHalted, PrinterNotResponding, UploadFailed
from fake_marlin.wire.commstack import (
    CHUNK_SIZE,
    MAX_DATA,
    CommType,
    FrameSplitter,
    Packet,
    Task,
    decode_frame,
    encode_packet,
)

BUILD_NUMBER = 1  # what this host answers the MK20's pings with, as the ESP answers its own
UPLOAD_ATTEMPTS = 3
REPORTS = frozenset({"M27", "M105", "M114", "M115", "M20", "M31"})  # harmless to ask twice


class Outcome(Enum):
    SUCCESS = auto()
    FAILED = auto()
    TIMEOUT = auto()


@dataclass(eq=False)
class Exchange:
    task: int
    data: bytes
    sent_at: float | None = None
    outcome: Outcome | None = None
    answer: bytes = b""


@dataclass
class CommStackStats:
    packets_sent: int = 0
    resends: int = 0
    timeouts: int = 0
    rejects: int = 0  # ResponseFailed answers
    corrupt_frames: int = 0
    unconfirmed: int = 0


class CommStackEndpoint:
    def __init__(self, timeout: float = 2.0) -> None:
        self.timeout = timeout
        self.stats = CommStackStats()
        self._frames = FrameSplitter(limit=1 << 16)
        self._current: Exchange | None = None
        self._answers: list[bytes] = []  # our responses to the printer's requests

    def start(self, task: int, data: bytes = b"") -> Exchange:
        if self._current is not None and self._current.outcome is None:
            raise RuntimeError("one CommStack request at a time")
        self._current = Exchange(task, data)
        return self._current

    def poll(self, now: float) -> list[bytes]:
        out, self._answers = self._answers, []
        current = self._current
        if current is None or current.outcome is not None:
            return out
        if current.sent_at is None:
            current.sent_at = now
            self.stats.packets_sent += 1
            out.append(encode_packet(Packet(current.task, CommType.REQUEST, current.data)))
        elif now >= current.sent_at + self.timeout:
            self.stats.timeouts += 1
            current.outcome = Outcome.TIMEOUT
        return out

    def next_deadline(self) -> float | None:
        current = self._current
        if current is None or current.outcome is not None or current.sent_at is None:
            return None
        return current.sent_at + self.timeout

    def receive_data(self, data: bytes) -> None:
        self._frames.receive_data(data)
        while (frame := self._frames.next_frame()) is not None:
            decoded = decode_frame(frame)
            if not isinstance(decoded, Packet):
                if frame:
                    self.stats.corrupt_frames += 1  # the ESP only logs these
                continue
            if decoded.comm_type == CommType.REQUEST:
                self._answer(decoded)
            else:
                self._settle(decoded)

    def _answer(self, request: Packet) -> None:
        data = struct.pack("<i", BUILD_NUMBER) if request.task == Task.PING else b""
        self._answers.append(encode_packet(Packet(request.task, CommType.RESPONSE_SUCCESS, data)))

    def _settle(self, response: Packet) -> None:
        current = self._current
        if current is None or current.outcome is not None or current.sent_at is None:
            return  # late: for an exchange that has timed out, or stray
        if response.task != current.task:
            return
        if response.comm_type == CommType.RESPONSE_SUCCESS:
            current.outcome = Outcome.SUCCESS
        else:
            self.stats.rejects += 1
            current.outcome = Outcome.FAILED
        current.answer = response.data


# -- the rules above the exchange ------------------------------------------------------------
@dataclass(frozen=True)
class Request:
    task: Task
    data: bytes = b""
    resend: bool = False  # the same request again (counted in the stats' resends)


@dataclass(frozen=True)
class Reply:
    outcome: Outcome
    answer: bytes = b""


T = TypeVar("T")
Steps = Generator[Request, Reply, T]


def check_command(command: str) -> str:
    """A line as it can stand in a file on the card: printable ASCII."""
    if not command or not all(" " <= char <= "~" for char in command):
        raise CommandError(f"{command!r}: a command is printable ASCII")
    return command


def request(
    task: Task, data: bytes, max_transmissions: int, retry_on_timeout: bool = True,
    refused: str | None = None,
) -> Steps[bytes]:
    """A request that may go again: until ResponseSuccess, or the retries run out. A
    ResponseFailed is retried too (it may have answered a damaged frame); `refused` says what
    it means when every try is refused. Returns the success's data."""
    reply = Reply(Outcome.TIMEOUT)
    for attempt in range(max_transmissions):
        reply = yield Request(task, data, resend=attempt > 0)
        if reply.outcome is Outcome.SUCCESS:
            return reply.answer
        if reply.outcome is Outcome.TIMEOUT and not retry_on_timeout:
            raise PrinterNotResponding(
                f"no answer to {task.name}; it may or may not have been carried out"
            )
    if reply.outcome is Outcome.FAILED and refused is not None:
        raise UploadFailed(refused)
    what = "refused" if reply.outcome is Outcome.FAILED else "unanswered"
    raise PrinterNotResponding(
        f"{task.name} {what} {max_transmissions} times; is a Printrbot (CommStack) on the port?"
    )


def run_gcode(command: str, max_transmissions: int) -> Steps[tuple[str, ...]]:
    """RunPrinterGCode: returns what the command printed. Only reports are asked again after
    silence: anything else may have run already."""
    check_command(command)
    answer = yield from request(
        Task.RUN_PRINTER_GCODE, command.encode("ascii") + b"\0", max_transmissions,
        retry_on_timeout=command.split()[0].upper() in REPORTS,
    )
    lines = tuple(answer.decode("latin-1").splitlines())
    for line in lines:
        if is_halt_message(line):
            raise PrinterHalted(f"the printer halted: {line}")
    return lines


def upload(
    name: str, content: bytes, max_transmissions: int,
    progress: Callable[[int], None] | None = None,
) -> Steps[None]:
    """Store `content` on the SD card as `name`, exactly; `progress` gets the bytes stored."""
    for _ in range(UPLOAD_ATTEMPTS):
        if (yield from _upload_once(name, content, max_transmissions, progress)):
            return
    raise UploadFailed(f"could not store {name} intact in {UPLOAD_ATTEMPTS} attempts")


def _upload_once(
    name: str, content: bytes, max_transmissions: int, progress: Callable[[int], None] | None
) -> Steps[bool]:
    header = {"localFilePath": name, "showUI": False, "fileSize": len(content), "compression": 1}
    opened = json.dumps(header).encode() + b"\0"
    if len(opened) > MAX_DATA:
        raise CommandError(f"the file name {name!r} is too long for FileOpenForWrite")
    yield from request(
        Task.FILE_OPEN_FOR_WRITE, opened, max_transmissions,
        refused=f"the printer cannot open {name} for writing (has it an SD card?)",
    )
    yield from request(Task.FILE_SET_SIZE, struct.pack("<I", len(content)), max_transmissions)
    for start in range(0, len(content), CHUNK_SIZE):
        chunk = content[start:start + CHUNK_SIZE]
        if not (yield from _store_chunk(chunk, start, max_transmissions)):
            return False
        if progress is not None:
            progress(start + len(chunk))
    length = stored_length(
        (yield from request(Task.FILE_CLOSE, b"", max_transmissions))
    )
    return length is None or length == len(content)


def _store_chunk(chunk: bytes, offset: int, max_transmissions: int) -> Steps[bool]:
    """Append `chunk` at `offset`, once; False if the file is not what it should be."""
    for attempt in range(max_transmissions):
        reply = yield Request(Task.FILE_SAVE_DATA, chunk, resend=attempt > 0)
        if reply.outcome is Outcome.SUCCESS:
            length = stored_length(reply.answer)
            if length is None or length == offset + len(chunk):
                return True
        else:
            # Refused (perhaps for another frame) or unanswered: was it stored?
            length = yield from _ask_length(max_transmissions)
            if length is None:  # a printer that does not say: only a refusal is safe to repeat
                if reply.outcome is Outcome.TIMEOUT:
                    return False
                continue
            if length == offset + len(chunk):
                return True
        if length != offset:
            return False  # neither before nor after this chunk: start over
    return False


def _ask_length(max_transmissions: int) -> Steps[int | None]:
    """The open file's length, asked with an empty FileSaveData (None: not told)."""
    for _ in range(max_transmissions):
        reply = yield Request(Task.FILE_SAVE_DATA, b"")
        if reply.outcome is Outcome.SUCCESS:
            return stored_length(reply.answer)
    raise PrinterNotResponding("no answer to FileSaveData; is a Printrbot on the port?")


def start_print(name: str, max_transmissions: int) -> Steps[None]:
    """PrintProjectWithID, once: a second would print the file again if the first already ran,
    so an answer that is not a success is checked with `M27 C` before the request goes again."""
    for attempt in range(max_transmissions):
        reply = yield Request(Task.PRINT_PROJECT_WITH_ID, name.encode() + b"\0", resend=attempt > 0)
        if reply.outcome is Outcome.SUCCESS:
            return
        selected = " ".join((yield from run_gcode("M27 C", max_transmissions)))
        if "Current file:" in selected and PurePath(name).name in selected.split():
            return
    raise UploadFailed(f"the printer would not print {name}")


def stored_length(answer: bytes) -> int | None:
    """The file length fake-marlin's MK20 puts in its answers (a real one sends nothing)."""
    return int(struct.unpack_from("<I", answer)[0]) if len(answer) >= 4 else None
