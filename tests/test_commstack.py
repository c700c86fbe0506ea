"""Printrhub's CommStack: frames, the MK20's answers, its file tasks, and the host's upload."""

import json
import struct

import pytest
import trio
import trio.testing
from hypothesis import given, settings
from hypothesis import strategies as st

from fake_marlin.emulator.faults.layer import FaultConfig, parse_fault
from fake_marlin.emulator.journal.verify import is_host_command
from fake_marlin.emulator.printer.failures import Failure, FailureKind, apply
from fake_marlin.emulator.printer.model import Printer, PrinterConfig
from fake_marlin.emulator.protocols.commstack import (
    CommStackProtocol,
    FrameRejected,
    RequestReceived,
)
from fake_marlin.emulator.server.lifecycle import ServerConfig
from fake_marlin.host.clients.commstack import CommStackClient
from fake_marlin.host.connect import connect
from fake_marlin.host.cores.commstack import SYNC_TASKS, CommStackCore, Outcome, Result
from fake_marlin.wire.commstack import (
    HEADER,
    MAX_DATA,
    BadData,
    BadHeader,
    CommType,
    FrameSplitter,
    Packet,
    Task,
    data_checksum,
    decode_frame,
    encode_packet,
    header_checksum,
    starts_with_header,
)
from tests.conftest import running_printer

PING = Packet(Task.PING, CommType.REQUEST)


def frames(data: bytes) -> list[bytes]:
    splitter = FrameSplitter()
    splitter.receive_data(data)
    found = []
    while (frame := splitter.next_frame()) is not None:
        found.append(frame)
    return found


# -- the wire -------------------------------------------------------------------------------
def test_the_reference_ping():
    """docs/protocols.md section 3: the 8-byte header with its padding byte, COBS, 0x00."""
    wire = encode_packet(PING)
    assert wire.hex() == "031901010101021a0100"
    assert decode_frame(wire[:-1]) == PING


def test_checksums_cover_what_the_firmware_says():
    wire = encode_packet(Packet(Task.FILE_SAVE_DATA, CommType.REQUEST, b"\x01\x02\xff"))
    from cobs import cobs

    raw = bytearray(cobs.decode(wire[:-1]))
    assert raw[:8] == bytes([8, 1, 3, 0]) + struct.pack("<HH", 0x102, 8 + 1 + 3 + 0x102)
    raw[9] ^= 1  # damaged data: the header still checks
    assert decode_frame(cobs.encode(bytes(raw))) == BadData(Task.FILE_SAVE_DATA, CommType.REQUEST)
    raw[0] ^= 1  # damaged header
    assert isinstance(decode_frame(cobs.encode(bytes(raw))), BadHeader)
    raw[3] = 0x5A  # ...and the padding byte is nobody's business
    raw[0] ^= 1
    raw[9] ^= 1
    assert decode_frame(cobs.encode(bytes(raw))).data == b"\x01\x02\xff"


packets = st.builds(
    Packet, st.integers(0, 255), st.integers(0, 255), st.binary(max_size=245)
)


@given(packets)
def test_any_packet_round_trips(packet):
    wire = encode_packet(packet)
    assert wire.count(0) == 1 and wire.endswith(b"\0")
    assert frames(wire) == [wire[:-1]]
    assert decode_frame(wire[:-1]) == packet


@given(st.binary(max_size=1200))
def test_garbage_never_crashes_either_side(data):
    mk20 = CommStackProtocol()
    mk20.receive_data(data)
    while mk20.next_event() is not None:
        pass
    assert len(mk20.data_to_send()) % 10 == 0  # only empty ResponseFailed packets, if anything
    host = CommStackCore()
    host.receive_data(data, 0.0)
    host.poll(0.0)


