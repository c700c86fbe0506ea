"""The printer side of STK500v2 as an Arduino Mega's bootloader speaks it, as a sans-IO machine.

An ATmega2560 board resets when a host opens its port and runs arduino's stk500boot.c first.
avrdude (`-c wiring`, `-c stk500v2`) flashes the firmware through it; old Cura and OctoPrint up
to 1.4.0 found printers by talking to it, then told it CMD_LEAVE_PROGMODE_ISP, which starts the
firmware on the same open connection.

Bytes from the host go in through receive_data(); next_event() yields each well-formed message,
and after LEAVE the hand-over with the bytes that followed it, which are the firmware's to read.
Bootloader.answer() is the reply stk500boot.c builds for a message, acting on the board's
memories (avr_memory.BoardMemory); send(Answer) frames it for the host.
"""

from dataclasses import dataclass
from typing import TYPE_CHECKING
from enum import Enum, auto

from fake_marlin.emulator.protocols.avr_memory import PAGE_SIZE, BoardMemory

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
CMD_PROGRAM_FLASH_ISP = 0x13
CMD_READ_FLASH_ISP = 0x14
CMD_PROGRAM_EEPROM_ISP = 0x15
CMD_READ_EEPROM_ISP = 0x16
CMD_READ_FUSE_ISP = 0x18
CMD_PROGRAM_LOCK_ISP = 0x19
CMD_READ_LOCK_ISP = 0x1A
CMD_READ_SIGNATURE_ISP = 0x1B
CMD_SPI_MULTI = 0x1D

# Commands whose effect no host could see, but LEAVE's hand-over (next_event()): a plain OK.
ACKNOWLEDGED = frozenset((CMD_SET_PARAMETER, CMD_ENTER_PROGMODE_ISP, CMD_LEAVE_PROGMODE_ISP))

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
# stk500boot.c erases pages only below its APP_END, FLASHEND - 2 * BOOTSIZE + 1 with BOOTSIZE
# 8192: 16 KiB short of the end, twice the Mega's boot section.
ERASE_END = 0x3C000
DATA_OFFSET = 10  # PROGRAM_*_ISP: size, mode, delay, three ISP commands and two poll values first
MAX_READ = MAX_BODY - 3  # a READ_*_ISP reply (command, status, data, status) fills msgBuffer


def _signature_byte(index: int) -> int:
    return SIGNATURE[min(index, 2)]  # stk500boot.c answers the last byte for any index past 1


def _spi_answer(instruction: int, address: int) -> int:
    """What stk500boot.c pretends an ISP instruction of CMD_SPI_MULTI read (it has no SPI)."""
    if instruction == SPI_READ_SIGNATURE:
        return _signature_byte(address)
    if instruction == SPI_READ_LOW_FUSE:
        return LOW_FUSE
    if instruction == SPI_READ_HIGH_FUSE:
        return HIGH_FUSE  # the lock byte's instruction starts with 0x58 too: it reads this
    return 0


