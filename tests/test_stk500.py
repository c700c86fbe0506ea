"""The Arduino Mega's STK500v2 bootloader that answers first in `--protocol auto`; its hand-over."""

import pytest
import serial
import trio
from hypothesis import given
from hypothesis import strategies as st

from fake_marlin.emulator.protocols.stk500 import (
    MAX_BODY,
    LeftBootloader,
    MessageReceived,
    Reply,
    Stk500Protocol,
    answer,
    encode_message,
)
from fake_marlin.emulator.server.lifecycle import ServerConfig
from fake_marlin.emulator.sessions.stk500 import BYTE_TIMEOUT
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
            protocol.send(Reply(event.seq, answer(event.body)))
    return events


def reply_to(seq: int, body: bytes) -> bytes:
    protocol = Stk500Protocol()
    protocol.receive_data(encode_message(seq, body))
    event = protocol.next_event()
    return protocol.send(Reply(event.seq, answer(event.body)))


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
        (b"\x13\x00\x02\xc1\x0a\x40\x4c\x20\x00\x00\xff\xff", b"\x13\xc0"),  # no flash to program
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
        assert lines[0] == "start" and lines[1] == "echo: External Reset"
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
