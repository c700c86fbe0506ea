"""One boot of a Printrbot Simple 2016 as its ESP8266 sees it: the MK20 side of CommStack.

Tasks answered (Printrhub's mk20 Application.cpp, ReceiveSDCardFile and DownloadFileController):
- Ping: the MK20's build number (int32); it also pings the host every 5 s until the host
  answers one or pings it.
- GetSystemInfo: the 128-byte SystemInfo struct the ESP keeps.
- FileOpenForWrite (JSON `localFilePath`, `compression` 1 = none, 2 = RLE16, or a bare path),
  FileSetSize, FileSaveData (data), FileClose: a file on the SD card. The announced size (JSON
  `fileSize`, FileSetSize's u32) is accepted and not needed: the file is the data stored.
  The ResponseSuccess of FileSaveData and FileClose carries the file's length so far (u32),
  which the MK20 does not send: a host that ignores it loses nothing, and ours learns from it
  whether a chunk whose answer was lost was stored (an empty FileSaveData asks).
- RunPrinterGCode: G-code lines run in order; the reply comes once they have run and carries
  what they printed (the MK20 has no handler; a host needs one to reach the printer).
- PrintProjectWithID: print a stored file (its path, or the file just stored), from the card.
Anything else is answered with an empty ResponseSuccess, as the firmware answers any request.

The SD card can be pulled (the sd-removed fault): from then on nothing is written and nothing
printed from it. A file open for writing stays lost, as the firmware's File does, even once a
card is mounted again: FileSaveData is still answered with success (writeToFile ignores what
the write returns) and the length, which no longer grows; and "the file just stored" is
forgotten, since the card it was stored on is gone.
"""

import json
import math
import struct
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import trio

from fake_marlin.emulator.firmware import Firmware
from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.printer.model import Printer
from fake_marlin.emulator.printer.statements import Statement
from fake_marlin.emulator.printer.sdcard import OpenFile
from fake_marlin.emulator.protocols.commstack import (
    CommStackProtocol,
    RequestReceived,
    Response,
    ResponseReceived,
)
from fake_marlin.emulator.sessions.base import MachineClock
from fake_marlin.emulator.sessions.driver import run_command
from fake_marlin.wire.commstack import MAX_DATA, CommType, Packet, Task, encode_packet
from fake_marlin.wire.gcode import strip_comment

BUILD_NUMBER = 109  # mk20 Application.h FIRMWARE_BUILDNR
PING_INTERVAL = 5.0
SYSTEM_INFO = struct.Struct("<15sB32s16s37s5s18shbx")  # esp application.h struct SystemInfo
COMPRESSION_RLE16 = 2


@dataclass
class _Upload:
    path: Path
    compression: int
    written: int = 0
    lost: bool = False  # its card was pulled: the File writes nothing any more


