"""Marlin's binary file transfer (`M28 B1`): the packet codec (wire/marlin_binary.py), the
printer's machine (emulator/protocols/marlin_binary.py) against binary_stream.h's replies, and
the Marlin session switching to it and back on an in-memory link."""

import random
from contextlib import asynccontextmanager

import heatshrink2
import pytest
import trio
from hypothesis import given, settings
from hypothesis import strategies as st

from fake_marlin.emulator.faults.layer import FRAMERS, FaultConfig, FaultLayer
from fake_marlin.emulator.faults.rules import FaultKind, FaultRule, Trigger
from fake_marlin.emulator.printer.model import DEFAULT_CAPABILITIES, Printer, PrinterConfig
from fake_marlin.emulator.protocols.marlin_binary import (
    BUFFER_SIZE,
    PACKET_MAX_WAIT,
    TRANSFER_TIMEOUT,
    BackToAscii,
    FileAborted,
    FileClosed,
    FileData,
    FileOpened,
    FileResult,
    MarlinBinaryProtocol,
    UsageError,
)
from fake_marlin.emulator.server.lifecycle import ServerConfig
from fake_marlin.wire import marlin_binary as wire
from fake_marlin.wire.framing import split_units
from fake_marlin.wire.marlin_binary import Packet, PacketError, decode, encode, open_payload
from tests.conftest import running_printer
from tests.terminal import Terminal, numbered

CONTROL, FILE = wire.Protocol.CONTROL, wire.Protocol.FILE_TRANSFER
SYNC, CLOSE = wire.Control.SYNC, wire.Control.CLOSE
QUERY, OPEN, FCLOSE, WRITE, ABORT = (
    wire.FileRequest.QUERY, wire.FileRequest.OPEN, wire.FileRequest.CLOSE,
    wire.FileRequest.WRITE, wire.FileRequest.ABORT,
)
VERSION_REPLY = "PFT:version:0.1.0:compression:heatshrink,8,4"
JOB = "".join(f"G1 X{n % 40}.{n % 10} Y{n % 23}.5 E{n / 50:.3f} F3000\n" for n in range(400)).encode()


def step_checksum(data: bytes, cs: int = 0) -> int:
    """binary_stream.h's checksum(), one byte at a time, as PROTOCOLS.md section 5 states it."""
    for byte in data:
        low = ((cs & 0xFF) + byte) % 255
        cs = (((cs >> 8) + low) % 255) << 8 | low
    return cs


def compress(data: bytes) -> bytes:
    return heatshrink2.encode(data, window_sz2=8, lookahead_sz2=4)


# -- the codec ------------------------------------------------------------------------------
VECTORS = [  # PROTOCOLS.md section 5
    (Packet(0, CONTROL, SYNC), "adb5000100000103"),
    (Packet(1, FILE, OPEN, open_payload("test.gco")), "adb501110b001d4d0000746573742e67636f00b195"),
]


@pytest.mark.parametrize("packet, hex_bytes", VECTORS, ids=["SYNC", "OPEN test.gco"])
def test_the_reference_vectors(packet, hex_bytes):
    assert encode(packet).hex() == hex_bytes
    assert decode(bytes.fromhex(hex_bytes)) == packet


packets = st.builds(
    Packet, st.integers(0, 255), st.integers(0, 15), st.integers(0, 15), st.binary(max_size=200)
)


@given(st.binary(max_size=300), st.integers(0, 0xFFFF))
def test_the_checksum_is_the_firmwares_step_by_step(data, start):
    start = (start >> 8) % 255 << 8 | (start & 0xFF) % 255  # a value the firmware can hold
    assert wire.checksum(data, start) == step_checksum(data, start)


@given(packets)
def test_a_packet_decodes_to_what_was_encoded(packet):
    assert decode(encode(packet)) == packet


