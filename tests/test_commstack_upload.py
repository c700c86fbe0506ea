"""The host's exactly-once rules for CommStack, driven with no I/O: a test plays the MK20.

Each case loses or refuses one particular exchange and checks that the file on the card is the
job, byte for byte, and that the print was started once.
"""

import struct
from collections.abc import Callable

import pytest

from fake_marlin.host.cores import commstack
from fake_marlin.host.cores.commstack import Outcome, Reply, Request, Steps
from fake_marlin.host.errors import PrinterNotResponding, UploadFailed
from fake_marlin.wire.commstack import CHUNK_SIZE, Task

CONTENT = b"".join(b"G1 X%d Y%d\n" % (n, n) for n in range(60))  # several 128-byte chunks


class MK20:
    """The printer's side of the file and print tasks, as fake-marlin's MK20 answers them.

    `lose(n)` makes the n-th request (from 1) reach the printer but its answer vanish;
    `refuse(n)` makes the n-th request arrive damaged (ResponseFailed, nothing done)."""

    def __init__(self, tells_length: bool = True) -> None:
        self.file = bytearray()
        self.tells_length = tells_length
        self.requests: list[Request] = []
        self.prints: list[str] = []
        self.selected: str | None = None
        self._lost: set[int] = set()
        self._refused: set[int] = set()
        self.close_length_off_by = 0

    def lose(self, *numbers: int) -> "MK20":
        self._lost.update(numbers)
        return self

    def refuse(self, *numbers: int) -> "MK20":
        self._refused.update(numbers)
        return self

    def answer(self, request: Request) -> Reply:
        self.requests.append(request)
        number = len(self.requests)
        if number in self._refused:
            return Reply(Outcome.FAILED)
        data = self._carry_out(request)
        return Reply(Outcome.TIMEOUT) if number in self._lost else Reply(Outcome.SUCCESS, data)

    def _length(self, extra: int = 0) -> bytes:
        return struct.pack("<I", len(self.file) + extra) if self.tells_length else b""

    def _carry_out(self, request: Request) -> bytes:
        if request.task == Task.FILE_OPEN_FOR_WRITE:
            self.file.clear()
        elif request.task == Task.FILE_SAVE_DATA:
            self.file += request.data
            return self._length()
        elif request.task == Task.FILE_CLOSE:
            return self._length(self.close_length_off_by)
        elif request.task == Task.PRINT_PROJECT_WITH_ID:
            self.selected = request.data.rstrip(b"\0").decode()
            self.prints.append(self.selected)
        elif request.task == Task.RUN_PRINTER_GCODE:
            if self.selected is not None:
                return f"Current file: {self.selected}\n".encode()
            return b"No print\n"
        return b""


def drive(steps: Steps[object], printer: Callable[[Request], Reply]) -> object:
    try:
        request = next(steps)
        while True:
            request = steps.send(printer(request))
    except StopIteration as done:
        return done.value


def upload(printer: MK20, content: bytes = CONTENT) -> None:
    drive(commstack.upload("job.gcode", content, max_transmissions=8), printer.answer)


def tasks(printer: MK20) -> list[Task]:
    return [Task(request.task) for request in printer.requests]


def test_a_clean_upload_is_open_size_chunks_close():
    printer = MK20()
    upload(printer)
    chunks = -(-len(CONTENT) // CHUNK_SIZE)
    assert tasks(printer) == [Task.FILE_OPEN_FOR_WRITE, Task.FILE_SET_SIZE] + [
        Task.FILE_SAVE_DATA
    ] * chunks + [Task.FILE_CLOSE]
    assert bytes(printer.file) == CONTENT


def test_a_chunk_stored_whose_answer_is_lost_is_not_sent_again():
    printer = MK20().lose(4)  # the second chunk is stored, its answer lost
    upload(printer)
    assert bytes(printer.file) == CONTENT
    # After the silence the host asks the length (an empty FileSaveData) and moves on.
    assert printer.requests[4] == Request(Task.FILE_SAVE_DATA, b"")
    assert printer.requests[5].data == CONTENT[2 * CHUNK_SIZE : 3 * CHUNK_SIZE]


def test_a_refused_chunk_is_sent_again_once_the_length_shows_it_missing():
    printer = MK20().refuse(3)
    upload(printer)
    assert bytes(printer.file) == CONTENT
    assert printer.requests[4] == Request(Task.FILE_SAVE_DATA, CONTENT[:CHUNK_SIZE], resend=True)


def test_a_wrong_final_length_starts_the_upload_over():
    printer = MK20()
    printer.close_length_off_by = 1
    with pytest.raises(UploadFailed, match="intact in 3 attempts"):
        upload(printer)
    assert tasks(printer).count(Task.FILE_OPEN_FOR_WRITE) == 3


def test_without_lengths_a_lost_chunk_answer_starts_over_rather_than_guess():
    printer = MK20(tells_length=False).lose(3)
    upload(printer)
    assert bytes(printer.file) == CONTENT
    assert tasks(printer).count(Task.FILE_OPEN_FOR_WRITE) == 2


def test_a_print_whose_answer_is_lost_is_checked_not_started_twice():
    printer = MK20().lose(1)
    drive(commstack.start_print("job.gcode", max_transmissions=8), printer.answer)
    assert printer.prints == ["job.gcode"]
    assert tasks(printer) == [Task.PRINT_PROJECT_WITH_ID, Task.RUN_PRINTER_GCODE]


def test_a_command_that_is_not_a_report_is_not_repeated_after_silence():
    printer = MK20().lose(1)
    with pytest.raises(PrinterNotResponding, match="may or may not have been carried out"):
        drive(commstack.run_gcode("G28", max_transmissions=8), printer.answer)
    assert len(printer.requests) == 1