@settings(max_examples=200)
@given(st.integers(1, 9), st.binary(max_size=40))
def test_an_answer_that_follows_a_cut_one_in_the_same_block_is_still_heard(cut, data):
    """A frame cut short loses its 0x00, so the next frame's bytes join it: the host takes the
    whole frame at the end of such a block (campaign 2030, case 880)."""
    host = CommStackCore()
    exchange = host.start(0x41)
    host.poll(0.0)
    spoiled = encode_packet(Packet(Task.FILE_SAVE_DATA, CommType.RESPONSE_SUCCESS, b"\x07\x00"))
    host.receive_data(
        spoiled[:cut] + encode_packet(Packet(0x41, CommType.RESPONSE_SUCCESS, data)), 0.0
    )
    assert exchange.outcome is Outcome.SUCCESS and exchange.answer == data
    assert host.stats.corrupt_frames == 1


# -- the MK20's receiver --------------------------------------------------------------------
def test_a_bad_data_checksum_is_answered_failed_and_a_bad_header_not_at_all():
    from cobs import cobs

    mk20 = CommStackProtocol()
    good = encode_packet(Packet(Task.FILE_SAVE_DATA, CommType.REQUEST, b"abc"))
    raw = bytearray(cobs.decode(good[:-1]))
    raw[8] ^= 4
    mk20.receive_data(cobs.encode(bytes(raw)) + b"\0")
    assert mk20.next_event() == FrameRejected("data checksum", answered=True)
    assert mk20.data_to_send() == encode_packet(Packet(Task.FILE_SAVE_DATA, CommType.RESPONSE_FAILED))
    raw[8] ^= 4
    raw[6] ^= 1
    mk20.receive_data(cobs.encode(bytes(raw)) + b"\0")
    assert mk20.next_event() == FrameRejected("header checksum", answered=False)
    assert mk20.data_to_send() == b""
    # A stray 0x00 is an empty frame: the MK20 answers it as a failure of the last task.
    mk20.receive_data(encode_packet(PING) + b"\0")
    assert mk20.next_event() == RequestReceived(Task.PING, b"")
    assert mk20.next_event() == FrameRejected("not a COBS frame", answered=True)
    assert mk20.data_to_send() == encode_packet(Packet(Task.PING, CommType.RESPONSE_FAILED))


def raw_frame(task: int, data: bytes, comm_type: int = CommType.REQUEST) -> bytes:
    """A packet on the wire as encode_packet makes it, but of any length."""
    from cobs import cobs

    sum_ = data_checksum(data)
    checksum = header_checksum(task, comm_type, len(data), sum_)
    header = HEADER.pack(task, comm_type, len(data), sum_, checksum)
    return cobs.encode(header + data) + b"\0"


def test_max_data_is_the_most_a_request_carries_for_the_mk20_to_answer_it_once():
    """The MK20 reads a frame with readBytesUntil(0, buffer, 256) on the Teensy 3.1 core, which
    keeps the buffer's last byte for a NUL: 255 bytes at most. 245 data bytes make a 254-byte
    frame, read with its 0x00; 246 make 255, whose 0x00 is left over and read as an empty frame:
    the request runs, and a ResponseFailed follows its answer."""
    mk20 = CommStackProtocol()
    wire = encode_packet(Packet(Task.FILE_SAVE_DATA, CommType.REQUEST, b"x" * MAX_DATA))
    assert len(wire) == 255
    mk20.receive_data(wire)
    assert mk20.next_event() == RequestReceived(Task.FILE_SAVE_DATA, b"x" * MAX_DATA)
    assert mk20.next_event() is None and mk20.data_to_send() == b""
    wire = raw_frame(Task.FILE_SAVE_DATA, b"y" * (MAX_DATA + 1))
    assert len(wire) == 256
    mk20.receive_data(wire)
    assert mk20.next_event() == RequestReceived(Task.FILE_SAVE_DATA, b"y" * (MAX_DATA + 1))
    assert mk20.next_event() == FrameRejected("not a COBS frame", answered=True)
    failed = encode_packet(Packet(Task.FILE_SAVE_DATA, CommType.RESPONSE_FAILED))
    assert mk20.data_to_send() == failed
    with pytest.raises(ValueError):
        encode_packet(Packet(Task.FILE_SAVE_DATA, CommType.REQUEST, b"y" * (MAX_DATA + 1)))