@given(packets, st.data())
def test_any_single_bit_of_damage_is_detected(packet, data):
    raw = bytearray(encode(packet))
    bit = data.draw(st.integers(0, len(raw) * 8 - 1))
    raw[bit // 8] ^= 1 << bit % 8
    with pytest.raises(PacketError):
        decode(bytes(raw))


def test_what_is_no_packet_is_refused_with_a_reason():
    with pytest.raises(PacketError, match="AD B5"):
        decode(b"G28\n")
    with pytest.raises(PacketError, match="says 11 bytes, not 10"):
        decode(encode(Packet(0, FILE, WRITE, b"x"))[:-1])
    with pytest.raises(ValueError, match="protocol 16"):
        encode(Packet(0, 16, 0))


# -- the printer's machine, reply by reply --------------------------------------------------
def replies(machine: MarlinBinaryProtocol, data: bytes, ok: bool = True) -> tuple[list, list[str]]:
    """Feed `data`; the events (each answered `ok`) and the lines the firmware said."""
    machine.receive_data(data)
    events, out = [], b""
    while (event := machine.next_event()) is not None:
        events.append(event)
        out += machine.data_to_send()
        if not isinstance(event, BackToAscii):
            out += machine.send(FileResult(ok))
    out += machine.data_to_send()
    return events, out.decode().splitlines()


def opened(name: str = "a.gco", compression: bool = False) -> MarlinBinaryProtocol:
    machine = MarlinBinaryProtocol()
    replies(machine, encode(Packet(0, FILE, OPEN, open_payload(name, compression))))
    return machine


def corrupt_payload(packet: Packet) -> bytes:
    raw = bytearray(encode(packet))
    raw[wire.HEADER_SIZE] ^= 0x10
    return bytes(raw)


CASES = [  # (name, packets sent to a fresh machine, the lines said, events)
    ("SYNC tells the sync number and the buffer", [Packet(0, CONTROL, SYNC)], ["ss0,96,0.1.0"], []),
    ("SYNC with any sync number", [Packet(9, CONTROL, SYNC)], ["ss0,96,0.1.0"], []),
    ("QUERY", [Packet(0, FILE, QUERY)], ["ok0", VERSION_REPLY], []),
    ("a wrong header checksum", [bytes.fromhex("adb5000100000203")],
     ["echo:Packet header(0?) corrupt", "echo:Resend request 1", "rs0"], []),
    ("a wrong payload checksum", [corrupt_payload(Packet(0, FILE, WRITE, b"G28\n"))],
     ["echo:Packet(0) payload corrupt", "echo:Resend request 1", "rs0"], []),
    ("a packet out of order", [Packet(5, FILE, QUERY)],
     ["echo:Datastream packet out of order", "echo:Resend request 1", "rs0"], []),
    ("out of order again after a resend request: dropped unanswered",
     [Packet(5, FILE, QUERY), Packet(6, FILE, QUERY)],
     ["echo:Datastream packet out of order", "echo:Resend request 1", "rs0"], []),
    ("the previous packet again: its ok was lost", [Packet(0, FILE, QUERY), Packet(0, FILE, QUERY)],
     ["ok0", VERSION_REPLY, "ok0"], []),
    ("a payload past the line buffer", [Packet(0, FILE, WRITE, bytes(BUFFER_SIZE + 1))],
     ["echo:Datastream packet data buffer overrun", "fe0"], []),
    ("a file CLOSE with no file open", [Packet(0, FILE, FCLOSE)], ["ok0", "PFT:invalid"], []),
    ("a WRITE with no file open", [Packet(0, FILE, WRITE, b"G28\n")], ["ok0", "PFT:invalid"], []),
    ("an ABORT with no file open", [Packet(0, FILE, ABORT)], ["ok0", "PFT:success"], []),
    ("an unknown file request (the firmware's spelling)", [Packet(0, FILE, 7)], ["ok0", "PTF:invalid"], []),
    ("an unknown control packet", [Packet(0, CONTROL, 5)],
     ["ok0", "echo:Unknown BinaryProtocolControl Packet"], []),
    ("an unknown protocol", [Packet(0, 2, 0)], ["ok0", "echo:Unsupported Binary Protocol"], []),
    ("an OPEN whose name has no NUL", [Packet(0, FILE, OPEN, b"\0\0a.gco")], ["ok0", "PFT:fail"], []),
    ("an OPEN", [Packet(0, FILE, OPEN, open_payload("a.gco", compression=True))],
     ["ok0", "PFT:success"], [FileOpened("a.gco", True, False)]),
    ("an OPEN with a file open already",
     [Packet(0, FILE, OPEN, open_payload("a.gco")), Packet(1, FILE, OPEN, open_payload("b.gco"))],
     ["ok0", "PFT:success", "ok1", "PFT:busy"], [FileOpened("a.gco", False, False)]),
    ("a transfer", [Packet(0, FILE, OPEN, open_payload("a.gco")), Packet(1, FILE, WRITE, b"G28\n"),
                    Packet(2, FILE, FCLOSE)],
     ["ok0", "PFT:success", "ok1", "ok2", "PFT:success"],
     [FileOpened("a.gco", False, False), FileData(b"G28\n"), FileClosed(False)]),
    ("an ABORT", [Packet(0, FILE, OPEN, open_payload("a.gco")), Packet(1, FILE, ABORT)],
     ["ok0", "PFT:success", "ok1", "PFT:success"],
     [FileOpened("a.gco", False, False), FileAborted(False, timed_out=False)]),
    ("a dummy transfer writes nothing",
     [Packet(0, FILE, OPEN, open_payload("a.gco", dummy=True)), Packet(1, FILE, WRITE, b"G28\n")],
     ["ok0", "PFT:success", "ok1"], [FileOpened("a.gco", False, True)]),
    ("CLOSE: back to ASCII", [Packet(0, CONTROL, CLOSE)], ["ok0"], [BackToAscii(b"")]),
]


@pytest.mark.parametrize("sent, said, events", [case[1:] for case in CASES], ids=[c[0] for c in CASES])
def test_each_packet_gets_the_firmwares_answer(sent, said, events):
    machine = MarlinBinaryProtocol()
    got_events, got_lines = [], []
    for packet in sent:
        more_events, lines = replies(machine, packet if isinstance(packet, bytes) else encode(packet))
        got_events += more_events
        got_lines += lines
    assert got_lines == said
    assert got_events == events


def test_a_buffer_overrun_needs_a_new_sync():
    machine = MarlinBinaryProtocol()
    replies(machine, encode(Packet(0, FILE, QUERY)) + encode(Packet(1, FILE, QUERY)))
    assert machine.sync == 2
    assert replies(machine, encode(Packet(2, FILE, WRITE, bytes(200))))[1][-1] == "fe2"
    assert machine.sync == 0
    assert replies(machine, encode(Packet(0, CONTROL, SYNC)))[1] == ["ss0,96,0.1.0"]


def test_a_failed_open_or_write_or_close_is_said():
    machine = MarlinBinaryProtocol()
    assert replies(machine, encode(Packet(0, FILE, OPEN, open_payload("a.gco"))), ok=False)[1] == [
        "ok0", "PFT:fail"]
    assert not machine.transfer_active
    replies(machine, encode(Packet(1, FILE, OPEN, open_payload("a.gco"))))
    assert replies(machine, encode(Packet(2, FILE, WRITE, b"G28\n")), ok=False)[1] == ["ok2", "PFT:ioerror"]
    assert replies(machine, encode(Packet(3, FILE, FCLOSE)), ok=False)[1] == ["ok3", "PFT:ioerror"]
    assert machine.transfer_active  # as file_close() returns before it ends the transfer


def test_a_compressed_transfer_arrives_decompressed():
    machine = opened(compression=True)
    packed = compress(JOB)
    data = b""
    for n, start in enumerate(range(0, len(packed), BUFFER_SIZE), start=1):
        events, _ = replies(machine, encode(Packet(n % 256, FILE, WRITE, packed[start:start + BUFFER_SIZE])))
        data += b"".join(event.data for event in events)
    assert data == JOB and len(packed) < len(JOB) / 2


def test_a_packet_left_half_sent_times_out_into_a_resend():
    machine = MarlinBinaryProtocol()
    raw = encode(Packet(0, FILE, QUERY))
    replies(machine, raw[:5])
    machine.time_passed(1.0)  # the bytes came at 1 s
    assert machine.mid_packet and machine.next_deadline() == 1.0 + PACKET_MAX_WAIT
    machine.time_passed(1.0 + PACKET_MAX_WAIT - 0.001)
    assert machine.data_to_send() == b""
    machine.time_passed(1.0 + PACKET_MAX_WAIT)
    assert machine.data_to_send().decode().splitlines() == [
        "echo:Datastream timeout", "echo:Resend request 1", "rs0"]
    assert replies(machine, raw)[1] == ["ok0", VERSION_REPLY]
    machine.time_passed(2.0)
    assert machine.next_deadline() is None  # between packets there is nothing to time out
    machine.time_passed(60.0)
    assert machine.data_to_send() == b""


def test_each_byte_of_a_packet_restarts_its_timer():
    machine = MarlinBinaryProtocol()
    raw = encode(Packet(0, FILE, QUERY))
    replies(machine, raw[:5])
    machine.time_passed(1.0)
    replies(machine, raw[5:7])
    machine.time_passed(1.4)
    assert machine.next_deadline() == 1.4 + PACKET_MAX_WAIT
    machine.time_passed(1.0 + PACKET_MAX_WAIT)
    assert machine.data_to_send() == b""


def test_an_idle_transfer_is_aborted_without_a_word():
    machine = opened()
    machine.time_passed(0.0)  # the OPEN came at 0 s
    assert machine.next_deadline() == TRANSFER_TIMEOUT
    machine.time_passed(TRANSFER_TIMEOUT - 0.001)
    assert machine.next_event() is None
    machine.time_passed(TRANSFER_TIMEOUT)
    assert machine.next_event() == FileAborted(False, timed_out=True)
    assert machine.next_event() is None  # it waits for its result
    assert machine.send(FileResult(True)) == b""
    assert not machine.transfer_active and machine.next_deadline() is None


def test_a_file_packet_restarts_the_transfer_timer_and_other_bytes_do_not():
    machine = opened()
    machine.time_passed(0.0)
    replies(machine, encode(Packet(1, FILE, WRITE, b"G28\n")))
    machine.time_passed(4.0)
    assert machine.next_deadline() == 4.0 + TRANSFER_TIMEOUT
    replies(machine, b"noise")  # no token: no packet
    machine.time_passed(6.0)
    assert machine.next_deadline() == 4.0 + TRANSFER_TIMEOUT


def test_the_bytes_after_close_are_handed_back_and_the_stream_lives_on():
    machine = MarlinBinaryProtocol()
    events, lines = replies(machine, encode(Packet(0, CONTROL, CLOSE)) + b"M115\n")
    assert events == [BackToAscii(b"M115\n")] and lines == ["ok0"]
    with pytest.raises(UsageError):
        machine.receive_data(b"M105\n")
    machine.enter(encode(Packet(0, CONTROL, SYNC)))
    assert replies(machine, b"")[1] == ["ss1,96,0.1.0"]


def test_the_caller_must_answer_in_turn():
    machine = MarlinBinaryProtocol()
    with pytest.raises(UsageError):
        machine.send(FileResult(True))
    machine.receive_data(encode(Packet(0, FILE, OPEN, open_payload("a.gco"))) + encode(Packet(1, FILE, QUERY)))
    assert isinstance(machine.next_event(), FileOpened)
    assert machine.next_event() is None  # until the card says how the OPEN went
    assert machine.send(FileResult(True)) == b"ok0\nPFT:success\n"
    assert machine.next_event() is None and machine.data_to_send() == f"ok1\n{VERSION_REPLY}\n".encode()


SESSION = b"".join(encode(packet) for packet in [
    Packet(0, CONTROL, SYNC), Packet(0, FILE, QUERY), Packet(1, FILE, OPEN, open_payload("a.gco")),
    *(Packet(n, FILE, WRITE, JOB[(n - 2) * 96:(n - 1) * 96]) for n in range(2, 8)),
    Packet(8, FILE, FCLOSE), Packet(9, CONTROL, CLOSE),
])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, len(SESSION)), max_size=30), st.binary(max_size=20))
def test_however_the_bytes_are_cut_the_answers_are_the_same(cuts, noise):
    """Noise between packets costs nothing (noise inside one is another test's matter)."""
    whole_events, whole_lines = replies(MarlinBinaryProtocol(), SESSION)
    stream = noise.replace(wire.TOKEN[:1], b"") + SESSION
    machine = MarlinBinaryProtocol()
    events, lines = [], []
    points = sorted({0, len(stream), *(min(cut, len(stream)) for cut in cuts)})
    for start, end in zip(points, points[1:]):
        more_events, more_lines = replies(machine, stream[start:end])
        events += more_events
        lines += more_lines
    assert (events, lines) == (whole_events, whole_lines)


