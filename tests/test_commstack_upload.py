"""The host's exactly-once rules for CommStack, driven with no I/O: a test plays the MK20.

Each case loses, refuses, delays or damages particular exchanges and checks that the file on
the card is the job, byte for byte, and that the print was started once.
"""

import json
import random
import struct
from collections.abc import Callable

import pytest

from fake_marlin.host.cores import commstack
from fake_marlin.host.cores.commstack import (
    MIN_CHUNK,
    SYNC_TASKS,
    UPLOAD_ATTEMPTS,
    Connection,
    Outcome,
    Result,
    Request,
    Steps,
)
from fake_marlin.host.errors import PrinterNotResponding, UploadFailed
from fake_marlin.wire.commstack import CHUNK_SIZE, Task

CONTENT = b"".join(b"G1 X%d Y%d\n" % (n, n) for n in range(60))  # several chunks
JOB = b"".join(
    b"G1 X%d Y%d E%.2f F3000\n" % (50 + n % 40, 70 - n % 20, n * 0.8) for n in range(200)
)


class MK20:
    """The printer's side of the file and print tasks, as fake-marlin's MK20 answers them.

    Requests are numbered from 1. `lose(n)`: request n is carried out, its answer vanishes.
    `refuse(n)`: request n arrives damaged (ResponseFailed, nothing done). `late(first)`: the
    answer to the first request that `first` picks comes during the next exchange instead,
    and is taken for that one's if it is of the same task (as the host's endpoint matches
    answers by task), whose own answer then comes late in turn, once more; an answer that
    comes during an exchange of another task goes unheeded. `damaged(request)`, if given, says
    which requests arrive damaged. `rename_next_open`: the next FileOpenForWrite's name
    arrives changed past the checksum."""

    def __init__(self, tells_length: bool = True) -> None:
        self.files: dict[str, bytearray] = {}
        self.writing: str | None = None
        self.tells_length = tells_length
        self.requests: list[Request] = []
        self.prints: list[str] = []
        self.selected: str | None = None
        self.close_length_off_by = 0
        self.damaged: Callable[[Request], bool] = lambda request: False
        self.rename_next_open: str | None = None
        self._lost: set[int] = set()
        self._refused: set[int] = set()
        self._late: Callable[[Request], bool] | None = None
        self._held: list[tuple[int, Result]] = []  # (task, answer) on its way, late
        self._chain = 0

    @property
    def file(self) -> bytes:
        return bytes(self.files.get("job.gcode", b""))

    def lose(self, *numbers: int) -> "MK20":
        self._lost.update(numbers)
        return self

    def refuse(self, *numbers: int) -> "MK20":
        self._refused.update(numbers)
        return self

    def late(self, first: Callable[[Request], bool]) -> "MK20":
        self._late = first
        return self

    def answer(self, request: Request) -> Result:
        self.requests.append(request)
        number = len(self.requests)
        if number in self._refused or self.damaged(request):
            own = Result(Outcome.FAILED)
        else:
            data = self._carry_out(request)
            own = Result(Outcome.TIMEOUT) if number in self._lost else data
        if self._late is not None and self._late(request):
            self._late = None
            self._held, self._chain = [(request.task, own)], 2
            return Result(Outcome.TIMEOUT)
        if self._held:
            (task, held), self._held = self._held[0], []
            if task == request.task and held.outcome is not Outcome.TIMEOUT:
                self._chain -= 1
                if self._chain > 0:
                    self._held = [(request.task, own)]
                return held
        return own

    def _length(self, extra: int = 0) -> bytes:
        if not self.tells_length or self.writing is None:
            return b""
        return struct.pack("<I", len(self.files[self.writing]) + extra)

    def _carry_out(self, request: Request) -> Result:
        data = b""
        if request.task == Task.FILE_OPEN_FOR_WRITE:
            name = json.loads(request.data.rstrip(b"\0"))["localFilePath"]
            name, self.rename_next_open = self.rename_next_open or name, None
            self.files[name] = bytearray()
            self.writing = name
        elif request.task == Task.FILE_SAVE_DATA:
            if self.writing is not None:
                self.files[self.writing] += request.data
            data = self._length()
        elif request.task == Task.FILE_CLOSE:
            data = self._length(self.close_length_off_by)
            self.writing = None
        elif request.task == Task.PRINT_PROJECT_WITH_ID:
            name = request.data.rstrip(b"\0").decode()
            if name not in self.files or name == self.writing:
                return Result(Outcome.FAILED)
            self.selected = name
            self.prints.append(name)
        elif request.task == Task.RUN_PRINTER_GCODE:
            data = f"Current file: {self.selected or '(no file)'}\n".encode()
        return Result(Outcome.SUCCESS, data)


def drive(steps: Steps[object], printer: Callable[[Request], Result]) -> object:
    try:
        request = next(steps)
        while True:
            request = steps.send(printer(request))
    except StopIteration as done:
        return done.value


