"""The Arduino Mega's STK500v2 bootloader that answers first in `--protocol auto`; its hand-over."""

import random
import subprocess
import sys

import pytest
import serial
import trio
from hypothesis import given
from hypothesis import strategies as st

from fake_marlin.emulator.protocols.avr_memory import (
    BOOT_SECTION,
    EEPROM_SIZE,
    FLASH_SIZE,
    PAGE_SIZE,
    BoardMemory,
)
from fake_marlin.emulator.protocols.stk500 import (
    MAX_BODY,
    MAX_READ,
    Bootloader,
    LeftBootloader,
    MessageReceived,
    Answer,
    Stk500Protocol,
    answer,
    encode_message,
)
from fake_marlin.emulator.server.flash_file import FlashFile, FlashFileError
from fake_marlin.emulator.server.lifecycle import ServerConfig
from fake_marlin.emulator.sessions.stk500 import BYTE_TIMEOUT, Stk500Session
from fake_marlin.wire.stk500 import MAX_MESSAGE
from fake_marlin.wire.ultimaker import encode_packet
from tests.conftest import running_printer
from tests.terminal import Terminal, numbered

TEMPERATURES = "T:21.00 /0.00 B:21.00 /0.00 @:0 B@:0"
ENTER = bytes((0x10, 0xC8, 0x64, 0x19, 0x20, 0x00, 0x53, 0x03, 0xAC, 0x53, 0x00, 0x00))
LOAD_ADDRESS = bytes((0x06, 0x80, 0x00, 0x00, 0x00))
LEAVE = b"\x11"
SIGN_ON = b"\x01"


def feed(protocol: Stk500Protocol, data: bytes) -> list:
    """Everything the bytes make, each message answered as the session answers it."""
    protocol.receive_data(data)
    events = []
    while (event := protocol.next_event()) is not None:
        events.append(event)
        if isinstance(event, MessageReceived):
            protocol.send(Answer(event.seq, answer(event.body)))
    return events


def reply_to(seq: int, body: bytes) -> bytes:
    protocol = Stk500Protocol()
    protocol.receive_data(encode_message(seq, body))
    event = protocol.next_event()
    return protocol.send(Answer(event.seq, answer(event.body)))


# -- the wire, against docs/protocols.md section 4 -------------------------------------------
@pytest.mark.parametrize(
    "seq, body, message, reply",
    [
        (1, SIGN_ON, "1b0100010e0114", "1b01000b0e0100084156524953505f3274"),
        (3, b"\xee", None, "1b0300020eeec03a"),
    ],
)
def test_the_reference_vectors(seq, body, message, reply):
    if message is not None:
        assert encode_message(seq, body).hex() == message
    assert reply_to(seq, body).hex() == reply


