"""Marlin's binary file transfer (`M28 B1`) on trio: the machine of
emulator/protocols/marlin_binary.py, the SD card it writes, and the firmware's two timers.

MarlinSession hands the line over when M28 B1 has run and takes it back when the host closes
binary mode. What the card does and says mirrors SDFileTransferProtocol: OPEN mounts the card
and opens the file as openFileWrite() does (`echo:SD card ok`, `echo:Now fresh file: ...`,
`Writing to file: ...`); CLOSE closes it and releases the card (a host sends M21 afterwards,
as Marlin's transfer script does); ABORT, or TRANSFER_TIMEOUT without a file packet, deletes it.
"""

from collections.abc import Callable
from pathlib import Path

import trio

from fake_marlin.emulator.printer.model import Printer
from fake_marlin.emulator.printer.statements import Statement, state
from fake_marlin.emulator.protocols.marlin_binary import (
    BackToAscii,
    FileAborted,
    FileData,
    FileEvent,
    FileOpened,
    FileResult,
    MarlinBinaryProtocol,
    Mode,
)
from fake_marlin.emulator.sessions.base import MachineClock


class BinaryTransfer:
    def __init__(self, printer: Printer, send: Callable[[bytes], None],
                 say: Callable[[Statement], None]) -> None:
        self.printer = printer
        self._send = send
        self._say = say
        # Made at the first M28 B1, then kept for the boot: the firmware's stream (its sync
        # number, an open transfer) lives on between binary sessions.
        self.protocol: MarlinBinaryProtocol | None = None
        self._clock: MachineClock | None = None  # the machine's timers, made with it
        self._clock_made = trio.Event()
        self._file: Path | None = None

    @property
    def active(self) -> bool:
        return self.protocol is not None and self.protocol.mode is not Mode.ASCII

    def enter(self, data: bytes) -> None:
        """M28 B1 has run: binary mode from here, `data` (what followed it) first."""
        if self.protocol is None:
            self.protocol = MarlinBinaryProtocol()
            self.protocol.receive_data(data)
            self._clock = MachineClock(
                self.protocol, after=self._read_events, running=lambda: not self.printer.halted
            )
            self._clock_made.set()
        else:
            self.protocol.enter(data)
        # M28 B1 ran now: the packet timer counts from here. What came with it is read once
        # its `ok` is out (the session feeds b"").
        self.protocol.time_passed(trio.current_time())

    def feed(self, data: bytes) -> bytes:
        """Bytes from the host; returns what follows the packet that closes binary mode."""
        assert self.protocol is not None and self._clock is not None, "feed() before enter()"
        self.protocol.receive_data(data)
        unread = self._read_events()
        self._clock.tell()  # what was read came now
        return unread

    def _read_events(self) -> bytes:
        """The card's part in what the machine read (or a timer made); returns the bytes that
        follow the packet that closes binary mode, if it came."""
        protocol = self.protocol
        assert protocol is not None
        unread = b""
        while (event := protocol.next_event()) is not None:
            self._send(protocol.data_to_send())  # `ok<sync>` goes before what the card says
            if isinstance(event, BackToAscii):
                unread = event.unread
                break
            self._send(protocol.send(FileResult(self._on_card(event))))
        self._send(protocol.data_to_send())
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
                self._say(state("file_deleted", name=removed))
        self._file = None
        sd.reset()  # card.release(): the card is unmounted until the next M21 or OPEN
        sd.mounted = False
        return True

    def _open(self, name: str) -> bool:
        sd = self.printer.sd
        sd.reset()  # card.mount()
        if not sd.mounted:
            self._say(state("sd_init_fail"))
            return False
        self._say(state("sd_ok"))
        self._say(state("now_fresh_file", name=name))
        opened = sd.open_for_write(name)
        if opened is None:
            self._say(state("open_failed", name=name))
            return False
        self._file, shown = opened
        self._say(state("writing_to_file", name=shown))
        return True

    # -- the firmware's timers ---------------------------------------------------------
    async def run(self) -> None:
        await self._clock_made.wait()  # the first M28 B1 of the boot
        assert self._clock is not None
        await self._clock.run()
