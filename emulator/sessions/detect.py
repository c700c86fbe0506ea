"""`--protocol auto`: the first decisive bytes of a connection choose the protocol."""

import math
from collections.abc import Callable
from enum import Enum

import trio

from fake_marlin.emulator.protocols.repetier import MAX_CMD_SIZE
from fake_marlin.emulator.protocols.stk500 import MESSAGE_START
from fake_marlin.emulator.sessions.base import Session
from fake_marlin.emulator.sessions.stk500 import Stk500Session
from fake_marlin.wire import g2core, repetier
from fake_marlin.wire.commstack import starts_with_header

PRINTABLE = frozenset(range(0x20, 0x7F)) | {0x0A, 0x0D}
# A CommStack frame starts with its COBS code byte: the distance to the header's first zero,
# which is at the latest its padding byte (offset 3), so 1 to 4.
COBS_HEADER_STARTS = frozenset({1, 2, 3, 4})
HOLD_TIMEOUT = 0.2  # a command comes in one write: bytes held longer unconfirmed are noise


class Detected(Enum):
    ULTIMAKER = "ultimaker"
    MARLIN = "marlin"
    STK500 = "stk500"  # a host talking to the Arduino bootloader that runs first after a reset
    REPETIER = "repetier"
    COMMSTACK = "commstack"
    G2CORE = "g2core"  # its JSON requests, its single characters and G-code lines


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
    if byte in COBS_HEADER_STARTS:
        return Detected.COMMSTACK
    return None


def starts_with_repetier_command(data: bytes) -> bool | None:
    """Whether `data` begins with a whole binary command whose Fletcher-16 checks out; None
    until enough bytes have come."""
    size = repetier.command_size(data[:5])
    if size is None or len(data) < size:
        return None if len(data) < MAX_CMD_SIZE else False
    if size > MAX_CMD_SIZE:
        return False
    try:
        repetier.decode(data[:size])
    except repetier.BadChecksum:
        return False
    return True


# In this order, where a firmware has more than one (a g2core board reads a line as g2core,
# which hands it to Marlin's protocol if it is a Marlin host's).
LINE_SPEAKERS = (Detected.G2CORE, Detected.MARLIN, Detected.REPETIER)

# What a board tells apart unless its profile says otherwise: all but g2core's, whose lines
# would take Marlin's.
MARLIN_BOARD = frozenset(Detected) - {Detected.G2CORE}

CONFIRMED_BY = {
    Detected.REPETIER: starts_with_repetier_command,
    Detected.COMMSTACK: starts_with_header,
}


class DetectingSession:
    """Holds a connection's first bytes until they name a protocol, then hands over.

    The greeting waits too: a printer that does not yet know its protocol cannot say hello in it.
    `bootloader`: whether the bootloader still listens, as it does only right after a reset;
    once it has handed over, 0x1B is noise to the firmware like any other control byte.
    """

    def __init__(self, make_session: Callable[[Detected], Session], bootloader: bool = True,
                 protocols: frozenset[Detected] = MARLIN_BOARD) -> None:
        self._make_session = make_session
        self._bootloader = bootloader
        # The protocols this firmware speaks: bytes of any other are noise to it.
        self._protocols = protocols
        # Who reads a printable line: Marlin's protocol, or (Repetier-Firmware, which has no
        # other) Repetier's, whose machine takes ASCII lines beside its binary commands.
        self._lines = next((speaker for speaker in LINE_SPEAKERS if speaker in protocols), None)
        self._session: Session | None = None
        self._held = b""  # the start of what may be a Repetier command or a CommStack frame
        self._fed = trio.Event()

    @property
    def active(self) -> Session | None:
        """The session that took over, once the protocol is known (the firmware's, past a
        bootloader)."""
        session = self._session
        return session.active if isinstance(session, Stk500Session) else session

    def boot(self) -> None:
        pass

    def feed(self, data: bytes) -> None:
        self._fed.set()
        if self._session is None:
            data = self._held + data
            self._held = b""
            index = 0
            while index < len(data):
                protocol = classify(data[index], self._bootloader)
                if self._lines is Detected.G2CORE and data[index] in g2core.SINGLE_CHARACTERS:
                    protocol = Detected.MARLIN  # ^X, ^D, ENQ: a g2core host's
                line = protocol is Detected.MARLIN
                if line:
                    protocol = self._lines
                elif protocol not in self._protocols and protocol is not Detected.STK500:
                    protocol = None
                if protocol in CONFIRMED_BY and not line:
                    # Control bytes and high bytes are common in noise: only a checksum that
                    # checks out (a Repetier command's, a CommStack header's) decides.
                    confirmed = CONFIRMED_BY[protocol](data[index:])
                    if confirmed is None:
                        self._held = data[index:]
                        return
                    if not confirmed:
                        protocol = None
                if protocol is not None:
                    session = self._session = self._make_session(protocol)
                    session.boot()
                    data = data[index:]
                    break
                index += 1
            else:
                return
        self._session.feed(data)

    async def run(self) -> None:
        while self._session is None:
            fed = self._fed = trio.Event()
            with trio.move_on_after(HOLD_TIMEOUT if self._held else math.inf) as waiting:
                await fed.wait()
            if waiting.cancelled_caught and self._held:
                # No header came with it: the candidate byte was noise; read on after it.
                rest, self._held = self._held[1:], b""
                self.feed(rest)
        await self._session.run()