class Uploader:
    """A host as binproto2 behaves: each packet until `ok`, again on `rs`, again after silence
    (on which the firmware's packet timer has run out, if it was inside a packet)."""

    def __init__(self, machine: MarlinBinaryProtocol, damage) -> None:
        self.machine = machine
        self.damage = damage  # (index of the transmission, its bytes) -> the bytes that arrive
        self.transmissions = 0
        self.resends = 0
        self.data = b""
        self.now = 0.0  # the firmware's time: a millisecond a transmission, and its silences

    def send(self, packet: Packet) -> list[str]:
        for _ in range(20):
            raw = self.damage(self.transmissions, encode(packet))
            self.transmissions += 1
            events, lines = replies(self.machine, raw)
            self.now += 0.001
            self.machine.time_passed(self.now)
            self.data += b"".join(event.data for event in events if isinstance(event, FileData))
            if not any(line.startswith(("ok", "rs", "ss")) for line in lines):
                self.now += PACKET_MAX_WAIT  # silence
                self.machine.time_passed(self.now)
                lines += self.machine.data_to_send().decode().splitlines()
            if f"ok{packet.sync}" in lines or (packet.type == SYNC and packet.protocol == CONTROL
                                                and any(line.startswith("ss") for line in lines)):
                return lines
            self.resends += 1
        raise AssertionError(f"{packet} never got its ok")

    def upload(self, data: bytes, compressed: bool) -> None:
        payload = compress(data) if compressed else data
        self.send(Packet(0, CONTROL, SYNC))
        self.send(Packet(0, FILE, OPEN, open_payload("a.gco", compressed)))
        for n, start in enumerate(range(0, len(payload), BUFFER_SIZE), start=1):
            self.send(Packet(n % 256, FILE, WRITE, payload[start:start + BUFFER_SIZE]))


