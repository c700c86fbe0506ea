"""Repetier's protocol: the binary codec, the firmware's receiver, the session and the host."""

import struct

import pytest
import trio
import trio.testing
from hypothesis import given, settings
from hypothesis import strategies as st

from fake_marlin.emulator.faults.layer import FaultConfig, parse_fault
from fake_marlin.emulator.journal.verify import verify
from fake_marlin.emulator.protocols.repetier import (
    CommandReceived,
    CommandRejected,
    Done,
    EmergencyStop,
    RepetierProtocol,
)
from fake_marlin.emulator.server.lifecycle import ServerConfig
from fake_marlin.host.codecs import repetier as host_codec
from fake_marlin.host.connect import connect
from fake_marlin.wire import repetier
from fake_marlin.wire.gcode import canonical
from tests.conftest import running_printer

VECTORS = [  # docs/protocols.md section 2
    ("G28", 1, False, "850001001ca2ba"),
    ("G1 X10 Y20 F3000", 2, False, "9d01020001000020410000a04100803b45e586"),
    ("M117 Hello", 5, True, "83900000050500750048656c6c6f89aa"),
]


def binary(text: str, n: int | None, v2: bool = False) -> bytes:
    command = repetier.from_gcode(text, n, v2)
    if v2 and not command.v2:
        command = repetier.BinaryCommand(command.n, command.m, command.g, command.params, command.text, v2=True)
    return repetier.encode(command)


def ascii_line(n: int, text: str) -> bytes:
    body = f"N{n} {text}".encode()
    checksum = 0
    for byte in body:
        checksum ^= byte
    return body + b"*%d\n" % checksum


def received(protocol: RepetierProtocol, data: bytes) -> tuple[list, str]:
    """Events for `data` (each command run at once), and what the printer said."""
    protocol.receive_data(data)
    events, said = [], b""
    while (event := protocol.next_event()) is not None:
        events.append(event)
        if isinstance(event, CommandReceived):
            said += protocol.send(Done())
    return events, (said + protocol.data_to_send()).decode()


# -- the codec ------------------------------------------------------------------------------
@pytest.mark.parametrize("text, n, v2, wire", VECTORS)
def test_reference_vectors_encode_and_decode(text, n, v2, wire):
    assert binary(text, n, v2).hex() == wire
    frame = bytes.fromhex(wire)
    assert repetier.command_size(frame[:5]) == len(frame)
    decoded = repetier.decode(frame)
    assert (decoded.n, repetier.to_gcode(decoded)) == (n, text)


def test_every_field_has_its_bit_and_type():
    line = "G1 X1 Y2 Z3 E4 F5 T6 S-7 P8 I9 J10 R11 D12 C13 H14 A15 B16 K17 L18 O19"
    command = repetier.from_gcode(line, 9, v2=True)
    frame = repetier.encode(command)
    bits, bits2 = struct.unpack_from("<HH", frame)
    assert bits == 0x1000 | 0x0F7D | 0x0080  # N G X Y Z E F T S P, V2, marker
    assert bits2 == 0x07FF  # I J R D C H A B K L O
    assert repetier.to_gcode(repetier.decode(frame)) == line
    # V2 carries G and M in 16 bits, V1 in 8.
    assert repetier.from_gcode("M900 K0.1", 1, v2=False) is None
    assert repetier.decode(binary("M900 K0.1", 1, v2=True)).m == 900


@pytest.mark.parametrize(
    "line, reason",
    [
        ("M104 S200.5", "S is an integer field"),
        ("G28 X", "a letter without a value"),
        ("G29 V4", "no field for V"),
        ("M118 hello", "M118's text has no field"),
        ("M23 a file.gco", "a file name ends at a space"),
        ("G2 X1 I1", "I needs V2"),
        ("M117 seventeen characters", "V1 text holds 16"),
    ],
)
def test_lines_without_an_exact_v1_form_go_as_ascii(line, reason):
    assert repetier.from_gcode(line, 3, v2=False) is None, reason


def test_floats_are_what_float32_keeps():
    command = repetier.from_gcode("G1 X10810.12345 E0.1", 1)
    assert repetier.to_gcode(repetier.decode(repetier.encode(command))) == "G1 X10810.123 E0.1"
    assert canonical("G1 X10810.12345 E0.1") == canonical("G1 E0.1 X10810.123")