def upload(printer: MK20, content: bytes = CONTENT, connection: Connection | None = None) -> None:
    drive(commstack.upload("job.gcode", content, 8, connection=connection), printer.answer)


def tasks(printer: MK20) -> list[str]:
    return [
        "SYNC" if request.task in SYNC_TASKS else Task(request.task).name
        for request in printer.requests
    ]


def chunks(printer: MK20) -> list[bytes]:
    return [r.data for r in printer.requests if r.task == Task.FILE_SAVE_DATA and r.data]


def is_ask(request: Request) -> bool:
    return request.task == Task.FILE_SAVE_DATA and not request.data


# -- a clean line ---------------------------------------------------------------------------
def test_a_clean_upload_is_open_size_chunks_close():
    printer = MK20()
    upload(printer)
    sent = chunks(printer)
    assert tasks(printer) == ["FILE_OPEN_FOR_WRITE", "FILE_SET_SIZE"] + [
        "FILE_SAVE_DATA"
    ] * len(sent) + ["FILE_CLOSE"]
    assert b"".join(sent) == printer.file == CONTENT
    assert not any(request.resend for request in printer.requests)


def test_chunks_start_small_and_grow_to_the_esps_128_on_a_clean_line():
    printer = MK20()
    connection = Connection()
    upload(printer, JOB, connection)
    sent = chunks(printer)
    assert len(sent[0]) == MIN_CHUNK
    assert max(map(len, sent)) == CHUNK_SIZE and connection.chunk_size == CHUNK_SIZE
    assert printer.file == JOB


def test_until_then_a_line_end_goes_in_a_chunk_of_its_own():
    """Two flips that the byte sum misses can change a command's characters, not a 1-byte
    chunk: damage past the checksums never joins two commands."""
    printer = MK20()
    upload(printer)
    assert all(chunk == b"\n" or b"\n" not in chunk for chunk in chunks(printer))
    assert b"\n" in chunks(printer)


# -- one exchange goes wrong ----------------------------------------------------------------
def test_a_chunk_stored_whose_answer_is_lost_is_not_sent_again():
    printer = MK20().lose(4)  # the second chunk is stored, its answer lost
    upload(printer)
    assert printer.file == CONTENT
    # After the silence the host syncs, asks the length (an empty FileSaveData) and moves on.
    assert tasks(printer)[4:6] == ["SYNC", "FILE_SAVE_DATA"] and is_ask(printer.requests[5])
    assert b"".join(chunks(printer)) == CONTENT  # each chunk sent once, in order
    assert not any(request.resend for request in printer.requests)


def test_a_refused_chunk_is_sent_again_once_the_length_shows_it_missing():
    printer = MK20().refuse(3)
    upload(printer)
    assert printer.file == CONTENT
    assert tasks(printer)[3:5] == ["SYNC", "FILE_SAVE_DATA"] and is_ask(printer.requests[4])
    assert printer.requests[5] == Request(Task.FILE_SAVE_DATA, CONTENT[:MIN_CHUNK], resend=True)


def test_a_late_answer_is_not_taken_for_the_next_chunks():
    """The answer to an ask comes late and is taken for the next ask's; that one's comes
    during the next chunk's exchange. It tells a length the chunk cannot make: the host
    syncs and asks rather than send the chunk again (which would store it twice)."""
    printer = MK20().lose(4).late(is_ask)
    upload(printer)
    assert printer.file == CONTENT
    assert sum(request.resend for request in printer.requests) == 0
    assert tasks(printer).count("FILE_OPEN_FOR_WRITE") == 1


def test_a_wrong_final_length_starts_the_upload_over_and_gives_up_at_the_same_place():
    printer = MK20()
    printer.close_length_off_by = 1
    with pytest.raises(
        UploadFailed, match=f"intact in {UPLOAD_ATTEMPTS} attempts: at byte {len(CONTENT)} "
    ):
        upload(printer)
    assert tasks(printer).count("FILE_OPEN_FOR_WRITE") == UPLOAD_ATTEMPTS


def test_without_lengths_a_lost_chunk_answer_starts_over_rather_than_guess():
    printer = MK20(tells_length=False).lose(3)
    upload(printer)
    assert printer.file == CONTENT
    assert tasks(printer).count("FILE_OPEN_FOR_WRITE") == 2


# -- a line that damages most of what is sent ----------------------------------------------
def test_a_line_that_damages_every_long_chunk_still_stores_the_file_chunk_by_chunk():
    counter = iter(range(1, 1 << 30))
    printer = MK20()
    # Chunks over 16 bytes arrive damaged nine times in ten, whatever the upload's progress.
    printer.damaged = lambda r: (
        r.task == Task.FILE_SAVE_DATA and len(r.data) > 16 and next(counter) % 10 != 0
    )
    upload(printer, JOB)
    assert printer.file == JOB
    assert tasks(printer).count("FILE_OPEN_FOR_WRITE") == 1