class CommStackSession:
    def __init__(
        self,
        printer: Printer,
        journal: Journal,
        send: Callable[[bytes], None],
        before_command: Callable[[str], None] = lambda text: None,
        firmware: Firmware | None = None,
    ) -> None:
        self.printer = printer
        self.journal = journal
        self._send = send
        self._before_command = before_command
        self.firmware = firmware or Firmware.make()
        self._words = self.firmware.words
        self.protocol = CommStackProtocol()
        self._requests_in, self._requests = trio.open_memory_channel[RequestReceived](math.inf)
        self._upload: _Upload | None = None
        self._last_stored: Path | None = None
        self._last_size = 0
        self._host_answered_ping = False
        self._paused_until = -math.inf
        # readBytesUntil gives up on a frame when no byte has come for a second: what it has
        # read by then is the frame (one whose 0x00 was lost is read whole).
        self._clock = MachineClock(self.protocol, after=self._read_frames)

    def boot(self) -> None:
        pass  # the MK20 speaks first only with its pings

    def announce(self, statements: Iterable[Statement]) -> None:
        pass  # CommStack has no channel for the printer's messages

    def block_queue(self, seconds: float, nursery: trio.Nursery) -> None:
        self._paused_until = trio.current_time() + seconds

    def feed(self, data: bytes) -> None:
        self.protocol.receive_data(data)
        self._read_frames()
        self._clock.tell()

    def _read_frames(self) -> None:
        while (event := self.protocol.next_event()) is not None:
            if isinstance(event, RequestReceived):
                self._requests_in.send_nowait(event)
            elif isinstance(event, ResponseReceived):
                packet = event.packet
                if packet.task == Task.PING and packet.comm_type == CommType.RESPONSE_SUCCESS:
                    self._host_answered_ping = True
        self._send(self.protocol.data_to_send())

    def _reply(self, task: int, success: bool = True, data: bytes = b"") -> None:
        self._send(self.protocol.send(Response(task, success, data[:MAX_DATA])))

    async def run(self) -> None:
        async with trio.open_nursery() as nursery:
            nursery.start_soon(self._serve)
            nursery.start_soon(self._ping_host)
            nursery.start_soon(self._clock.run)

    async def _ping_host(self) -> None:
        """Application::pingESP(): every 5 s until the other side answers."""
        while not self._host_answered_ping:
            request = Packet(Task.PING, CommType.REQUEST, struct.pack("<i", BUILD_NUMBER))
            self._send(encode_packet(request))
            await trio.sleep(PING_INTERVAL)

    async def _serve(self) -> None:
        sd = self.printer.sd
        while True:
            await trio.sleep_until(self._paused_until)
            try:
                request = self._requests.receive_nowait()
            except trio.WouldBlock:
                if sd.printing and not self.printer.halted:
                    await self._print_next_line()
                    continue
                request = await self._requests.receive()
            await self._handle(request)

    async def _print_next_line(self) -> None:
        line = self.printer.sd.next_line()
        if line is None:
            self.printer.sd.printing = False
            return
        await self._run_gcode(line)

    async def _run_gcode(self, text: str) -> list[str]:
        self._check_card()
        self._before_command(text)
        if self.printer.halted:
            return []
        reports: list[Statement] = []
        reply = await run_command(self.printer, text, self.journal, reports.append)
        return self._words.lines([*reports, *reply.response_data()])

    # -- the tasks -----------------------------------------------------------------------
    async def _handle(self, request: RequestReceived) -> None:
        task, data = request.task, request.data
        self._check_card()
        if task == Task.PING:
            self._host_answered_ping = True  # a ping from the ESP stops the MK20's too
            self._reply(task, data=struct.pack("<i", BUILD_NUMBER))
        elif task == Task.GET_SYSTEM_INFO:
            self._reply(task, data=self._system_info())
        elif task == Task.FILE_OPEN_FOR_WRITE:
            self._reply(task, self._open_for_write(data))
        elif task == Task.FILE_SET_SIZE:
            self._reply(task)  # the file ends where its data does: the size is not needed
        elif task == Task.FILE_SAVE_DATA:
            stored = self._save(data)
            length = b"" if self._upload is None else struct.pack("<I", self._upload.written)
            self._reply(task, stored, length if stored else b"")
        elif task == Task.FILE_CLOSE:
            self._close()
            self._reply(task, data=struct.pack("<I", self._last_size))
        elif task == Task.RUN_PRINTER_GCODE:
            await self._run_printer_gcode(data)
        elif task == Task.PRINT_PROJECT_WITH_ID:
            self._reply(task, self._print_file(data))
        else:
            self._reply(task)

    def _check_card(self) -> None:
        """A card that has been pulled takes the file being written and the one just stored
        with it (checked before every request and command, so before any M21 mounts one)."""
        if not self.printer.sd.mounted:
            if self._upload is not None:
                self._upload.lost = True
            self._last_stored = None

    def _system_info(self) -> bytes:
        return SYSTEM_INFO.pack(
            b"127.0.0.1", 0, b"", b"fake-marlin", self.firmware.identity.uuid.encode(), b"1.0",
            b"02:00:00:00:00:01", BUILD_NUMBER, False,
        )

    def _open_for_write(self, data: bytes) -> bool:
        text = data.split(b"\0", 1)[0].decode("latin-1").strip()
        compression = 1
        try:
            fields = json.loads(text)
        except ValueError:
            fields = {"localFilePath": text}
        if not isinstance(fields, dict):
            return False
        name = fields.get("localFilePath")
        if isinstance(fields.get("compression"), int):
            compression = fields["compression"]
        path = self._card_path(name)
        if path is None:
            return False
        self._close()
        sd = self.printer.sd
        if sd.selected is not None and sd.selected.path == path:
            sd.selected, sd.printing = None, False  # the file it was printing is rewritten
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(b"")
        except OSError:
            return False
        self._upload = _Upload(path, compression)
        return True

    def _card_path(self, name) -> Path | None:
        sd = self.printer.sd
        if not isinstance(name, str) or not name.strip("/ ") or not sd.mounted:
            return None
        return sd.path_on_card(name)

    def _save(self, data: bytes) -> bool:
        upload = self._upload
        if upload is None:
            return True  # the firmware answers success and writes nothing
        if upload.compression == COMPRESSION_RLE16:
            if len(data) % 3:
                return False
            data = b"".join(
                data[i + 1:i + 3] * data[i] for i in range(0, len(data), 3)
            )
        if upload.lost:
            return True  # the write fails, and writeToFile() answers success regardless
        try:
            with open(upload.path, "ab") as target:
                target.write(data)
        except OSError:
            return False
        upload.written += len(data)
        return True

    def _close(self) -> None:
        upload = self._upload
        if upload is not None:
            self._last_stored = None if upload.lost else upload.path
            self._last_size = upload.written
            self._upload = None

    async def _run_printer_gcode(self, data: bytes) -> None:
        text = data.split(b"\0", 1)[0].decode("latin-1")
        output: list[str] = []
        for line in text.splitlines():
            command = strip_comment(line)
            if command:
                output += await self._run_gcode(command)
            if self.printer.halted:
                break
        answer = "\n".join(output).encode("latin-1", "replace")
        self._reply(Task.RUN_PRINTER_GCODE, not self.printer.halted, answer)

    def _print_file(self, data: bytes) -> bool:
        sd = self.printer.sd
        name = data.split(b"\0", 1)[0].decode("latin-1").strip()
        if name:
            path = self._card_path(name)
        else:
            path = self._last_stored
        if path is None or sd.root is None or not sd.mounted or not path.is_file():
            return False  # (a card pulled has no files, and forgot the file just stored)
        if self.printer.halted:
            return False
        if sd.printing and sd.selected is not None and sd.selected.path == path:
            return True  # asked again (its answer was lost): it is printing already
        self._close()
        relative = path.relative_to(sd.root.resolve()).as_posix()
        found = sd.find(relative)
        short = found[0] if found else path.name
        sd.selected = OpenFile(path, short, path.read_bytes())
        sd.printing = True
        return True