@settings(max_examples=60, deadline=None)
@given(compressed=st.booleans(), hit=st.integers(0, 40), bit=st.integers(0, 8 * 106 - 1))
def test_a_flipped_bit_anywhere_costs_a_resend_never_a_byte(compressed, hit, bit):
    def damage(index: int, raw: bytes) -> bytes:
        if index != hit:
            return raw
        damaged = bytearray(raw)
        damaged[bit // 8 % len(raw)] ^= 1 << bit % 8
        return bytes(damaged)

    uploader = Uploader(MarlinBinaryProtocol(), damage)
    uploader.upload(JOB[:3000], compressed)
    assert uploader.data == JOB[:3000]
    assert uploader.resends == (1 if hit < uploader.transmissions - 1 else 0)


def test_many_flipped_bits_cost_resends_never_a_byte():
    draw = random.Random(5)

    def damage(index: int, raw: bytes) -> bytes:
        damaged = bytearray(raw)
        for position in range(len(damaged)):
            if draw.random() < 0.004:
                damaged[position] ^= 1 << draw.randrange(8)
        return bytes(damaged)

    uploader = Uploader(MarlinBinaryProtocol(), damage)
    uploader.upload(JOB, compressed=False)
    assert uploader.data == JOB and uploader.resends > 20


# -- the fault layer's units -----------------------------------------------------------------
UNITS = [b"N1 M28 B1*96\n", encode(Packet(0, CONTROL, SYNC)), encode(Packet(0, FILE, QUERY)),
         encode(Packet(1, FILE, WRITE, b"G28\nG1 X10\n")), encode(Packet(2, FILE, WRITE, bytes(range(90)))),
         encode(Packet(3, CONTROL, CLOSE)), b"M20\n"]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 400), max_size=30))
