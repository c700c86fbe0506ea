"""The moments after a reset when an Arduino Mega's STK500v2 bootloader has the port.

Hosts that probe a printer through its bootloader (old Cura, OctoPrint up to 1.4.0) end with
LEAVE_PROGMODE_ISP and then talk to the firmware on the same connection, so the bootloader
hands over to the firmware session rather than ending the connection.
"""

from collections.abc import Callable, Iterable

import trio

from fake_marlin.emulator.protocols.stk500 import (
    LeftBootloader,
    MessageReceived,
    Reply,
    Stk500Protocol,
    answer,
)
from fake_marlin.emulator.sessions.base import HandsOver, Session

# stk500boot.c's recchar_timeout() polls the UART F_CPU / 2 times for each next byte, then jumps
# to the firmware: some seconds on a 16 MHz board (the exact time is its compiled loop's).
BYTE_TIMEOUT = 5.0


class Stk500Session:
    def __init__(
        self,
        send: Callable[[bytes], None],
        start_firmware: Callable[[], HandsOver],
        byte_timeout: float = BYTE_TIMEOUT,
    ) -> None:
        self._send = send
        self._start_firmware = start_firmware
        self.byte_timeout = byte_timeout
        self.protocol = Stk500Protocol()
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
                self._send(self.protocol.send(Reply(event.seq, answer(event.body))))
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

    def announce(self, lines: Iterable[str]) -> None:
        pass  # faults reach a firmware that is not running yet: nothing prints them

    def block_queue(self, seconds: float, nursery: trio.Nursery) -> None:
        pass  # the bootloader has no command queue