def test_a_bad_header_is_copied_in_before_it_is_checked():
    """packetReceived() memcpy()s a frame's header into the current one first: its task is the
    one a later undecodable frame is answered under."""
    mk20 = CommStackProtocol()
    mk20.receive_data(encode_packet(PING))
    assert mk20.next_event() == RequestReceived(Task.PING, b"")
    from cobs import cobs

    damaged = HEADER.pack(Task.FILE_CLOSE, CommType.REQUEST, 0, 0, 0x1234)  # a wrong checksum
    mk20.receive_data(cobs.encode(damaged) + b"\0\0")
    assert mk20.next_event() == FrameRejected("header checksum", answered=False)
    assert mk20.next_event() == FrameRejected("not a COBS frame", answered=True)
    assert mk20.data_to_send() == encode_packet(Packet(Task.FILE_CLOSE, CommType.RESPONSE_FAILED))


def test_a_read_ends_when_no_byte_has_come_for_a_second():
    """Stream's timeout (1 s, which the MK20 keeps): a frame whose 0x00 was lost is read then,
    whole, rather than with the next frame."""
    mk20 = CommStackProtocol()
    mk20.receive_data(encode_packet(PING)[:-1])
    mk20.time_passed(10.0)  # the bytes came at 10 s
    assert mk20.next_event() is None and mk20.reading
    assert mk20.next_deadline() == 11.0
    mk20.time_passed(10.999)
    assert mk20.next_event() is None and mk20.reading
    mk20.time_passed(11.0)
    assert mk20.next_event() == RequestReceived(Task.PING, b"")
    assert not mk20.reading and mk20.next_deadline() is None


def test_a_byte_that_comes_before_the_second_is_out_restarts_it():
    mk20 = CommStackProtocol()
    frame = encode_packet(PING)[:-1]
    mk20.receive_data(frame[:3])
    mk20.time_passed(10.0)
    mk20.receive_data(frame[3:])
    mk20.time_passed(10.9)  # read at once: the second counts from here
    assert mk20.next_deadline() == 11.9
    mk20.time_passed(11.5)
    assert mk20.next_event() is None and mk20.reading
    mk20.time_passed(11.9)
    assert mk20.next_event() == RequestReceived(Task.PING, b"")


# -- the MK20's tasks -----------------------------------------------------------------------
async def exchange(host, packet: Packet) -> Packet:
    await host.send_all(encode_packet(packet))
    buffer = b""
    while True:
        buffer += await host.receive_some()
        for frame in frames(buffer):
            answer = decode_frame(frame)
            if isinstance(answer, Packet) and answer.comm_type != CommType.REQUEST:
                return answer


@pytest.fixture
def sd_printer(tmp_path):
    return Printer(PrinterConfig(sd_dir=tmp_path))


async def test_files_are_stored_on_the_card_and_printed(autojump_clock, sd_printer, tmp_path):
    async with running_printer(ServerConfig(protocol="auto"), sd_printer) as printer:
        host = printer.link.open_host()
        request = lambda task, data=b"": exchange(host, Packet(task, CommType.REQUEST, data))  # noqa: E731
        assert (await request(Task.PING, struct.pack("<i", 7))).data == struct.pack("<i", 109)
        info = await request(Task.GET_SYSTEM_INFO)
        assert len(info.data) == 128 and info.data[48:59] == b"fake-marlin"
        opened = json.dumps({"localFilePath": "/jobs/part.gcode", "fileSize": 24, "compression": 1})
        assert (await request(Task.FILE_OPEN_FOR_WRITE, opened.encode() + b"\0")).comm_type == CommType.RESPONSE_SUCCESS
        assert (await request(Task.FILE_SET_SIZE, struct.pack("<I", 24))).comm_type == CommType.RESPONSE_SUCCESS
        await request(Task.FILE_SAVE_DATA, b"G28\nG1 X5 F3000\n")
        await request(Task.FILE_SAVE_DATA, b"M400\nM8\n")
        closed = await request(Task.FILE_CLOSE)
        assert closed.data == struct.pack("<I", 24)
        assert (tmp_path / "jobs" / "part.gcode").read_bytes() == b"G28\nG1 X5 F3000\nM400\nM8\n"
        assert (await request(Task.PRINT_PROJECT_WITH_ID)).comm_type == CommType.RESPONSE_SUCCESS
        await trio.sleep(30)
        ran = await request(Task.RUN_PRINTER_GCODE, b"M114\0")
        assert ran.data.startswith(b"X:5.00 Y:0.00 Z:0.00")
        assert (await request(Task.PRINT_PROJECT_WITH_ID, b"/nowhere.gcode\0")).comm_type == CommType.RESPONSE_FAILED
        assert (await request(Task.FILE_OPEN_FOR_WRITE, b"../outside\0")).comm_type == CommType.RESPONSE_FAILED
        assert (await request(Task.DEBUG_LOG, b"x")).comm_type == CommType.RESPONSE_SUCCESS
        journal = printer.journal
    assert journal == ["G28", "G1 X5 F3000", "M400", "M8", "M114"]