@pytest.mark.parametrize(
    "body, reply",
    [
        (SIGN_ON, b"\x01\x00\x08AVRISP_2"),
        (ENTER, b"\x10\x00"),
        (LEAVE, b"\x11\x00"),
        (LOAD_ADDRESS, b"\x06\x00"),
        (b"\x02\x98\x01", b"\x02\x00"),  # SET_PARAMETER
        (b"\x12\x00\x00\xac\x80\x00\x00", b"\x12\xc0"),  # CHIP_ERASE_ISP: the board refuses it
        (b"\x03\x90", b"\x03\x00\x0f"),  # GET_PARAMETER: hardware version
        (b"\x03\x91", b"\x03\x00\x02"),  # software major
        (b"\x03\x92", b"\x03\x00\x0a"),  # software minor
        (b"\x03\x98", b"\x03\x00\x00"),  # anything else reads 0
        (b"\x1d\x04\x04\x00\x30\x00\x00\x00", b"\x1d\x00\x00\x30\x00\x1e\x00"),  # SPI_MULTI
        (b"\x1d\x04\x04\x00\x30\x00\x01\x00", b"\x1d\x00\x00\x30\x00\x98\x00"),
        (b"\x1d\x04\x04\x00\x30\x00\x02\x00", b"\x1d\x00\x00\x30\x00\x01\x00"),
        (b"\x1d\x04\x04\x00\xa0\x00\x00\x00", b"\x1d\x00\x00\xa0\x00\x00\x00"),  # other reads: 0
        (b"\x1b\x04\x30\x00\x01\x00", b"\x1b\x00\x98\x00"),  # READ_SIGNATURE_ISP
        (b"\xee", b"\xee\xc0"),  # Cura's question for a flash checksum command
        (b"\x13\x00\x02\xc1\x0a\x40\x4c\x20\x00\x00\xff\xff", b"\x13\x00"),  # a word of flash
        (b"\x14\x00\x04\x20", b"\x14\x00\xff\xff\xff\xff\x00"),  # READ_FLASH: erased
        (b"\x16\x00\x02\xa0", b"\x16\x00\xff\xff\x00"),  # READ_EEPROM: erased
        (b"\x1a\x00\x58\x00\x00\x00", b"\x1a\x00\xcf\x00"),  # READ_LOCK: 0x0F as burnt
        (b"\x18\x00\x50\x00\x00\x00", b"\x18\x00\xff\x00"),  # READ_FUSE: low
        (b"\x18\x00\x58\x08\x00\x00", b"\x18\x00\xd8\x00"),  # high
        (b"\x18\x00\x50\x08\x00\x00", b"\x18\x00\xfd\x00"),  # extended
        (b"\x17\x00\xac\xa0\x00\xff", b"\x17\xc0"),  # PROGRAM_FUSE: not from a bootloader
        (b"\x1d", b"\x1d\x00\x00\x00\x00\x00\x00"),  # arguments a short message lacks read as 0
    ],
)
def test_the_bootloader_answers_as_stk500boot_does(body, reply):
    assert answer(body) == reply


def test_replies_echo_the_sequence_number_whatever_it_is():
    for seq in (0, 1, 2, 200, 255):
        assert reply_to(seq, ENTER) == encode_message(seq, b"\x10\x00")


def test_a_bad_checksum_is_dropped_unanswered_and_the_next_message_is_read():
    protocol = Stk500Protocol()
    damaged = bytearray(encode_message(1, SIGN_ON))
    damaged[-1] ^= 0x40
    events = feed(protocol, bytes(damaged) + encode_message(2, ENTER))
    assert events == [MessageReceived(2, ENTER)]
    assert protocol.data_to_send() == b""  # only the ENTER reply went out, through send()


@pytest.mark.parametrize(
    "before",
    [
        b"\x00\xffM105\n\x0e",  # garbage without a start byte
        b"\x1b",  # a stray start byte
        b"\x1b\x01\x00",  # a message cut short by a lost byte
        encode_message(1, ENTER)[1:],  # a message whose 0x1B was lost
        b"\x1b\x05\x7f\xff\x0e",  # a length no body has: no waiting for 32767 bytes
        b"\x1b\x05\x00\x00\x0e",  # an empty body
    ],
)
def test_damage_before_a_message_costs_no_message_after_it(before):
    events = feed(Stk500Protocol(), before + encode_message(7, SIGN_ON))
    assert events[-1] == MessageReceived(7, SIGN_ON)


def test_messages_split_anywhere_are_read_whole():
    protocol = Stk500Protocol()
    events = []
    for byte in encode_message(1, SIGN_ON) + encode_message(2, ENTER):
        events += feed(protocol, bytes((byte,)))
    assert events == [MessageReceived(1, SIGN_ON), MessageReceived(2, ENTER)]


def test_leave_hands_the_bytes_after_it_to_the_firmware():
    protocol = Stk500Protocol()
    events = feed(protocol, encode_message(4, LEAVE) + b"M105\n" + encode_message(5, SIGN_ON))
    rest = b"M105\n" + encode_message(5, SIGN_ON)
    assert events == [MessageReceived(4, LEAVE), LeftBootloader(rest)]
    assert protocol.next_event() is None
    with pytest.raises(RuntimeError):
        protocol.receive_data(b"G28\n")