def test_marlins_framer_finds_lines_and_packets_however_they_are_cut(cuts):
    framer = FRAMERS["marlin"][0]
    stream = b"".join(UNITS)
    assert split_units(stream, framer) == (UNITS, b"")
    points = sorted({0, len(stream), *(min(cut, len(stream)) for cut in cuts)})
    found, rest = [], b""
    for start, end in zip(points, points[1:]):
        units, rest = split_units(rest + stream[start:end], framer)
        found += units
    assert (found, rest) == (UNITS, b"")


def test_a_unit_fault_drops_a_whole_packet_and_holds_back_nothing_else():
    rule = FaultRule(FaultKind.DROP, Trigger(nth=3), direction="to-printer")
    layer = FaultLayer(FaultConfig(rules=(rule,)))
    layer.set_protocol("marlin")
    passed = b"".join(segment.data for unit in UNITS for segment in layer.to_printer(unit))
    assert passed == b"".join(UNITS[:2] + UNITS[3:])


def test_a_packet_whose_header_is_damaged_ends_after_the_header():
    raw = bytearray(encode(Packet(1, FILE, WRITE, b"G28\n")))
    raw[3] ^= 1
    units, rest = split_units(bytes(raw) + b"M105\n", FRAMERS["marlin"][0])
    # The payload is noise then, here a line and the footer's bytes with the next line.
    assert units == [bytes(raw[:8]), b"G28\n", bytes(raw[12:]) + b"M105\n"] and rest == b""


