"""The moments after a reset when an Arduino Mega's STK500v2 bootloader has the port.

avrdude flashes the board's memories through it; hosts that probe a printer through it (old
Cura, OctoPrint up to 1.4.0) end with LEAVE_PROGMODE_ISP and then talk to the firmware on the
same connection, so the bootloader hands over to the firmware session rather than ending the
connection. The memories are the printer's, not the boot's: they outlive every reset.
"""

from collections.abc import Callable, Iterable

import trio

from fake_marlin.emulator.printer.statements import Statement
from fake_marlin.emulator.protocols.avr_memory import BoardMemory
from fake_marlin.emulator.protocols.stk500 import (
    Bootloader,
    LeftBootloader,
    MessageReceived,
    Answer,
    Stk500Protocol,
)
from fake_marlin.emulator.sessions.base import HandsOver, Session

# stk500boot.c's recchar_timeout() polls the UART F_CPU / 2 times for each next byte, then jumps
# to the firmware: 8,000,000 passes of a loop of some 16 cycles (load and test the UART status,
# count in 32 bits, compare) at 16 MHz. Longer than avrdude's 5 s wait for a reply, so avrdude
# finds the bootloader still there when it resyncs after a lost message.
BYTE_TIMEOUT = 8.0


class Stk500Session:
    def __init__(
        self,
        send: Callable[[bytes], None],
        start_firmware: Callable[[], HandsOver],
        memory: BoardMemory,
        flash_changed: Callable[[], None] = lambda: None,
        byte_timeout: float = BYTE_TIMEOUT,
    ) -> None:
        """`flash_changed` is called when a message has changed the flash, before its reply
        goes out: a host told a page is written may count on it (--flash-file keeps it)."""
        self._send = send
        self._start_firmware = start_firmware
        self._flash_changed = flash_changed
        self.byte_timeout = byte_timeout
        self.protocol = Stk500Protocol()
        self.bootloader = Bootloader(memory)
        self.firmware: HandsOver | None = None  # the session the bootloader handed over to
        self._heard = trio.Event()

    @property
    def active(self) -> Session | None:
        """The session that speaks for the printer: this one, then the firmware's."""
        if self.firmware is None:
            return self
        return self.firmware.active

    def boot(self) -> None:
        pass  # the bootloader says nothing until it is spoken to

    def feed(self, data: bytes) -> None:
        if self.firmware is not None:
            self.firmware.feed(data)
            return
        self._heard.set()
        self.protocol.receive_data(data)
        while (event := self.protocol.next_event()) is not None:
            if isinstance(event, MessageReceived):
                reply = self.bootloader.answer(event.body)
                if self.bootloader.memory.has_changed_pages:
                    self._flash_changed()
                self._send(self.protocol.send(Answer(event.seq, reply)))
            elif isinstance(event, LeftBootloader):
                self._jump_to_firmware(event.rest)

    def _jump_to_firmware(self, rest: bytes) -> None:
        firmware = self.firmware = self._start_firmware()
        firmware.boot()
        self._heard.set()
        if rest:
            firmware.feed(rest)

    async def run(self) -> None:
        while self.firmware is None:
            heard = self._heard = trio.Event()
            with trio.move_on_after(self.byte_timeout):
                await heard.wait()
            if self.firmware is None and not heard.is_set():
                # A host that went quiet mid-conversation: the board starts its firmware anyway,
                # and a half-read message is lost with the bootloader.
                self._jump_to_firmware(b"")
        await self.firmware.run()

    def announce(self, statements: Iterable[Statement]) -> None:
        pass  # faults reach a firmware that is not running yet: nothing prints them

    def block_queue(self, seconds: float, nursery: trio.Nursery) -> None:
        pass  # the bootloader has no command queue