async def test_rle16_data_is_expanded(autojump_clock, sd_printer, tmp_path):
    async with running_printer(ServerConfig(protocol="commstack"), sd_printer) as printer:
        host = printer.link.open_host()
        opened = json.dumps({"localFilePath": "ui.min", "compression": 2}).encode() + b"\0"
        await exchange(host, Packet(Task.FILE_OPEN_FOR_WRITE, CommType.REQUEST, opened))
        bad = await exchange(host, Packet(Task.FILE_SAVE_DATA, CommType.REQUEST, b"\x02\x01"))
        assert bad.comm_type == CommType.RESPONSE_FAILED
        await exchange(host, Packet(Task.FILE_SAVE_DATA, CommType.REQUEST, b"\x03\x41\x42\x01\x43\x44"))
        await exchange(host, Packet(Task.FILE_CLOSE, CommType.REQUEST))
    assert (tmp_path / "ui.min").read_bytes() == b"ABABABCD"


async def test_a_request_whose_marker_is_lost_is_answered_once_the_line_is_quiet(autojump_clock):
    async with running_printer(ServerConfig(protocol="commstack")) as printer:
        host = printer.link.open_host()
        await host.send_all(encode_packet(Packet(Task.PING, CommType.RESPONSE_SUCCESS)))
        await trio.sleep(0.5)
        await host.send_all(encode_packet(Packet(Task.GET_SYSTEM_INFO, CommType.REQUEST))[:-1])
        started = trio.current_time()
        buffer = b""
        with trio.fail_after(5):
            while not any(
                isinstance(p := decode_frame(f), Packet) and p.task == Task.GET_SYSTEM_INFO
                for f in frames(buffer)
            ):
                buffer += await host.receive_some()
        assert 1.0 <= trio.current_time() - started < 1.1


async def test_the_mk20_pings_until_someone_answers(autojump_clock):
    async with running_printer(ServerConfig(protocol="commstack")) as printer:
        host = printer.link.open_host()
        await trio.sleep(11)
        pings = frames(await host.receive_some())
        assert [decode_frame(f) for f in pings] == [Packet(Task.PING, CommType.REQUEST, struct.pack("<i", 109))] * 3
        await host.send_all(encode_packet(Packet(Task.PING, CommType.RESPONSE_SUCCESS, struct.pack("<i", 1))))
        await trio.sleep(20)
        await host.send_all(encode_packet(PING))
        assert [decode_frame(f).comm_type for f in frames(await host.receive_some())] == [CommType.RESPONSE_SUCCESS]


async def test_a_ping_from_the_host_stops_the_mk20s_pings_too(autojump_clock):
    """Application::runTask: a Ping request sets _espOK, as the ESP's answer to a ping does."""
    async with running_printer(ServerConfig(protocol="commstack")) as printer:
        host = printer.link.open_host()
        await trio.sleep(1)
        await host.send_all(encode_packet(PING))
        await trio.sleep(20)
        received = [decode_frame(f) for f in frames(await host.receive_some())]
    assert [p.comm_type for p in received] == [CommType.REQUEST, CommType.RESPONSE_SUCCESS]


