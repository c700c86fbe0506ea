"""The ESP's end of CommStack, sans-IO: the exchange of one request at a time, and the rules
that store a file on the printer's card and print it exactly once.

`CommStackCore` is the wire's state machine: one request in flight, its answer matched by task
(CommStack has no sequence numbers), and the MK20's own pings answered.

What an exchange can end in (Exchange.outcome):
- SUCCESS / FAILED: a ResponseSuccess / ResponseFailed for the task in flight. A ResponseFailed
  comes for a request whose data checksum was wrong (it did nothing), but also, from the MK20,
  for a frame it could not decode at all, under the task of the last frame it read: it does not
  prove which request failed. And a success may be the late answer to an earlier request of
  the same task, one whose exchange timed out.
- TIMEOUT: no answer for `timeout` seconds. The request may have been lost, or its answer.

The rules above the exchange (`run_gcode`, `upload`, `start_print`) are generators: each yields
the next `Request` and is sent the `Result` it got, so that the client only carries requests to
the endpoint and replies back, and a test can play the printer's part with no I/O at all.

Fresh answers. The line keeps order and the MK20 answers its requests in turn, so once the
answer to a request has come, every answer to anything sent before it has come too, or never
will. `sync` makes such a request that no other answer can be mistaken for: one under a task
ID no firmware uses (0x40 and up, a new one each time), which the MK20 answers, as any request
it has no handler for, with an empty ResponseSuccess under the same ID. After it, the next
answer to a task is the answer to the request sent after the sync.

Exactly once: neither a refusal nor silence says whether a chunk was stored. fake-marlin's MK20
says the file's length in its answers (FileSaveData's and FileClose's), so each chunk is stored
on its own: a success that gives the length the chunk makes is its answer; anything else (a
refusal, silence, a success with an older length) is settled by a sync and then the file's
length (an empty FileSaveData): the chunk is there, or is sent again, or the file is neither
(it is wrong). Only a file that is wrong starts the upload over (FileOpenForWrite empties it),
and only the same place going wrong UPLOAD_ATTEMPTS times gives up. Retries are counted per
chunk: only a printer that stops answering, or that stores none of `max_transmissions` chunks
of the smallest size, makes an upload attempt end. With a printer that does not say the
length, a refused chunk is sent again and an unanswered one starts the upload over.

Chunk sizes (the ESP always sends 128 bytes; the MK20 stores whatever length comes). Every byte
in a frame adds to the chance that it is damaged, and to the chance that two flips of one bit
position cancel out in the MK20's byte sum and pass unseen (at 1e-3 per bit, about 1 in 40
of the 128-byte chunks that are accepted; 1 in 3000 of 8-byte ones). So chunks start at
MIN_CHUNK, double after GROW_AFTER bytes stored at the first try, up to CHUNK_SIZE, and fall to
MIN_CHUNK again whenever one is damaged on its way (a lost answer says nothing of that way).
Until they are back at CHUNK_SIZE a line end goes in a chunk of its own (`Connection.next_chunk`).

A print request that is not answered with a success is checked with `M27 C` (which file is
selected), after a sync, before it is sent again. A file the printer will not print is stored
again (`store_and_print`).

Restarts. The MK20 says nothing as it boots but its pings, which it repeats every 5 s until it
hears from the ESP: a ping may be a boot, or a repeat of one whose answer the line lost. Once
the MK20 has answered a Ping of ours (`handshake`, before the print request) it pings no more
until it boots again, so a ping after that answer is a restart
(`CommStackCore.printer_restarted`).
"""

import itertools
import json
import struct
from collections import Counter
from collections.abc import Callable, Generator, Iterable
from dataclasses import dataclass
from enum import Enum, auto
from pathlib import PurePath
from typing import TypeVar