# -- the session: M28 B1, the card, and back ------------------------------------------------
class BinaryHost(Terminal):
    async def packet(self, packet: Packet, until: str | None = None) -> list[str]:
        """Send a packet; the lines up to `until` (default `ok<sync>`, or `ss` for SYNC)."""
        await self.stream.send_all(encode(packet))
        if until is None:
            until = "ss" if (packet.protocol, packet.type) == (CONTROL, SYNC) else f"ok{packet.sync}"
        return await self.read_until(lambda line: line.startswith(until), timeout=30)

    async def upload(self, name: str, data: bytes, compressed: bool = False, sync: int = 1) -> int:
        assert (await self.packet(Packet(sync, FILE, OPEN, open_payload(name, compressed)), "PFT:"))[-1] == (
            "PFT:success")
        payload = compress(data) if compressed else data
        for start in range(0, len(payload), BUFFER_SIZE):
            sync += 1
            await self.packet(Packet(sync % 256, FILE, WRITE, payload[start:start + BUFFER_SIZE]))
        sync += 1
        assert (await self.packet(Packet(sync % 256, FILE, FCLOSE), "PFT:"))[-1] == "PFT:success"
        return sync + 1


@asynccontextmanager
async def marlin(tmp_path, sd=True, **config):
    sd_dir = tmp_path / "sd"
    if sd:
        sd_dir.mkdir(parents=True)
    printer = Printer(PrinterConfig(sd_dir=sd_dir, **config))
    async with running_printer(ServerConfig(protocol="marlin"), printer) as running:
        host = BinaryHost(running.link.open_host())
        await host.quiet_for(1)
        yield host, sd_dir


async def binary_mode(host: BinaryHost) -> None:
    assert await host.command("M28 B1") == ["echo:Switching to Binary Protocol", "ok"]
    assert await host.packet(Packet(0, CONTROL, SYNC)) == ["ss0,96,0.1.0"]
    assert await host.packet(Packet(0, FILE, QUERY), "PFT:") == ["ok0", VERSION_REPLY]


async def test_m28_b1_uploads_plain_and_compressed_then_the_printer_speaks_ascii(tmp_path, autojump_clock):
    async with marlin(tmp_path) as (host, sd):
        await binary_mode(host)
        await host.stream.send_all(encode(Packet(1, FILE, OPEN, open_payload("plain.gco"))))
        assert await host.read_until(lambda line: line.startswith("PFT:")) == [
            "ok1", "echo:SD card ok", "echo:Now fresh file: plain.gco", "Writing to file: plain.gco",
            "PFT:success"]
        sync = 2
        for start in range(0, len(JOB), BUFFER_SIZE):
            assert await host.packet(Packet(sync % 256, FILE, WRITE, JOB[start:start + BUFFER_SIZE])) == [
                f"ok{sync % 256}"]
            sync += 1
        assert await host.packet(Packet(sync % 256, FILE, FCLOSE), "PFT:") == [f"ok{sync % 256}", "PFT:success"]
        sync = await host.upload("packed.gco", JOB, compressed=True, sync=sync + 1)
        assert await host.packet(Packet(sync % 256, CONTROL, CLOSE)) == [f"ok{sync % 256}"]
        assert (sd / "plain.gco").read_bytes() == JOB == (sd / "packed.gco").read_bytes()
        # The firmware released the card after each CLOSE: M21 mounts it again.
        assert await host.command("M20") == ["echo:No media", "ok"]
        assert await host.command("M21") == ["echo:SD card ok", "ok"]
        assert await host.command("M20") == [
            "Begin file list", f"PACKED.GCO {len(JOB)}", f"PLAIN.GCO {len(JOB)}", "End file list", "ok"]
        assert "Cap:BINARY_FILE_TRANSFER:1" in await host.command("M115")


