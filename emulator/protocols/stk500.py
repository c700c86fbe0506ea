"""The printer side of STK500v2 as an Arduino Mega's bootloader speaks it, as a sans-IO machine.

An ATmega2560 board resets when a host opens its port and runs arduino's stk500boot.c first.
Old Cura and OctoPrint up to 1.4.0 found printers by talking to that bootloader, then told it
CMD_LEAVE_PROGMODE_ISP, which starts the firmware on the same open connection.

Bytes from the host go in through receive_data(); next_event() yields each well-formed message,
and after LEAVE the hand-over with the bytes that followed it, which are the firmware's to read.
answer() is the reply stk500boot.c builds for a message; send(Reply) frames it for the host.
"""

from dataclasses import dataclass
from enum import Enum, auto

# The message's wire facts are shared (the fault layer frames messages with them).
from fake_marlin.wire.stk500 import HEADER_SIZE as HEADER_SIZE
from fake_marlin.wire.stk500 import MAX_BODY as MAX_BODY
from fake_marlin.wire.stk500 import MESSAGE_START as MESSAGE_START
from fake_marlin.wire.stk500 import TOKEN as TOKEN
from fake_marlin.wire.stk500 import checksum as checksum
from fake_marlin.wire.stk500 import encode_message as encode_message

CMD_SIGN_ON = 0x01
CMD_SET_PARAMETER = 0x02
CMD_GET_PARAMETER = 0x03
CMD_LOAD_ADDRESS = 0x06
CMD_ENTER_PROGMODE_ISP = 0x10
CMD_LEAVE_PROGMODE_ISP = 0x11
CMD_CHIP_ERASE_ISP = 0x12
CMD_READ_FUSE_ISP = 0x18
CMD_READ_SIGNATURE_ISP = 0x1B
CMD_SPI_MULTI = 0x1D

# Commands whose effect no host could see, but LEAVE's hand-over (next_event()): a plain OK.
ACKNOWLEDGED = frozenset(
    (CMD_SET_PARAMETER, CMD_LOAD_ADDRESS, CMD_ENTER_PROGMODE_ISP, CMD_LEAVE_PROGMODE_ISP)
)

STATUS_CMD_OK = 0x00
STATUS_CMD_FAILED = 0xC0

SIGN_ON_NAME = b"AVRISP_2"
SIGNATURE = bytes((0x1E, 0x98, 0x01))  # ATmega2560
# CONFIG_PARAM_* of stk500boot.c; any other parameter reads 0 there.
PARAMETERS = {
    0x80: 0x00,  # PARAM_BUILD_NUMBER_LOW
    0x81: 0x00,  # PARAM_BUILD_NUMBER_HIGH
    0x90: 0x0F,  # PARAM_HW_VER
    0x91: 0x02,  # PARAM_SW_MAJOR
    0x92: 0x0A,  # PARAM_SW_MINOR
}
# An Arduino Mega 2560's fuses as its boards.txt burns them with the bootloader.
LOW_FUSE, HIGH_FUSE, EXTENDED_FUSE = 0xFF, 0xD8, 0xFD
SPI_READ_SIGNATURE = 0x30
SPI_READ_LOW_FUSE = 0x50
SPI_READ_HIGH_FUSE = 0x58


def _signature_byte(index: int) -> int:
    return SIGNATURE[min(index, 2)]  # stk500boot.c answers the last byte for any index past 1


def _spi_answer(instruction: int, address: int) -> int:
    """What stk500boot.c pretends an ISP instruction of CMD_SPI_MULTI read (it has no SPI)."""
    if instruction == SPI_READ_SIGNATURE:
        return _signature_byte(address)
    if instruction == SPI_READ_LOW_FUSE:
        return LOW_FUSE
    if instruction == SPI_READ_HIGH_FUSE:
        return HIGH_FUSE
    return 0


