"""`--protocol auto`: the first decisive bytes of a connection choose the protocol."""

from collections.abc import Callable
from enum import Enum

import trio

from emulator.protocols.stk500 import MESSAGE_START

PRINTABLE = frozenset(range(0x20, 0x7F)) | {0x0A, 0x0D}


class Detected(Enum):
    ULTIMAKER = "ultimaker"
    MARLIN = "marlin"
    STK500 = "stk500"  # a host talking to the Arduino bootloader that runs first after a reset
    REPETIER = "repetier"


def classify(byte: int, bootloader: bool = True) -> Detected | None:
    """What a connection's first bytes say about the host; None for noise that says nothing."""
    if byte == MESSAGE_START and bootloader:
        return Detected.STK500
    if byte == 0xFF:
        return Detected.ULTIMAKER
    if byte & 0x80:
        # A Repetier binary command: bit 7 of its first byte is always set. (0xFF would need
        # M and G in one command; it is Ultimaker's.)
        return Detected.REPETIER
    if byte in PRINTABLE:
        return Detected.MARLIN
    return None


class DetectingSession:
    """Holds a connection's first bytes until they name a protocol, then hands over.

    The greeting waits too: a printer that does not yet know its protocol cannot say hello in it.
    `bootloader`: whether the bootloader still listens, as it does only right after a reset;
    once it has handed over, 0x1B is noise to the firmware like any other control byte.
    """

    def __init__(self, make_session: Callable[[Detected], object], bootloader: bool = True) -> None:
        self._make_session = make_session
        self._bootloader = bootloader
        self._session = None
        self._detected = trio.Event()

    @property
    def active(self):
        """The session that took over, once the protocol is known (the firmware's, past a
        bootloader)."""
        return getattr(self._session, "active", self._session)

    def boot(self) -> None:
        pass

    def feed(self, data: bytes) -> None:
        if self._session is None:
            for index, byte in enumerate(data):
                protocol = classify(byte, self._bootloader)
                if protocol is not None:
                    self._session = self._make_session(protocol)
                    self._session.boot()
                    self._detected.set()
                    data = data[index:]
                    break
            else:
                return
        self._session.feed(data)

    async def run(self) -> None:
        await self._detected.wait()
        await self._session.run()