async def test_what_comes_with_m28_b1_is_read_in_binary(tmp_path, autojump_clock):
    async with marlin(tmp_path) as (host, _):
        await host.stream.send_all(b"M28 B1\n" + encode(Packet(0, CONTROL, SYNC)))
        assert await host.read_until(lambda line: line.startswith("ss")) == [
            "echo:Switching to Binary Protocol", "ok", "ss0,96,0.1.0"]
        await host.stream.send_all(encode(Packet(0, CONTROL, CLOSE)) + b"M105\n")
        lines = await host.read_until(lambda line: line.startswith("ok T:"))
        assert lines[0] == "ok0"


async def test_the_firmwares_timers_resend_a_stalled_packet_and_drop_an_idle_transfer(
        tmp_path, autojump_clock):
    async with marlin(tmp_path) as (host, sd):
        await binary_mode(host)
        raw = encode(Packet(1, FILE, OPEN, open_payload("idle.gco")))
        await host.stream.send_all(raw[:6])
        start = trio.current_time()
        assert await host.read_until(lambda line: line.startswith("rs")) == [
            "echo:Datastream timeout", "echo:Resend request 1", "rs1"]
        assert trio.current_time() - start == pytest.approx(0.5)
        await host.stream.send_all(raw)
        await host.read_until(lambda line: line == "PFT:success")
        await host.packet(Packet(2, FILE, WRITE, b"G28\n"))
        assert (sd / "idle.gco").exists()
        start = trio.current_time()
        assert await host.read_line() == "File deleted:IDLE.GCO"
        assert trio.current_time() - start == pytest.approx(10)
        assert not (sd / "idle.gco").exists()
        assert await host.packet(Packet(3, FILE, WRITE, b"G1 X1\n"), "PFT:") == ["ok3", "PFT:invalid"]


async def test_abort_deletes_the_file_and_a_missing_card_fails_the_open(tmp_path, autojump_clock):
    async with marlin(tmp_path) as (host, sd):
        await binary_mode(host)
        await host.packet(Packet(1, FILE, OPEN, open_payload("part.gco")), "PFT:")
        await host.packet(Packet(2, FILE, WRITE, b"G28\n"))
        assert await host.packet(Packet(3, FILE, ABORT), "PFT:") == ["ok3", "File deleted:PART.GCO", "PFT:success"]
        assert list(sd.iterdir()) == []
        assert await host.packet(Packet(4, FILE, OPEN, open_payload("../out.gco")), "PFT:") == [
            "ok4", "echo:SD card ok", "echo:Now fresh file: ../out.gco", "open failed, File: ../out.gco.",
            "PFT:fail"]
    async with marlin(tmp_path / "nocard", sd=False) as (host, _):
        await binary_mode(host)
        assert await host.packet(Packet(1, FILE, OPEN, open_payload("a.gco")), "PFT:") == [
            "ok1", "echo:SD init fail", "PFT:fail"]


async def test_without_the_capability_m28_b1_is_a_file_named_b1(tmp_path, autojump_clock):
    capabilities = tuple((name, False if name == "BINARY_FILE_TRANSFER" else on)
                         for name, on in DEFAULT_CAPABILITIES)
    async with marlin(tmp_path, capabilities=capabilities) as (host, sd):
        assert await host.command("M28 B1") == ["Writing to file: B1", "ok"]
        assert await host.command("M29") == ["Done saving file.", "ok"]
        assert (sd / "B1").exists()
    async with marlin(tmp_path / "b0") as (host, sd):
        assert await host.command("M28 B0 up.gco") == ["Writing to file: up.gco", "ok"]


async def test_an_m28_b1_printed_from_the_card_leaves_the_hosts_next_m28_an_ascii_upload(
        tmp_path, autojump_clock):
    async with marlin(tmp_path) as (host, sd):
        (sd / "job.g").write_text("M28 B1\nG4 P10\n")
        assert (await host.command("M23 job.g"))[-1] == "ok"
        await host.command("M24")
        await host.read_until(lambda line: line == "Done printing file")
        assert await host.command("M28 up.gco") == ["Writing to file: up.gco", "ok"]
        assert await host.command(numbered(1, "G1 X1")) == ["ok"]  # saved, not run
        assert (await host.command("M29"))[-1] == "ok"
        assert (sd / "up.gco").read_text() == "G1 X1\n"