floats32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
commands = st.builds(
    repetier.BinaryCommand,
    n=st.none() | st.integers(0, 0xFFFF),
    m=st.none() | st.integers(0, 0xFF),
    g=st.none() | st.integers(0, 0xFF),
    params=st.lists(st.sampled_from("XYZEF"), unique=True).flatmap(
        lambda letters: st.tuples(*[st.tuples(st.just(letter), floats32) for letter in "XYZEF" if letter in letters])
    ),
    text=st.none() | st.text(st.characters(min_codepoint=1, max_codepoint=127), max_size=16),
)


@given(commands)
def test_any_command_round_trips(command):
    frame = repetier.encode(command)
    assert repetier.command_size(frame[:5]) == len(frame)
    assert repetier.decode(frame) == command


@given(commands, st.data())
def test_fletcher16_catches_every_single_bit_error(command, data):
    frame = bytearray(repetier.encode(command))
    bit = data.draw(st.integers(0, len(frame) * 8 - 1))
    frame[bit // 8] ^= 1 << (bit % 8)
    with pytest.raises(repetier.BadChecksum):
        repetier.decode(bytes(frame))


@settings(max_examples=300)
@given(st.binary(max_size=600))
def test_garbage_never_crashes_or_hangs_the_receiver(data):
    protocol = RepetierProtocol()
    for chunk in (data[: len(data) // 2], data[len(data) // 2:]):
        received(protocol, chunk)
        protocol.stalled()
    assert not protocol.has_input or not protocol.reading
    host_parser = host_codec.LineParser()
    host_parser.receive_data(data)
    while host_parser.next_event() is not None:
        pass


# -- the firmware's receiver ----------------------------------------------------------------
def test_binary_and_ascii_mix_and_each_is_acknowledged_with_its_number():
    protocol = RepetierProtocol()
    events, said = received(protocol, binary("M110", 0) + b"\0\0" + binary("G28", 1) + ascii_line(2, "G1 X5"))
    assert [(e.text, e.line_number, e.binary) for e in events] == [("G28", 1, True), ("G1 X5", 2, False)]
    assert said == "ok\r\nok 1\r\nok 2\r\n"


def test_a_damaged_binary_command_needs_31_nuls_before_the_next_is_read():
    protocol = RepetierProtocol()
    received(protocol, binary("G1 X1", 1))
    damaged = bytearray(binary("G1 X2", 2))
    damaged[5] ^= 0x10
    events, said = received(protocol, bytes(damaged) + binary("G1 X3", 3))
    assert isinstance(events[0], CommandRejected) and events[0].resend == 2
    assert said == "Error:Wrong checksum\r\n\r\nResend:2\r\nok\r\n"
    # The line after it was flushed; 30 NULs are not enough, anything else starts counting again.
    events, said = received(protocol, b"\0" * 30 + binary("G1 X2", 2))
    assert events == [] and said == ""
    events, said = received(protocol, b"\0" * 31 + binary("G1 X2", 2))
    assert [e.text for e in events] == ["G1 X2"] and said == "ok 2\r\n"


def test_a_repeated_line_is_skipped_and_a_gap_asks_for_a_resend():
    protocol = RepetierProtocol()
    received(protocol, binary("G1 X1", 1) + binary("G1 X2", 2))
    events, said = received(protocol, binary("G1 X1", 1))
    assert events == [] and said == "skip 1\r\nok\r\n"
    events, said = received(protocol, b"\0" * 32 + binary("G1 X9", 60))
    assert said == "Error:expected line 3 got 60\r\n\r\nResend:3\r\nok\r\n"


def test_after_binary_an_ascii_line_needs_a_checksum():
    protocol = RepetierProtocol()
    received(protocol, binary("G1 X1", 1))
    events, said = received(protocol, b"\0" * 31 + b"G1 X2\n")
    assert said == "Error:Checksum required when switching back to ASCII protocol.\r\n\r\nResend:2\r\nok\r\n"


def test_silence_in_the_middle_of_a_command_and_m112():
    protocol = RepetierProtocol()
    received(protocol, binary("G1 X1", 1)[:3])
    assert protocol.expects_more
    protocol.stalled()
    assert protocol.data_to_send() == b"\r\nResend:1\r\nok\r\n"
    events, _ = received(protocol, b"\0" * 31 + b"M112\n")
    assert events == [EmergencyStop("M112")]


# -- the printer, whole ---------------------------------------------------------------------
async def test_m115_announces_the_protocol_and_an_idle_printer_says_wait(autojump_clock):
    async with running_printer(ServerConfig(protocol="repetier")) as printer:
        host = printer.link.open_host()
        await trio.testing.wait_all_tasks_blocked()
        await host.send_all(binary("M110", 0) + binary("M115", 1) + binary("M105", 2))
        await trio.sleep(1.5)
        said = (await host.receive_some()).decode()
    assert said.startswith("start\r\nInfo:External Reset\r\n")
    assert "ok\r\nok 1\r\nFIRMWARE_NAME:Repetier_" in said and " REPETIER_PROTOCOL:3\r\n" in said
    assert "ok 2\r\nT:21.00 /0 B:21.00 /0 B@:0 @:0\r\nwait\r\n" in said


async def test_busy_while_a_long_command_holds_the_buffer(autojump_clock):
    async with running_printer(ServerConfig(protocol="repetier")) as printer:
        host = printer.link.open_host()
        await trio.testing.wait_all_tasks_blocked()
        await host.send_all(binary("G4 P5000", 1) + binary("G1 X5", 2))
        await trio.sleep(4.5)
        said = (await host.receive_some()).decode()
    assert said.endswith("ok 1\r\nbusy:processing\r\nbusy:processing\r\nbusy:processing\r\n")


# -- the host -------------------------------------------------------------------------------
def test_the_host_uses_v2_only_when_the_printer_reads_it():
    assert host_codec.encode_command(7, "G2 X1 Y1 I1 J0", 3)[1] is True
    data, is_binary = host_codec.encode_command(7, "G2 X1 Y1 I1 J0", 1)
    assert (data, is_binary) == (ascii_line(7, "G2 X1 Y1 I1 J0"), False)
    assert host_codec.encode_command(7, "G1 X1", 0) == (ascii_line(7, "G1 X1"), False)
    assert host_codec.encode_command(65536 + 7, "G1 X1", 1)[0][2:4] == b"\x07\x00"


JOB = ["G28", "M104 S200", "M117 Printing a longer message", "G2 X10 Y10 I5 J5", "M104 S200.5"] + [
    f"G1 X{n % 50}.25 Y{n % 33} E{n / 10:.3f} F3000" for n in range(300)
]


@pytest.mark.parametrize(
    "faults",
    [
        (),
        ("to-printer:bit-errors=3e-4",),
        ("to-host:bit-errors=1e-4", "to-printer:drop-bytes=1e-3"),
        ("to-printer:corrupt-lines=0.05", "to-host:corrupt-lines=0.05"),
    ],
)
async def test_the_host_streams_a_job_exactly_once_through_faults(autojump_clock, faults):
    config = FaultConfig(seed=3)
    for spec in faults:
        config = parse_fault(spec, config)
    async with running_printer(ServerConfig(protocol="auto", faults=config)) as printer:
        async with connect(printer.link.open_host(), "repetier") as client:
            summary = await client.print_commands(JOB)
            response = await client.send("M114")
        journal = printer.journal
    assert summary.commands == len(JOB)
    assert verify(list(enumerate(JOB, 1)), journal).passed(), journal
    ran = [canonical(line) for line in journal if line not in ("M115", "M114")]
    assert ran == [canonical(command) for command in JOB]
    assert response and response[0].startswith("X:")
    if faults:
        assert summary.resends > 0


async def test_auto_takes_high_bytes_for_noise_unless_a_command_checks_out(autojump_clock):
    async with running_printer(ServerConfig(protocol="auto")) as printer:
        host = printer.link.open_host()
        await host.send_all(b"\xf0\x81\x92M105\n")  # line noise, then a Marlin host
        await trio.sleep(1)
        assert (await host.receive_some()).decode().startswith("start\n")
        assert printer.server.protocol_name == "marlin"