from fake_marlin.host.codecs.marlin import is_halt_message
from fake_marlin.host.errors import CommandError, PrinterHalted, PrinterNotResponding, UploadFailed
from fake_marlin.wire.commstack import (
    BUFFER_SIZE,
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
UPLOAD_ATTEMPTS = 3  # times the file may prove wrong at one place before the upload gives up
MIN_CHUNK = 8  # the smallest FileSaveData chunk, and the first (the MK20 stores any length)
GROW_AFTER = 512  # bytes stored at the first try, running, before the chunk size doubles
OPEN_TRIES = 3  # times max_transmissions: FileOpenForWrite's JSON is the longest request
LENGTH_TRIES = 4  # times max_transmissions: asking the file's length, once a sync is answered
SYNC_TASKS = range(0x40, 0x100)  # task IDs no firmware uses: the MK20 answers them success
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


def _frame_after_a_cut(frame: bytes) -> Packet | None:
    """The whole frame at the end of a block that would not decode, if there is one.

    A frame cut short on the line loses its closing 0x00, so the next frame's bytes join it
    in one block and that frame is lost with it: a printer whose every other answer was cut
    would seem to answer none. A whole frame that follows a cut starts at some byte of the
    block and runs to its end; one whose header and data checksums both hold is taken.
    """
    # A whole frame is at most BUFFER_SIZE encoded bytes: only the block's tail can hold one
    # (a long run of noise costs one look per byte of that tail, not per byte of the block).
    for start in range(max(1, len(frame) - BUFFER_SIZE), len(frame)):
        decoded = decode_frame(frame[start:])
        if isinstance(decoded, Packet):
            return decoded
    return None


class CommStackCore:
    def __init__(self, timeout: float = 2.0) -> None:
        self.timeout = timeout
        self.stats = CommStackStats()
        self._frames = FrameSplitter(limit=1 << 16)
        self._current: Exchange | None = None
        self._answers: list[bytes] = []  # our responses to the printer's requests
        # The MK20's pings: it sends them from its boot on, every 5 s, until it hears from the
        # ESP (an answer to one, or a Ping of the ESP's own: Application::loop's `_espOK`). So
        # a ping may repeat one whose answer was lost on the line; only a ping that comes after
        # the MK20 has answered a Ping of ours (the handshake) says it booted again.
        self.printer_pings = 0
        self._pings_since_handshake: int | None = None  # None: no Ping of ours answered yet

    # The MK20 greets nobody, states no room, and prints no lines for the caller: what it says
    # comes in the answers of the exchanges.
    greeted = False
    room: int | None = None

    @property
    def corrupt_frames(self) -> int:
        return self.stats.corrupt_frames

    @property
    def printer_restarted(self) -> bool:
        """The MK20 has pinged since it last answered a Ping of ours: it has booted since.
        (The line keeps order, and the MK20 sets `_espOK` before it answers: a ping it sent
        before it handled our Ping comes before the answer.)"""
        return bool(self._pings_since_handshake)

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

    def next_event(self) -> None:
        """Nothing for the caller: receive_data() has handled the bytes already."""
        return None

    def receive_data(self, data: bytes, now: float) -> None:
        """The printer's bytes: its answers settle the exchange in flight, and its requests
        (pings) are answered at the next poll(). The time they came plays no part."""
        self._frames.receive_data(data)
        while (frame := self._frames.next_frame()) is not None:
            decoded = decode_frame(frame)
            if not isinstance(decoded, Packet):
                if not frame:
                    continue
                self.stats.corrupt_frames += 1  # the ESP only logs these
                recovered = _frame_after_a_cut(frame)
                if recovered is None:
                    continue
                decoded = recovered
            if decoded.comm_type == CommType.REQUEST:
                self._answer(decoded)
            else:
                self._settle(decoded)

    def _answer(self, request: Packet) -> None:
        if request.task == Task.PING:
            self.printer_pings += 1
            if self._pings_since_handshake is not None:
                self._pings_since_handshake += 1
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
            if current.task == Task.PING:
                self._pings_since_handshake = 0  # the MK20 has heard us: it pings no more
        else:
            self.stats.rejects += 1
            current.outcome = Outcome.FAILED
        current.answer = response.data


# -- the rules above the exchange ------------------------------------------------------------
@dataclass(frozen=True)
class Request:
    task: int  # a Task, or a sync task ID
    data: bytes = b""
    resend: bool = False  # data sent again (counted in the stats' resends)


@dataclass(frozen=True)
class Result:
    outcome: Outcome
    answer: bytes = b""


T = TypeVar("T")
Steps = Generator[Request, Result, T]


class Connection:
    """What the rules share over one connection: the sync task IDs handed out, and the chunk
    size the line has allowed lately."""

    def __init__(self) -> None:
        self._syncs = itertools.cycle(SYNC_TASKS)
        self.chunk_size = MIN_CHUNK  # until the line has shown it carries more
        self._clean = 0  # bytes stored at the first try since the size last changed

    def next_sync_task(self) -> int:
        return next(self._syncs)

    @property
    def noisy(self) -> bool:
        """The line has lately damaged a chunk (or has not yet shown that it does not)."""
        return self.chunk_size < CHUNK_SIZE

    def next_chunk(self, content: bytes, offset: int) -> bytes:
        """What to send of `content` from `offset`. On a noisy line a line end goes alone:
        the two flips in one frame that the MK20's byte sum misses can change a command's
        characters, but not a 1-byte chunk (that takes three, in the data and both sums), so
        damage past the checksums never joins two commands into one."""
        chunk = content[offset:offset + self.chunk_size]
        if self.noisy:
            end = chunk.find(b"\n")
            if end >= 0:
                chunk = chunk[:max(end, 1)]
        return chunk

    def chunk_stored(self, length: int, at_first_try: bool) -> None:
        if not at_first_try:
            return  # its answer was lost: that says nothing of the way to the printer
        self._clean += length
        if self._clean >= GROW_AFTER and self.chunk_size < CHUNK_SIZE:
            self.chunk_size = min(CHUNK_SIZE, self.chunk_size * 2)
            self._clean = 0

    def chunk_missed(self) -> None:
        """A chunk was damaged on its way: the smallest again, as every byte in a frame adds
        to the chance that two flips pass the byte sum."""
        self.chunk_size = MIN_CHUNK
        self._clean = 0


def check_command(command: str) -> str:
    """A line as it can stand in a file on the card: printable ASCII."""
    if not command or not all(" " <= char <= "~" for char in command):
        raise CommandError(f"{command!r}: a command is printable ASCII")
    return command


def request(
    task: Task, data: bytes, max_transmissions: int, retry_on_timeout: bool = True,
    refused: str | None = None, patience: int | None = None,
) -> Steps[bytes]:
    """A request that may go again: until ResponseSuccess, or the retries run out. A
    ResponseFailed is retried too (it may have answered a damaged frame); `refused` says what
    it means when every try is refused. `patience` is how many tries in all may go by, for a
    printer that may be busy for long (one that is printing runs each request after the
    command in hand, however long that takes); refusals still give up after
    `max_transmissions` running. Returns the success's data."""
    tries = max_transmissions if patience is None else max(patience, max_transmissions)
    result = Result(Outcome.TIMEOUT)
    refusals = 0
    for attempt in range(tries):
        result = yield Request(task, data, resend=attempt > 0)
        if result.outcome is Outcome.SUCCESS:
            return result.answer
        if result.outcome is Outcome.TIMEOUT and not retry_on_timeout:
            raise PrinterNotResponding(
                f"no answer to {task.name}; it may or may not have been carried out"
            )
        refusals = refusals + 1 if result.outcome is Outcome.FAILED else 0
        if refusals >= max_transmissions:
            break
    if result.outcome is Outcome.FAILED and refused is not None:
        raise UploadFailed(refused)
    what = "refused" if result.outcome is Outcome.FAILED else "unanswered"
    count = refusals if result.outcome is Outcome.FAILED else tries
    raise PrinterNotResponding(
        f"{task.name} {what} {count} times; is a Printrbot (CommStack) on the port?"
    )


def sync(
    connection: Connection, max_transmissions: int, patience: int | None = None
) -> Steps[None]:
    """Until the printer has answered everything sent before (see the module's docstring)."""
    tries = max_transmissions if patience is None else max(patience, max_transmissions)
    refusals = 0
    for _ in range(tries):
        result = yield Request(connection.next_sync_task())
        if result.outcome is Outcome.SUCCESS:
            return
        refusals = refusals + 1 if result.outcome is Outcome.FAILED else 0
        if refusals >= max_transmissions:
            break
    raise PrinterNotResponding(
        f"no request answered in {tries} tries; is a Printrbot (CommStack) on the port?"
    )


def handshake(max_transmissions: int, patience: int | None = None) -> Steps[None]:
    """A Ping of our own, until the MK20 answers it. Handling it sets `_espOK` (mk20
    Application::runTask), which stops the MK20's pings until it boots again: from the answer
    on, a ping from the printer says it restarted (CommStackCore.printer_restarted). Before
    it, a ping may repeat one whose answer the line lost. Harmless to repeat."""
    yield from request(
        Task.PING, struct.pack("<i", BUILD_NUMBER), max_transmissions, patience=patience
    )


def run_gcode(
    command: str, max_transmissions: int, patience: int | None = None
) -> Steps[tuple[str, ...]]:
    """RunPrinterGCode: returns what the command printed. Only reports are asked again after
    silence: anything else may have run already."""
    check_command(command)
    answer = yield from request(
        Task.RUN_PRINTER_GCODE, command.encode("ascii") + b"\0", max_transmissions,
        retry_on_timeout=command.split()[0].upper() in REPORTS, patience=patience,
    )
    lines = tuple(answer.decode("latin-1").splitlines())
    check_halt(lines)
    return lines


def check_halt(lines: Iterable[str]) -> None:
    """PrinterHalted if the printer's output says it has halted."""
    for line in lines:
        if is_halt_message(line):
            raise PrinterHalted(f"the printer halted: {line}")


def upload(
    name: str, content: bytes, max_transmissions: int,
    progress: Callable[[int], None] | None = None, connection: Connection | None = None,
) -> Steps[None]:
    """Store `content` on the SD card as `name`, exactly; `progress` gets the bytes stored."""
    connection = Connection() if connection is None else connection
    header = {"localFilePath": name, "showUI": False, "fileSize": len(content), "compression": 1}
    opened = json.dumps(header, separators=(",", ":")).encode() + b"\0"
    if len(opened) > MAX_DATA:
        raise CommandError(f"the file name {name!r} is too long for FileOpenForWrite")
    went_wrong: Counter[int] = Counter()
    while True:
        wrong = yield from _upload_once(
            name, opened, content, connection, max_transmissions, progress
        )
        if wrong is None:
            return
        where, why = wrong
        went_wrong[where] += 1
        if went_wrong[where] >= UPLOAD_ATTEMPTS:
            raise UploadFailed(
                f"could not store {name} intact in {UPLOAD_ATTEMPTS} attempts: at byte {where}"
                f" {why}"
            )


Wrong = tuple[int, str]  # where the file on the card went wrong, and how


def _upload_once(
    name: str, opened: bytes, content: bytes, connection: Connection, max_transmissions: int,
    progress: Callable[[int], None] | None,
) -> Steps[Wrong | None]:
    """One upload from an empty file: None once the file is `content`."""
    yield from request(  # harmless to repeat: no data has gone yet
        Task.FILE_OPEN_FOR_WRITE, opened, OPEN_TRIES * max_transmissions,
        refused=f"the printer cannot open {name} for writing (has it an SD card?)",
    )
    yield from request(Task.FILE_SET_SIZE, struct.pack("<I", len(content)), max_transmissions)
    offset = 0
    while offset < len(content):
        stored = yield from _store_chunk(content, offset, connection, max_transmissions)
        if isinstance(stored, tuple):
            return stored
        offset += stored
        if progress is not None:
            progress(offset)
    length = stored_length((yield from request(Task.FILE_CLOSE, b"", max_transmissions)))
    # FileClose is answered alike however often it comes: its answer is never out of date.
    if length is not None and length != len(content):
        return len(content), f"the printer closed a file of {length} bytes"
    return None


def _store_chunk(
    content: bytes, offset: int, connection: Connection, max_transmissions: int
) -> Steps[int | Wrong]:
    """Append the next chunk of `content` to the file, which holds `offset` bytes and has no
    data on the way to it, once. Returns how many bytes were stored, or how the file went
    wrong: it holds neither `offset` bytes nor those and the chunk; a printer that does not
    say the length left the chunk unanswered; or not even the smallest chunk is stored in
    `max_transmissions` tries (a card taken out, a file opened for something else: the
    upload starts over, which a printer that refuses all data soon gives up)."""
    tries_at_smallest = 0
    missed = False
    while True:
        chunk = connection.next_chunk(content, offset)
        end = offset + len(chunk)
        tries_at_smallest += len(chunk) <= MIN_CHUNK
        result = yield Request(Task.FILE_SAVE_DATA, chunk, resend=missed)
        if result.outcome is Outcome.SUCCESS:
            length = stored_length(result.answer)
            if length is None or length == end:  # the chunk's own answer
                connection.chunk_stored(len(chunk), at_first_try=not missed)
                return len(chunk)
            if length > offset:
                return offset, f"the file held {length} bytes"
            # An older length: a late answer to an earlier request. This one's is to come.
        length = yield from _length_now(connection, max_transmissions)
        if length is None:  # a printer that does not say: only a refusal is safe to repeat
            if result.outcome is not Outcome.FAILED:
                return offset, "a chunk went unanswered and the printer does not say the length"
        elif length == end:
            connection.chunk_stored(len(chunk), at_first_try=False)
            return len(chunk)
        elif length != offset:
            return offset, f"the file held {length} bytes"
        missed = True
        connection.chunk_missed()
        if tries_at_smallest >= max_transmissions:
            return offset, (
                f"the printer stored none of {max_transmissions} chunks of {MIN_CHUNK} bytes"
            )


def _length_now(connection: Connection, max_transmissions: int) -> Steps[int | None]:
    """The open file's length once everything sent before has been carried out (None: the
    printer does not say): a sync, then an empty FileSaveData. Asking again is safe, as no
    data is on the way: any answer to it is the same."""
    yield from sync(connection, max_transmissions)
    # The sync was answered: the printer is there, and this question is safe to repeat, so
    # ask longer than for a request that could not be. Each answer cut short also takes the
    # next with it (the bytes left without their 0x00 spoil the frame after them), so at a
    # few percent of damaged frames eight tries in a row can all be lost.
    for _ in range(LENGTH_TRIES * max_transmissions):
        result = yield Request(Task.FILE_SAVE_DATA, b"")
        if result.outcome is Outcome.SUCCESS:
            return stored_length(result.answer)
    raise PrinterNotResponding("no answer to FileSaveData; is a Printrbot on the port?")


def start_print(
    name: str,
    max_transmissions: int,
    connection: Connection | None = None,
    patience: int | None = None,
) -> Steps[None]:
    """PrintProjectWithID, once: a second would print the file again if the first already ran,
    so an answer that is not a success is checked with `M27 C`, after a sync (the request has
    been carried out by then, if it ever will be), before the request goes again. The print
    may have begun, and the printer be busy with its first command: `patience` (as for
    `request`) for the sync and the check."""
    if not (yield from _start_print(name, max_transmissions, connection, patience)):
        raise UploadFailed(f"the printer would not print {name}")


def store_and_print(
    name: str, content: bytes, max_transmissions: int,
    progress: Callable[[int], None] | None = None, connection: Connection | None = None,
    patience: int | None = None,
) -> Steps[None]:
    """`upload`, then `start_print`; a file the printer will not print is stored again (a name
    damaged past the checksum in FileOpenForWrite stores the job under another name), up to
    UPLOAD_ATTEMPTS times.

    Before the first print request, a `handshake`: from then on a ping from the printer says it
    restarted, and one that restarts during the print can be told from one that merely repeats
    a ping whose answer was lost. Only before the first: a print request whose answer is lost
    may have started the print, and a restart after it must still show."""
    connection = Connection() if connection is None else connection
    for attempt in range(UPLOAD_ATTEMPTS):
        yield from upload(name, content, max_transmissions, progress, connection)
        if attempt == 0:
            yield from handshake(max_transmissions, patience)
        if (yield from _start_print(name, max_transmissions, connection, patience)):
            return
    raise UploadFailed(f"the printer would not print {name}, stored {UPLOAD_ATTEMPTS} times")


def _start_print(
    name: str, max_transmissions: int, connection: Connection | None, patience: int | None
) -> Steps[bool]:
    """start_print's rule: False if the printer refused every try and selected nothing."""
    connection = Connection() if connection is None else connection
    for attempt in range(max_transmissions):
        result = yield Request(
            Task.PRINT_PROJECT_WITH_ID, name.encode() + b"\0", resend=attempt > 0
        )
        if result.outcome is Outcome.SUCCESS:
            return True
        yield from sync(connection, max_transmissions, patience)
        selected = " ".join((yield from run_gcode("M27 C", max_transmissions, patience)))
        if "Current file:" in selected and PurePath(name).name in selected.split():
            return True
    return False


def stored_length(answer: bytes) -> int | None:
    """The file length fake-marlin's MK20 puts in its answers (a real one sends nothing)."""
    return int(struct.unpack_from("<I", answer)[0]) if len(answer) >= 4 else None