async def test_a_pulled_card_takes_the_file_being_written_and_the_file_just_stored(
    autojump_clock, sd_printer, tmp_path
):
    """After sd-removed nothing is printed or written: PrintProjectWithID without a name (the
    file just stored) is refused, even once M21 mounts a card again, and a file that was open
    for writing takes no more data (success, as writeToFile answers, at an unchanged length)."""
    async with running_printer(ServerConfig(protocol="commstack"), sd_printer) as printer:
        host = printer.link.open_host()
        request = lambda task, data=b"": exchange(host, Packet(task, CommType.REQUEST, data))  # noqa: E731
        await request(Task.FILE_OPEN_FOR_WRITE, b'{"localFilePath":"a.gcode"}\0')
        await request(Task.FILE_SAVE_DATA, b"M117 a\n")
        assert (await request(Task.FILE_CLOSE)).data == struct.pack("<I", 7)
        await request(Task.FILE_OPEN_FOR_WRITE, b'{"localFilePath":"b.gcode"}\0')
        assert (await request(Task.FILE_SAVE_DATA, b"M117 b\n")).data == struct.pack("<I", 7)
        apply(sd_printer, Failure(FailureKind.SD_REMOVED), trio.current_time())
        assert (await request(Task.PRINT_PROJECT_WITH_ID)).comm_type == CommType.RESPONSE_FAILED
        saved = await request(Task.FILE_SAVE_DATA, b"M117 c\n")
        assert saved == Packet(Task.FILE_SAVE_DATA, CommType.RESPONSE_SUCCESS, struct.pack("<I", 7))
        await request(Task.RUN_PRINTER_GCODE, b"M21\0")
        assert (await request(Task.FILE_SAVE_DATA, b"M117 d\n")).data == struct.pack("<I", 7)
        await request(Task.FILE_CLOSE)
        assert (await request(Task.PRINT_PROJECT_WITH_ID)).comm_type == CommType.RESPONSE_FAILED
        named = await request(Task.PRINT_PROJECT_WITH_ID, b"a.gcode\0")
        assert named.comm_type == CommType.RESPONSE_SUCCESS
        await trio.sleep(5)
        journal = printer.journal
    assert (tmp_path / "b.gcode").read_bytes() == b"M117 b\n"
    assert [line for line in journal if line.startswith("M117")] == ["M117 a"]


# -- the host -------------------------------------------------------------------------------
JOB = ["G28", "M104 S200", "M117 Stored and printed"] + [f"G1 X{n % 50}.5 Y{n % 20} E{n / 10:.2f} F3000" for n in range(300)]


@pytest.mark.parametrize(
    "faults",
    [
        (),
        ("to-printer:bit-errors=1e-4", "to-host:bit-errors=1e-4"),
        ("to-printer:drop-bytes=2e-3", "to-host:drop-bytes=5e-3"),
    ],
)
async def test_the_host_uploads_and_prints_a_job_exactly_once(autojump_clock, sd_printer, tmp_path, faults):
    config = FaultConfig(seed=2)
    for spec in faults:
        config = parse_fault(spec, config)
    async with running_printer(ServerConfig(protocol="auto", faults=config), sd_printer) as printer:
        async with connect(printer.link.open_host(), "commstack") as client:
            summary = await client.print_commands(JOB)
        journal = printer.journal
    assert summary.commands == len(JOB)
    assert (tmp_path / "job.gcode").read_text() == "".join(command + "\n" for command in JOB)
    assert [line for line in journal if not is_host_command(line)] == JOB
    if faults:
        assert summary.resends + summary.timeouts > 0