def test_the_encoder_refuses_what_cannot_be_framed():
    with pytest.raises(ValueError):
        encode_message(256, SIGN_ON)
    with pytest.raises(ValueError):
        encode_message(1, bytes(0x10000))


@given(st.lists(st.binary(max_size=64), max_size=20))
def test_arbitrary_bytes_never_crash_the_parser(chunks):
    protocol = Stk500Protocol()
    for chunk in chunks:
        events = feed(protocol, chunk)
        for event in events:
            assert isinstance(event, (MessageReceived, LeftBootloader))
        if events and isinstance(events[-1], LeftBootloader):
            break


bodies = st.binary(min_size=1, max_size=MAX_BODY).filter(lambda body: body[0] != LEAVE[0])


@given(
    st.lists(st.tuples(st.integers(0, 255), bodies), min_size=1, max_size=5),
    st.binary(max_size=32).map(lambda garbage: garbage.replace(b"\x1b", b"")),
    st.integers(1, 64),
)
def test_encoded_messages_parse_back_whatever_the_chunking(messages, garbage, chunk_size):
    wire = garbage + b"".join(encode_message(seq, body) for seq, body in messages)
    protocol = Stk500Protocol()
    events = []
    for at in range(0, len(wire), chunk_size):
        events += feed(protocol, wire[at:at + chunk_size])
    assert events == [MessageReceived(seq, body) for seq, body in messages]


# -- flashing: the bootloader over the board's memories (as stk500boot.c does it) -------------
OLD_FLASH = random.Random(2560).randbytes(FLASH_SIZE)  # what an earlier firmware left


def load(word_address: int, extended: bool = True) -> bytes:
    """LOAD_ADDRESS as avrdude sends it: bit 31 set for flash on a chip past 64 KiB."""
    return b"\x06" + (word_address | (extended << 31)).to_bytes(4, "big")


def program_flash(data: bytes) -> bytes:
    return b"\x13" + len(data).to_bytes(2, "big") + b"\xc1\x0a\x40\x4c\x20\x00\x00" + data


def read_flash(size: int) -> bytes:
    return b"\x14" + size.to_bytes(2, "big") + b"\x20"


def program_eeprom(data: bytes) -> bytes:
    return b"\x15" + len(data).to_bytes(2, "big") + b"\xc1\x0a\xc1\xc2\xa0\x00\x00" + data


def read_eeprom(size: int) -> bytes:
    return b"\x16" + size.to_bytes(2, "big") + b"\xa0"


def read_reply(command: int, data: bytes) -> bytes:
    return bytes((command, 0x00)) + data + b"\x00"


def fresh(flash: bytes | None = None) -> Bootloader:
    """A bootloader just reset, on a board holding `flash` (default: erased)."""
    return Bootloader(BoardMemory(flash))


@pytest.mark.parametrize(
    "arguments, address",
    [
        (b"\x80\x00\x00\x00", 0x00000),
        (b"\x00\x00\x00\x01", 0x00002),  # a word address: the byte address is twice it
        (b"\x80\x00\x80\x00", 0x10000),  # past 64 KiB
        (b"\x80\x01\x00\x00", 0x20000),  # past 128 KiB: a word address past 0xFFFF
        (b"\x80\x01\xff\x80", 0x3FF00),  # the last page
        (b"\xff\xff\xff\xff", 0xFFFFFFFE),  # doubled in 32 bits: bit 31 drops out
        (b"\x00\x00", 0x00000),  # arguments a short message lacks read as 0
    ],
)
def test_load_address_doubles_the_word_address_in_32_bits(arguments, address):
    bootloader = fresh()
    assert bootloader.answer(b"\x06" + arguments) == b"\x06\x00"
    assert bootloader.address == address