class NoisyLine:
    """Bit errors both ways at `rate`: a request of n data bytes (a frame of about n + 10) is
    damaged with the chance that one of its bits flips, and so is its answer; a damaged
    request is answered ResponseFailed (its data checksum) or not at all (its header)."""

    def __init__(self, printer: MK20, rate: float, seed: int) -> None:
        self.printer, self.rate, self.random = printer, rate, random.Random(seed)

    def _hit(self, size: int) -> bool:
        return self.random.random() > (1 - self.rate) ** (8 * (size + 10))

    def answer(self, request: Request) -> Result:
        if self._hit(len(request.data)):
            self.printer.requests.append(request)
            return Result(Outcome.FAILED if self.random.random() < 0.5 else Outcome.TIMEOUT)
        result = self.printer.answer(request)
        return Result(Outcome.TIMEOUT) if self._hit(len(result.answer) + 4) else result


@pytest.mark.parametrize("seed", range(4))
def test_bit_errors_at_1e_3_both_ways_store_the_file_once(seed):
    """The issue's line: at 1e-3 a 128-byte chunk arrives damaged two times in three."""
    printer = MK20()
    drive(commstack.upload("job.gcode", JOB, 8), NoisyLine(printer, 1e-3, seed).answer)
    assert printer.file == JOB


def test_a_printer_that_stores_no_data_is_given_up_on():
    printer = MK20()
    printer.damaged = lambda r: r.task == Task.FILE_SAVE_DATA and bool(r.data)
    with pytest.raises(UploadFailed, match="stored none of 8 chunks of 8 bytes"):
        upload(printer)
    assert tasks(printer).count("FILE_OPEN_FOR_WRITE") == UPLOAD_ATTEMPTS


def test_a_silent_printer_is_given_up_on():
    with pytest.raises(PrinterNotResponding):
        drive(commstack.upload("job.gcode", CONTENT, 8), lambda request: Result(Outcome.TIMEOUT))


# -- printing -------------------------------------------------------------------------------
def print_job(printer: MK20) -> None:
    drive(commstack.store_and_print("job.gcode", CONTENT, 8), printer.answer)


def test_a_print_whose_answer_is_lost_is_checked_not_started_twice():
    printer = MK20()
    upload(printer)
    printer.lose(len(printer.requests) + 1)
    drive(commstack.start_print("job.gcode", 8), printer.answer)
    assert printer.prints == ["job.gcode"]
    assert tasks(printer)[-3:] == ["PRINT_PROJECT_WITH_ID", "SYNC", "RUN_PRINTER_GCODE"]


def test_a_file_the_printer_will_not_print_is_stored_again():
    """FileOpenForWrite's name changed past the checksum: the job went into another file."""
    printer = MK20()
    printer.rename_next_open = "jnb.gcode"
    print_job(printer)
    assert printer.prints == ["job.gcode"] and printer.file == CONTENT
    assert tasks(printer).count("FILE_OPEN_FOR_WRITE") == 2


def test_a_command_that_is_not_a_report_is_not_repeated_after_silence():
    printer = MK20().lose(1)
    with pytest.raises(PrinterNotResponding, match="may or may not have been carried out"):
        drive(commstack.run_gcode("G28", max_transmissions=8), printer.answer)
    assert len(printer.requests) == 1


def test_a_busy_printer_is_waited_for_but_one_that_refuses_is_not():
    silent_for = iter(range(30))
    answers = lambda request: (  # noqa: E731
        Result(Outcome.TIMEOUT) if next(silent_for, None) is not None
        else Result(Outcome.SUCCESS, b"SD printing byte 5/10\n")
    )
    assert drive(commstack.run_gcode("M27", 8, patience=40), answers) == ("SD printing byte 5/10",)
    refusals: list[Request] = []
    with pytest.raises(PrinterNotResponding, match="refused 8 times"):
        drive(
            commstack.run_gcode("M27", 8, patience=40),
            lambda request: refusals.append(request) or Result(Outcome.FAILED),
        )
    assert len(refusals) == 8


def test_the_printer_is_pinged_once_before_the_first_print_request_only():
    """The handshake that makes any later ping of the MK20's a restart (its pings stop once it
    has answered a Ping of ours): before the first print request, and not again before a second
    upload's, which must not hide a restart after a print request that may have started."""
    printer = MK20()
    printer.rename_next_open = "jnb.gcode"
    print_job(printer)
    sent = tasks(printer)
    assert sent.count("PING") == 1
    assert sent.index("PING") + 1 == sent.index("PRINT_PROJECT_WITH_ID")
    assert sent.count("FILE_OPEN_FOR_WRITE") == 2 and printer.prints == ["job.gcode"]