class Bootloader:
    """stk500boot.c (an ATmega2560 build) from one reset to its LEAVE, over the board's memories.

    It keeps a byte address, LOAD_ADDRESS's word address doubled in 32 bits (so avrdude's
    bit 31, its flag for the upper 64 KiB, drops out), which each read and write moves past what
    it covered. Each PROGRAM_FLASH erases first the next page of a count that starts at 0 on
    reset and on CHIP_ERASE, whatever page it then writes: written in order from the start, as
    avrdude writes, each page is erased just before it is written. CHIP_ERASE itself answers
    FAILED, as on the board (its issue 543), and avrdude stops there unless given -D.

    The board reads argument bytes a short message lacks from whatever its buffer held before;
    we read zeros. Where the board would run past its buffers or loop for ever (odd or zero
    flash sizes, more than a page, data the message does not hold), we answer FAILED and
    change nothing.
    """

    def __init__(self, memory: BoardMemory) -> None:
        self.memory = memory
        self.address = 0
        self.erase_address = 0

    def answer(self, body: bytes) -> bytes:
        command = body[0]
        args = body.ljust(8, b"\0")
        size = args[1] << 8 | args[2]
        if command == CMD_SIGN_ON:
            return bytes((command, STATUS_CMD_OK, len(SIGN_ON_NAME))) + SIGN_ON_NAME
        if command == CMD_GET_PARAMETER:
            return bytes((command, STATUS_CMD_OK, PARAMETERS.get(args[1], 0)))
        if command in ACKNOWLEDGED:
            return bytes((command, STATUS_CMD_OK))
        if command == CMD_LOAD_ADDRESS:
            self.address = int.from_bytes(args[1:5], "big") << 1 & 0xFFFFFFFF
            return bytes((command, STATUS_CMD_OK))
        if command == CMD_SPI_MULTI:
            # Always one answer byte, whatever numRx asked for, after echoing the instruction.
            tx0, answer_byte = args[4], _spi_answer(args[4], args[6])
            return bytes((command, STATUS_CMD_OK, 0, tx0, 0, answer_byte, STATUS_CMD_OK))
        if command == CMD_READ_SIGNATURE_ISP:
            return self._byte_reply(command, _signature_byte(args[4]))
        if command == CMD_READ_FUSE_ISP:
            if args[2] == SPI_READ_LOW_FUSE:
                return self._byte_reply(command, EXTENDED_FUSE if args[3] == 0x08 else LOW_FUSE)
            return self._byte_reply(command, HIGH_FUSE)
        if command == CMD_READ_LOCK_ISP:
            return self._byte_reply(command, self.memory.lock)
        if command == CMD_PROGRAM_LOCK_ISP:
            self.memory.program_lock_bits(~args[4] & 0xFF)
            return bytes((command, STATUS_CMD_OK, STATUS_CMD_OK))
        if command == CMD_CHIP_ERASE_ISP:
            self.erase_address = 0
        elif command == CMD_PROGRAM_FLASH_ISP and self._page_fits(body, size):
            self._program_flash(body[DATA_OFFSET:DATA_OFFSET + size])
            return bytes((command, STATUS_CMD_OK))
        elif command == CMD_PROGRAM_EEPROM_ISP and len(body) >= DATA_OFFSET + size:
            for value in body[DATA_OFFSET:DATA_OFFSET + size]:
                self.memory.write_eeprom(self.address >> 1, value)
                self.address += 2  # the EEPROM byte address is the word address LOAD gave
            return bytes((command, STATUS_CMD_OK))
        elif command == CMD_READ_FLASH_ISP and 2 <= size <= MAX_READ and size % 2 == 0:
            data = self.memory.read_flash(self.address, size)
            self.address += size
            return bytes((command, STATUS_CMD_OK)) + data + bytes((STATUS_CMD_OK,))
        elif command == CMD_READ_EEPROM_ISP and 1 <= size <= MAX_READ:
            # The board reads from the doubled address, so past its first block avrdude reads
            # other bytes than it wrote (ArduinoCore-avr issue 129): as on the board.
            data = bytes(self.memory.read_eeprom(self.address + i) for i in range(size))
            self.address += size
            return bytes((command, STATUS_CMD_OK)) + data + bytes((STATUS_CMD_OK,))
        # Anything it does not know fails too, such as the 0xEE with which Cura asks for a
        # flash checksum command.
        return bytes((command, STATUS_CMD_FAILED))

    @staticmethod
    def _byte_reply(command: int, value: int) -> bytes:
        return bytes((command, STATUS_CMD_OK, value, STATUS_CMD_OK))

    @staticmethod
    def _page_fits(body: bytes, size: int) -> bool:
        """Whole words, at most the page buffer, all of them in the message."""
        return 0 < size <= PAGE_SIZE and size % 2 == 0 and len(body) >= DATA_OFFSET + size

    def _program_flash(self, data: bytes) -> None:
        memory = self.memory
        if self.erase_address < ERASE_END:
            memory.erase_page(self.erase_address)
            self.erase_address += PAGE_SIZE
        # The page buffer is indexed by the address within its page and written whole, so
        # data that runs past the page's end wraps to its start; words not filled stay 0xFF.
        page_buffer = bytearray(b"\xff" * PAGE_SIZE)
        for i, value in enumerate(data):
            page_buffer[(self.address + i) % PAGE_SIZE] = value
        memory.write_page(self.address, bytes(page_buffer))
        self.address += len(data)


def answer(body: bytes) -> bytes:
    """The reply of a bootloader just reset, on a board whose memories are erased."""
    return Bootloader(BoardMemory()).answer(body)


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
class Answer:
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
    def send(self, event: Answer) -> bytes:
        if not isinstance(event, Answer):
            raise TypeError(f"cannot send {event!r}")
        self._output += encode_message(event.seq, event.body)
        return self.data_to_send()

    def data_to_send(self) -> bytes:
        data = bytes(self._output)
        self._output.clear()
        return data


if TYPE_CHECKING:  # mypy holds the machine to the shared interface
    from fake_marlin.emulator.protocols.base import ProtocolMachine

    _: type[ProtocolMachine[Event, Answer]] = Stk500Protocol