def answer(body: bytes) -> bytes:
    """The body of stk500boot.c's reply to a message body (an ATmega2560 build).

    The board reads argument bytes a short message lacks from whatever its buffer held before;
    we read zeros. Commands that need flash, EEPROM or lock bits behind them fail here: a
    programmer pointed at this printer learns it cannot flash it instead of believing it did.
    """
    command = body[0]
    args = body.ljust(8, b"\0")
    if command == CMD_SIGN_ON:
        return bytes((command, STATUS_CMD_OK, len(SIGN_ON_NAME))) + SIGN_ON_NAME
    if command == CMD_GET_PARAMETER:
        return bytes((command, STATUS_CMD_OK, PARAMETERS.get(args[1], 0)))
    if command in ACKNOWLEDGED:
        return bytes((command, STATUS_CMD_OK))
    if command == CMD_SPI_MULTI:
        # Always one answer byte, whatever numRx asked for, after echoing the instruction.
        tx0 = args[4]
        return bytes((command, STATUS_CMD_OK, 0, tx0, 0, _spi_answer(tx0, args[6]), STATUS_CMD_OK))
    if command == CMD_READ_SIGNATURE_ISP:
        return bytes((command, STATUS_CMD_OK, _signature_byte(args[4]), STATUS_CMD_OK))
    if command == CMD_READ_FUSE_ISP:
        if args[2] == SPI_READ_LOW_FUSE:
            fuse = EXTENDED_FUSE if args[3] == 0x08 else LOW_FUSE
        else:
            fuse = HIGH_FUSE
        return bytes((command, STATUS_CMD_OK, fuse, STATUS_CMD_OK))
    # CMD_CHIP_ERASE_ISP fails on purpose in stk500boot.c (its issue 543); anything it does not
    # know fails too, such as the 0xEE with which Cura asks for a flash checksum command.
    return bytes((command, STATUS_CMD_FAILED))


class BootloaderState(Enum):
    LISTENING = auto()
    LEAVING = auto()  # LEAVE came in: its reply goes out, then the firmware takes over
    LEFT = auto()


# Events out.
@dataclass(frozen=True)
class MessageReceived:
    seq: int
    body: bytes


@dataclass(frozen=True)
class LeftBootloader:
    """The firmware starts: `rest` arrived after LEAVE and is the firmware's to read."""

    rest: bytes


Event = MessageReceived | LeftBootloader


# Events in.
@dataclass(frozen=True)
class Reply:
    seq: int  # the sequence number of the message answered: replies echo it
    body: bytes


class Stk500Protocol:
    def __init__(self) -> None:
        self.state = BootloaderState.LISTENING
        self._input = bytearray()
        self._output = bytearray()

    # -- receiving ---------------------------------------------------------------------
    def receive_data(self, data: bytes) -> None:
        if self.state is BootloaderState.LEFT:
            raise RuntimeError("the bootloader has handed the connection to the firmware")
        self._input += data

    def next_event(self) -> Event | None:
        """The next event the received bytes make, or None when more bytes are needed.

        Answer each message before asking for the next event: after LEAVE the following
        event is the hand-over, and nothing may be said in the bootloader's name after it.
        """
        if self.state is BootloaderState.LEAVING:
            self.state = BootloaderState.LEFT
            rest = bytes(self._input)
            self._input.clear()
            return LeftBootloader(rest)
        if self.state is BootloaderState.LEFT:
            return None
        return self._next_message()

    def _next_message(self) -> MessageReceived | None:
        """stk500boot.c's receive loop, except after a start that leads nowhere.

        The board goes back to waiting for 0x1B after a bad token or checksum and carries on
        from the byte it stopped at, so a stray 0x1B just before a message can cost it that
        message. We look again from the byte after the failed start instead: garbage, or a
        message whose 0x1B was lost, costs no message after it. A message with a bad checksum
        is dropped unanswered, as the board drops it.
        """
        data = self._input
        while True:
            start = data.find(MESSAGE_START)
            if start < 0:
                data.clear()
                return None
            del data[:start]
            if len(data) < HEADER_SIZE:
                return None
            size = data[2] << 8 | data[3]
            if data[4] != TOKEN or not 1 <= size <= MAX_BODY:
                del data[:1]
                continue
            end = HEADER_SIZE + size + 1
            if len(data) < end:
                return None
            if checksum(data[:end]) != 0:
                del data[:1]
                continue
            seq, body = data[1], bytes(data[HEADER_SIZE:end - 1])
            del data[:end]
            if body[0] == CMD_LEAVE_PROGMODE_ISP:
                self.state = BootloaderState.LEAVING
            return MessageReceived(seq, body)

    # -- sending -----------------------------------------------------------------------
    def send(self, event: Reply) -> bytes:
        if not isinstance(event, Reply):
            raise TypeError(f"cannot send {event!r}")
        self._output += encode_message(event.seq, event.body)
        return self.data_to_send()

    def data_to_send(self) -> bytes:
        data = bytes(self._output)
        self._output.clear()
        return data