@given(st.integers(0, FLASH_SIZE // 2 - 1), st.booleans(), st.integers(1, MAX_READ // 2))
def test_reads_come_from_the_doubled_address_and_move_on_past_what_they_read(word, extended, words):
    bootloader, size = fresh(OLD_FLASH), 2 * words
    bootloader.answer(load(word, extended))
    expected = bytes(OLD_FLASH[(2 * word + i) % FLASH_SIZE] for i in range(2 * size))
    assert bootloader.answer(read_flash(size)) == read_reply(0x14, expected[:size])
    assert bootloader.answer(read_flash(size)) == read_reply(0x14, expected[size:])


@given(
    st.lists(st.binary(min_size=PAGE_SIZE, max_size=PAGE_SIZE), min_size=1, max_size=6),
    st.booleans(),
)
def test_pages_written_in_order_from_the_start_hold_them_over_any_old_flash(pages, load_each):
    """avrdude's flash write: each page erased by the count just before it is written."""
    bootloader = fresh(OLD_FLASH)
    bootloader.answer(load(0))
    for number, page in enumerate(pages):
        if load_each:  # avrdude loads each page's address; the board also counts on by itself
            assert bootloader.answer(load(number * PAGE_SIZE // 2)) == b"\x06\x00"
        assert bootloader.answer(program_flash(page)) == b"\x13\x00"
    written = b"".join(pages)
    assert bootloader.memory.flash == written + OLD_FLASH[len(written):]
    assert bootloader.memory.take_changed_pages() == list(range(len(pages)))


def test_a_page_written_out_of_turn_is_not_erased_first_and_the_turns_page_is():
    """stk500boot.c erases the next page of its count, whatever page it writes: a page not
    written in turn keeps the bits its old content had at 0 (its flash cells only lose charge)."""
    bootloader, data = fresh(OLD_FLASH), bytes(range(256))
    bootloader.answer(load(0x1000 // 2))
    bootloader.answer(program_flash(data))
    flash = bootloader.memory.flash
    assert flash[:PAGE_SIZE] == b"\xff" * PAGE_SIZE
    old = OLD_FLASH[0x1000:0x1100]
    assert flash[0x1000:0x1100] == bytes(a & b for a, b in zip(old, data))


def test_chip_erase_fails_but_starts_the_erase_count_again():
    bootloader = fresh()
    for page in (b"\x00" * PAGE_SIZE, b"\x0f" * PAGE_SIZE):
        bootloader.answer(load(0))
        bootloader.answer(program_flash(page))  # the second is page 0 unerased: 0x00 stays
    assert bootloader.memory.flash[:PAGE_SIZE] == b"\x00" * PAGE_SIZE
    assert bootloader.answer(b"\x12\x00\x00\xac\x80\x00\x00") == b"\x12\xc0"
    bootloader.answer(load(0))
    bootloader.answer(program_flash(b"\x0f" * PAGE_SIZE))
    assert bootloader.memory.flash[:PAGE_SIZE] == b"\x0f" * PAGE_SIZE


def test_a_write_from_mid_page_wraps_to_that_pages_start():
    """The page buffer is indexed by the address within the page and written to one page."""
    bootloader, data = fresh(), bytes(range(256))
    bootloader.answer(load((PAGE_SIZE + 0x80) // 2))
    bootloader.answer(program_flash(data))
    assert bootloader.memory.flash[PAGE_SIZE:2 * PAGE_SIZE] == data[0x80:] + data[:0x80]
    assert bootloader.address == 2 * PAGE_SIZE + 0x80


def test_a_short_write_leaves_the_rest_of_its_page_as_it_was():
    bootloader = fresh()
    bootloader.answer(load(0x102 // 2))
    bootloader.answer(program_flash(b"\x12\x34"))
    flash = bootloader.memory.flash
    assert flash[0x100:0x108] == b"\xff\xff\x12\x34\xff\xff\xff\xff"
    # The next word, at the address kept; but the count's second erase is this very page.
    bootloader.answer(program_flash(b"\x56\x78"))
    assert flash[0x100:0x108] == b"\xff\xff\xff\xff\x56\x78\xff\xff"


def test_the_bootloaders_own_section_cannot_be_written():
    bootloader = fresh()
    bootloader.answer(load(BOOT_SECTION // 2))
    assert bootloader.answer(program_flash(b"\x00" * PAGE_SIZE)) == b"\x13\x00"  # it says OK
    assert bootloader.memory.flash[BOOT_SECTION:] == b"\xff" * (FLASH_SIZE - BOOT_SECTION)
    assert bootloader.memory.take_changed_pages() == [0]  # only the count's erase of page 0


def test_lock_bits_once_programmed_forbid_writing_the_application():
    bootloader = fresh()
    assert bootloader.answer(b"\x1a\x00\x58\x00\x00\x00") == b"\x1a\x00\xcf\x00"
    # avrdude's lock write of 0xCB: BLB01 programmed, so SPM may not write the application.
    assert bootloader.answer(b"\x19\xac\xe0\x00\xcb") == b"\x19\x00\x00"
    assert bootloader.answer(b"\x1a\x00\x58\x00\x00\x00") == b"\x1a\x00\xcb\x00"
    bootloader.answer(load(0))
    assert bootloader.answer(program_flash(b"\x00" * PAGE_SIZE)) == b"\x13\x00"
    assert bootloader.memory.flash[:PAGE_SIZE] == b"\xff" * PAGE_SIZE
    bootloader.answer(b"\x19\xac\xe0\x00\xff")  # a lock bit once programmed stays so
    assert bootloader.answer(b"\x1a\x00\x58\x00\x00\x00") == b"\x1a\x00\xcb\x00"


@pytest.mark.parametrize(
    "body",
    [
        program_flash(b""),  # the board's do-while writes a word, then loops for ever
        program_flash(b"\x00" * 3),  # an odd size: the same
        program_flash(b"\x00" * (PAGE_SIZE + 2)),  # more than its page buffer holds
        program_flash(b"\x00" * 8)[:-2],  # a size the message does not carry
        program_eeprom(b"\x00" * 8)[:-1],
        read_flash(0),
        read_flash(7),
        read_flash(MAX_READ + 2),  # a reply longer than its buffer
        read_eeprom(0),
        read_eeprom(MAX_READ + 1),
    ],
)
def test_sizes_the_board_cannot_take_fail_and_change_nothing(body):
    bootloader = fresh(OLD_FLASH)
    bootloader.answer(load(0x40))
    assert bootloader.answer(body) == bytes((body[0], 0xC0))
    assert bootloader.memory.flash == OLD_FLASH
    assert bootloader.memory.eeprom == b"\xff" * EEPROM_SIZE
    assert bootloader.address == 0x80


def test_the_largest_read_fits_the_buffer_and_reads_wrap_at_the_end_of_the_flash():
    bootloader = fresh(OLD_FLASH)
    bootloader.answer(load(FLASH_SIZE // 2 - 2))
    reply = bootloader.answer(read_flash(MAX_READ))
    assert reply == read_reply(0x14, OLD_FLASH[-4:] + OLD_FLASH[:MAX_READ - 4])
    assert len(encode_message(1, reply)) <= MAX_MESSAGE


@given(st.integers(0, 0xFFFF), st.binary(max_size=MAX_BODY - 10))
def test_eeprom_writes_go_to_the_byte_address_load_gave(address, data):
    bootloader = fresh()
    bootloader.answer(load(address, extended=False))
    assert bootloader.answer(program_eeprom(data)) == b"\x15\x00"
    expected = bytearray(b"\xff" * EEPROM_SIZE)
    for i, value in enumerate(data):
        expected[(address + i) % EEPROM_SIZE] = value
    assert bootloader.memory.eeprom == expected


@pytest.mark.parametrize(
    "address, size, start",
    [
        (0, 8, 0),  # avrdude's first block reads back right
        (8, 8, 16),  # its next ones come from twice their address (ArduinoCore-avr issue 129)
        (16, 8, 32),
        (0, 256, 0),  # one read runs on byte by byte
        (0x900, 4, 0x200),  # the 12-bit EEPROM address wraps
    ],
)
def test_eeprom_reads_come_from_the_doubled_address_as_on_the_board(address, size, start):
    bootloader = fresh()
    contents = random.Random(address).randbytes(EEPROM_SIZE)
    bootloader.memory.eeprom[:] = contents
    bootloader.answer(load(address, extended=False))
    expected = bytes(contents[(start + i) % EEPROM_SIZE] for i in range(size))
    assert bootloader.answer(read_eeprom(size)) == read_reply(0x16, expected)


# -- a printer on an in-memory link ----------------------------------------------------------
class Programmer:
    """A host's STK500v2 side, as Cura's and OctoPrint's stk500v2.py: a message, then its reply."""

    def __init__(self, stream) -> None:
        self.stream = stream
        self.seq = 1
        self.unread = b""  # whatever came after the last reply

    async def send_message(self, body: bytes) -> bytes:
        """The whole reply, checked for the sequence number and the checksum."""
        await self.stream.send_all(encode_message(self.seq, body))
        data = self.unread
        with trio.fail_after(5):
            while len(data) < 5 or len(data) < 6 + int.from_bytes(data[2:4], "big"):
                data += await self.stream.receive_some(4096)
        size = 6 + int.from_bytes(data[2:4], "big")
        reply, self.unread = data[:size], data[size:]
        assert reply == encode_message(self.seq, reply[5:-1])
        self.seq = (self.seq + 1) & 0xFF
        return reply

    async def body(self, body: bytes) -> bytes:
        return (await self.send_message(body))[5:-1]


async def old_cura_probe(programmer: Programmer) -> None:
    """Cura's stk500v2.connect() then leaveISP(), byte for byte (still in Cura 4.8)."""
    assert await programmer.body(ENTER) == b"\x10\x00"
    assert await programmer.body(LOAD_ADDRESS) == b"\x06\x00"
    assert (await programmer.send_message(b"\xee")).hex() == "1b0300020eeec03a"
    assert await programmer.body(LEAVE) == b"\x11\x00"


async def test_old_curas_probe_then_m105_meets_the_firmware(autojump_clock):
    async with running_printer(ServerConfig(protocol="auto")) as running:
        programmer = Programmer(running.link.open_host())
        await old_cura_probe(programmer)
        assert programmer.unread == b""
        terminal = Terminal(programmer.stream)
        assert await terminal.quiet_for(1) == []  # the greeting waits for the firmware's protocol
        assert running.server.protocol_name is None
        lines = await terminal.command("M105")
        assert lines[0] == "start" and lines[1] == " External Reset"
        assert lines[-1] == f"ok {TEMPERATURES}"
        assert running.server.protocol_name == "marlin"
        assert running.journal == ["M105"]


async def test_octoprint_up_to_1_4_0_signs_on_enters_and_leaves_then_speaks_marlin(autojump_clock):
    async with running_printer(ServerConfig(protocol="auto")) as running:
        programmer = Programmer(running.link.open_host())
        reply = await programmer.send_message(SIGN_ON)
        assert reply.hex() == "1b01000b0e0100084156524953505f3274"
        assert await programmer.body(ENTER) == b"\x10\x00"
        assert await programmer.body(LEAVE) == b"\x11\x00"
        terminal = Terminal(programmer.stream)
        lines = await terminal.command("N0 M110 N0*125")
        assert lines[0] == "start" and lines[-1] == "ok"
        assert await terminal.command(numbered(1, "M105")) == [f"ok {TEMPERATURES}"]


async def test_the_ultimaker_protocol_after_leave(autojump_clock):
    async with running_printer(ServerConfig(protocol="auto")) as running:
        programmer = Programmer(running.link.open_host())
        await old_cura_probe(programmer)
        host = programmer.stream
        await host.send_all(encode_packet(0, b"M105"))
        received = b""
        with trio.fail_after(5):
            while b"\no00" not in received:
                received += await host.receive_some(4096)
        assert received.startswith(b"LOG:Marlin started\n\nq000F98\n")
        assert f"\n{TEMPERATURES}\n".encode() in received
        assert running.server.protocol_name == "ultimaker"


async def test_what_follows_leave_in_the_same_write_reaches_the_firmware(autojump_clock):
    async with running_printer(ServerConfig(protocol="auto")) as running:
        host = running.link.open_host()
        await host.send_all(encode_message(1, LEAVE) + b"M105\n")
        received = b""
        with trio.fail_after(5):
            while b"ok T:" not in received:
                received += await host.receive_some(4096)
        assert received.startswith(encode_message(1, b"\x11\x00") + b"start\n")


async def test_after_leave_the_bootloader_is_gone_until_the_next_reset(autojump_clock):
    async with running_printer(ServerConfig(protocol="auto")) as running:
        programmer = Programmer(running.link.open_host())
        await old_cura_probe(programmer)
        await programmer.stream.send_all(encode_message(5, SIGN_ON))  # noise to the firmware
        terminal = Terminal(programmer.stream)
        assert await terminal.quiet_for(2) == []
        assert (await terminal.command("M105"))[-1] == f"ok {TEMPERATURES}"
        again = Programmer(running.link.open_host())  # a reopen resets the board
        assert await again.body(SIGN_ON) == b"\x01\x00\x08AVRISP_2"


async def test_a_quiet_bootloader_starts_the_firmware_on_its_own(autojump_clock):
    async with running_printer(ServerConfig(protocol="auto")) as running:
        host = running.link.open_host()
        await host.send_all(encode_message(1, SIGN_ON)[:3])  # then nothing more
        await trio.sleep(BYTE_TIMEOUT + 1)
        terminal = Terminal(host)
        lines = await terminal.command("M105")
        assert lines[0] == "start" and lines[-1] == f"ok {TEMPERATURES}"


async def test_a_bad_checksum_gets_no_reply_from_the_printer_either(autojump_clock):
    async with running_printer(ServerConfig(protocol="auto")) as running:
        host = running.link.open_host()
        damaged = bytearray(encode_message(1, SIGN_ON))
        damaged[-1] ^= 1
        await host.send_all(bytes(damaged))
        with trio.move_on_after(1):
            unexpected = await host.receive_some(4096)
            pytest.fail(f"the printer answered a damaged message: {unexpected!r}")
        programmer = Programmer(host)
        assert await programmer.body(SIGN_ON) == b"\x01\x00\x08AVRISP_2"


async def test_the_flash_outlives_resets_it_is_the_boards(autojump_clock):
    page = bytes(range(256))
    async with running_printer(ServerConfig(protocol="auto")) as running:
        programmer = Programmer(running.link.open_host())
        assert await programmer.body(ENTER) == b"\x10\x00"
        assert await programmer.body(load(0x8000)) == b"\x06\x00"  # 64 KiB in
        assert await programmer.body(program_flash(page)) == b"\x13\x00"
        assert await programmer.body(LEAVE) == b"\x11\x00"
        again = Programmer(running.link.open_host())  # a reopen resets the board
        assert await again.body(load(0x8000)) == b"\x06\x00"
        assert await again.body(read_flash(256)) == read_reply(0x14, page)
        assert running.server.memory.flash[0x10000:0x10100] == page
        assert running.server.boots == 3  # power-up, then a reset at each open


async def test_a_page_cut_off_by_a_reset_is_lost_and_the_pages_before_it_kept(autojump_clock):
    pages = [bytes((n,)) * PAGE_SIZE for n in range(3)]
    async with running_printer(ServerConfig(protocol="auto")) as running:
        programmer = Programmer(running.link.open_host())
        await programmer.body(ENTER)
        for page in pages[:2]:
            assert await programmer.body(program_flash(page)) == b"\x13\x00"
        await programmer.stream.send_all(encode_message(9, program_flash(pages[2]))[:100])
        terminal = Terminal(running.link.open_host())  # avrdude killed; a host opens the port
        lines = await terminal.command("M105")
        assert lines[0] == "start" and lines[-1] == f"ok {TEMPERATURES}"
        flash = running.server.memory.flash
        assert flash[:3 * PAGE_SIZE] == pages[0] + pages[1] + b"\xff" * PAGE_SIZE


def test_the_flash_is_saved_before_the_host_hears_it_was_written():
    events: list[object] = []
    memory = BoardMemory()

    def save() -> None:
        events.append(("saved", memory.take_changed_pages()))

    session = Stk500Session(events.append, lambda: pytest.fail("no LEAVE was sent"), memory, save)
    session.feed(encode_message(1, load(0)) + encode_message(2, program_flash(b"\x00" * 256)))
    assert events == [
        encode_message(1, b"\x06\x00"), ("saved", [0]), encode_message(2, b"\x13\x00")
    ]


# -- --flash-file -----------------------------------------------------------------------------
def test_a_missing_flash_file_is_made_erased_and_pages_go_to_it_in_place(tmp_path):
    path = tmp_path / "mega.bin"
    flash = FlashFile.open(path)
    assert path.read_bytes() == b"\xff" * FLASH_SIZE
    flash.memory.erase_page(0x20100)
    flash.memory.write_page(0x20100, bytes(range(256)))
    flash.save()
    expected = bytearray(b"\xff" * FLASH_SIZE)
    expected[0x20100:0x20200] = bytes(range(256))
    assert path.read_bytes() == expected  # on disk before close: a kill loses nothing
    flash.close()
    assert FlashFile.open(path).memory.flash == expected


@pytest.mark.e2e
@pytest.mark.parametrize(
    "make, args, message",
    [
        (lambda path: path.write_bytes(b"\xff" * 1000), [], "1000 bytes, but an ATmega2560's"),
        (lambda path: path.mkdir(), [], "Is a directory"),
        (lambda path: None, ["--printers", "2"], "with --printers, put {n} in it"),
    ],
)
def test_a_flash_file_that_cannot_be_used_is_a_clear_error(tmp_path, make, args, message):
    path = tmp_path / "mega.bin"
    make(path)
    done = subprocess.run(
        [sys.executable, "-m", "fake_marlin.emulator.cli", "--flash-file", str(path), *args],
        capture_output=True, text=True, timeout=60,
    )
    assert done.returncode == 2 and message in done.stderr, done.stderr
    assert "Traceback" not in done.stderr and done.stdout == ""


def test_a_flash_file_in_a_missing_directory_is_a_clear_error(tmp_path):
    with pytest.raises(FlashFileError, match="No such file or directory"):
        FlashFile.open(tmp_path / "gone" / "mega.bin")


# -- the real program over a real pty (fake_printer: fake-marlin with its defaults) ----------
def read_message(port: serial.Serial) -> bytes:
    header = port.read(5)
    assert len(header) == 5 and header[0] == 0x1B, header
    rest = port.read(int.from_bytes(header[2:4], "big") + 1)
    return header + rest


@pytest.mark.e2e
def test_curas_probe_then_m105_over_a_real_pty(fake_printer):
    with serial.Serial(fake_printer.port, 115200, timeout=5) as port:
        for seq, body, reply in [
            (1, ENTER, b"\x10\x00"),
            (2, LOAD_ADDRESS, b"\x06\x00"),
            (3, b"\xee", b"\xee\xc0"),
            (4, LEAVE, b"\x11\x00"),
        ]:
            port.write(encode_message(seq, body))
            assert read_message(port) == encode_message(seq, reply)
        port.write(b"M105\n")
        lines = []
        while not lines or not lines[-1].startswith("ok"):
            line = port.readline()
            assert line.endswith(b"\n"), lines
            lines.append(line.decode("ascii").strip())
        assert lines[0] == "start" and lines[-1] == f"ok {TEMPERATURES}"
