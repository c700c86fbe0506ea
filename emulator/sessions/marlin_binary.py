"""Marlin's binary file transfer (`M28 B1`) on trio: the machine of
emulator/protocols/marlin_binary.py, the SD card it writes, and the firmware's two timers.

MarlinSession hands the line over when M28 B1 has run and takes it back when the host closes
binary mode. What the card does and says mirrors SDFileTransferProtocol: OPEN mounts the card
and opens the file as openFileWrite() does (`echo:SD card ok`, `echo:Now fresh file: ...`,
`Writing to file: ...`); CLOSE closes it and releases the card (a host sends M21 afterwards,
as Marlin's transfer script does); ABORT, or TRANSFER_TIMEOUT without a file packet, deletes it.
"""

import math
from collections.abc import Callable
from pathlib import Path

import trio

from fake_marlin.emulator.printer.model import Printer
from fake_marlin.emulator.protocols.marlin_binary import (
    PACKET_MAX_WAIT,
    TRANSFER_TIMEOUT,
    BackToAscii,
    FileAborted,
    FileData,
    FileEvent,
    FileOpened,
    FileResult,
    MarlinBinaryProtocol,
    Mode,
)


class BinaryTransfer:
    def __init__(self, printer: Printer, send: Callable[[bytes], None], say: Callable[[str], None]) -> None:
        self.printer = printer
        self._send = send
        self._say = say
        # Made at the first M28 B1, then kept for the boot: the firmware's stream (its sync
        # number, an open transfer) lives on between binary sessions.
        self.protocol: MarlinBinaryProtocol | None = None
        self._file: Path | None = None
        self._last_byte = self._last_file_packet = 0.0
        self._timers_changed = trio.Event()

    @property
    def active(self) -> bool:
        return self.protocol is not None and self.protocol.mode is not Mode.ASCII

    def enter(self, data: bytes) -> None:
        """M28 B1 has run: binary mode from here, `data` (what followed it) first."""
        if self.protocol is None:
            self.protocol = MarlinBinaryProtocol()
            self.protocol.receive_data(data)
        else:
            self.protocol.enter(data)
        self._last_byte = trio.current_time()

    def feed(self, data: bytes) -> bytes:
        """Bytes from the host; returns what follows the packet that closes binary mode."""
        protocol = self.protocol
        assert protocol is not None, "feed() before enter()"
        protocol.receive_data(data)
        now = trio.current_time()
        if data:
            self._last_byte = now
        packets = protocol.file_packets
        unread = b""
        while (event := protocol.next_event()) is not None:
            self._send(protocol.data_to_send())  # `ok<sync>` goes before what the card says
            if isinstance(event, BackToAscii):
                unread = event.unread
                break
            self._send(protocol.send(FileResult(self._on_card(event))))
        self._send(protocol.data_to_send())
        if protocol.file_packets != packets:
            self._last_file_packet = now
        self._timers_changed.set()
        return unread

    # -- the card ----------------------------------------------------------------------
    def _on_card(self, event: FileEvent) -> bool:
        sd = self.printer.sd
        if isinstance(event, FileOpened):
            return event.dummy or self._open(event.name)
        if isinstance(event, FileData):  # (never in a dummy transfer)
            return self._file is not None and sd.append(self._file, event.data)
        if event.dummy:
            return True  # a benchmark: nothing reaches the card
        if isinstance(event, FileAborted) and self._file is not None:
            removed = sd.remove(self._file)
            if removed is not None:
                self._say(f"File deleted:{removed}")
        self._file = None
        sd.reset()  # card.release(): the card is unmounted until the next M21 or OPEN
        sd.mounted = False
        return True

    def _open(self, name: str) -> bool:
        sd = self.printer.sd
        sd.reset()  # card.mount()
        if not sd.mounted:
            self._say("echo:SD init fail")
            return False
        self._say("echo:SD card ok")
        self._say(f"echo:Now fresh file: {name}")
        opened = sd.open_for_write(name)
        if opened is None:
            self._say(f"open failed, File: {name}.")
            return False
        self._file, shown = opened
        self._say(f"Writing to file: {shown}")
        return True

    # -- the firmware's timers ---------------------------------------------------------
    async def run(self) -> None:
        while True:
            changed = self._timers_changed = trio.Event()
            with trio.move_on_at(self._deadline()):
                await changed.wait()
                continue
            self._time_out()

    def _deadline(self) -> float:
        protocol = self.protocol
        if protocol is None or not self.active or self.printer.halted:
            return math.inf
        if protocol.mid_packet:
            return self._last_byte + PACKET_MAX_WAIT
        if protocol.transfer_active:
            return self._last_file_packet + TRANSFER_TIMEOUT
        return math.inf

    def _time_out(self) -> None:
        protocol = self.protocol
        assert protocol is not None
        if trio.current_time() < self._deadline():
            return  # the host was heard from at the last moment
        if protocol.mid_packet:
            protocol.packet_timed_out()
        elif (event := protocol.transfer_timed_out()) is not None:
            self._send(protocol.send(FileResult(self._on_card(event))))
        self._send(protocol.data_to_send())