async def test_the_host_follows_the_print_until_the_printer_says_it_is_done(autojump_clock):
    """An answer to M27 that is neither `Not SD printing` nor progress (a late answer to
    `M27 C`, or one damaged past the checksum) is asked again, not taken for the end."""
    client = CommStackClient(printer_link_stub())
    answers = iter([
        b"Current file: JOB.GCO job.gcode", b"SD printing byte 5/10",
        b"SD printine byte 7<10", b"Not SD printing",
    ])
    asked: list[bytes] = []

    async def run(steps):
        try:
            request = next(steps)
            while True:
                if request.task in SYNC_TASKS:
                    result = Result(Outcome.SUCCESS)
                else:
                    asked.append(request.data)
                    result = Result(Outcome.SUCCESS, next(answers))
                request = steps.send(result)
        except StopIteration as done:
            return done.value

    client._run = run
    progress: list[int] = []
    await client.wait_for_print(progress.append)
    assert asked == [b"M27\0"] * 4 and progress == [5]


def printer_link_stub():
    class Stream:
        async def send_all(self, data: bytes) -> None:
            pass

        async def receive_some(self, max_bytes: int | None = None) -> bytes:
            await trio.sleep_forever()
            return b""

    return Stream()


@given(packets)
def test_auto_detection_knows_a_frame_by_its_header_and_waits_for_no_more(packet):
    wire = encode_packet(packet)
    assert all(starts_with_header(wire[:cut]) in (None, True) for cut in range(len(wire)))
    assert starts_with_header(wire) is True
    assert starts_with_header(b"\x01\x0e\x01\x14M105\n") is False  # STK500 noise, then Marlin


# -- the MK20's pings: a boot, or an answer of ours that was lost ---------------------------
class LosesTheFirstPingAnswer:
    """The host's end of the line, where the host's first answer to one of the MK20's pings
    is lost on its way (as a dropped byte spoils it: campaign 2036, case 135)."""

    ANSWER = encode_packet(Packet(Task.PING, CommType.RESPONSE_SUCCESS, struct.pack("<i", 1)))

    def __init__(self, stream) -> None:
        self.stream = stream
        self.lost = False

    async def send_all(self, data: bytes) -> None:
        if not self.lost and self.ANSWER in data:
            data, self.lost = data.replace(self.ANSWER, b"", 1), True
        await self.stream.send_all(data)

    async def receive_some(self, max_bytes: int | None = None) -> bytes:
        return await self.stream.receive_some(max_bytes)


async def test_a_ping_repeated_because_its_answer_was_lost_is_no_reset(autojump_clock, sd_printer):
    """The MK20 pings every 5 s until it hears from the ESP (Application::loop, `_espOK`): the
    answer to its boot ping lost, it pings again mid-print, as it would after a reboot. The
    host makes sure it has been heard (a Ping of its own, answered) before it starts the print,
    so only a ping after that says the printer restarted (campaign 2036, case 135)."""
    async with running_printer(ServerConfig(protocol="commstack"), sd_printer) as printer:
        line = LosesTheFirstPingAnswer(printer.link.open_host())
        async with connect(line, "commstack") as client:
            summary = await client.print_commands(JOB)
        journal = printer.journal
    assert line.lost
    assert summary.commands == len(JOB)
    assert [line for line in journal if not is_host_command(line)] == JOB


def test_only_a_ping_after_the_mk20_has_answered_one_of_ours_says_it_restarted():
    """Until the MK20 has answered a Ping of the host's, its pings may be repeats of one whose
    answer was lost; once it has, it pings no more (the line keeps order: a ping it sent before
    it handled the host's comes before the answer), unless it boots again."""
    ping = encode_packet(Packet(Task.PING, CommType.REQUEST, struct.pack("<i", 109)))
    host = CommStackCore()
    host.receive_data(ping * 2, 0.0)  # the boot ping, and its repeat: our answer was lost
    assert host.printer_pings == 2 and not host.printer_restarted
    handshake = host.start(Task.PING, struct.pack("<i", 1))
    host.poll(0.0)
    host.receive_data(ping, 0.0)  # sent before the MK20 read our Ping: it crossed ours on the line
    assert not host.printer_restarted
    host.receive_data(encode_packet(Packet(Task.PING, CommType.RESPONSE_SUCCESS, b"m\0\0\0")), 0.0)
    assert handshake.outcome is Outcome.SUCCESS and not host.printer_restarted
    host.receive_data(ping, 0.0)
    assert host.printer_restarted and host.printer_pings == 4
