"""One fuzz target per receiver of untrusted input: `target(data: bytes) -> None`.

Each target feeds the fuzzer's bytes in pieces whose sizes the first byte picks (framing must not
depend on how the reads split the stream; the second byte is the target's own choices, see
split()), drains every event, and checks what a user relies on:
the events make sense, what the receiver says back reads as what it meant on the other end, and
its buffers stay bounded. Only the errors a module documents are caught; anything else escapes,
so that the fuzzer reports it with the input that caused it.

Buffers are private attributes; the targets read them (never write them) to check the bounds
the modules state. `assert` is the check: do not run the fuzzer with `python -O`.
"""

import atexit
import os
import re
import shutil
import tempfile
import typing
from collections.abc import Callable

from fake_marlin.emulator.printer import gcode
from fake_marlin.emulator.protocols import commstack as cs
from fake_marlin.emulator.protocols import g2core as g2
from fake_marlin.emulator.protocols.base import CommandDone, CommandReceived
from fake_marlin.emulator.protocols import marlin, stk500
from fake_marlin.emulator.protocols import repetier as rep
from fake_marlin.emulator.protocols import ultimaker as um
from fake_marlin.emulator.scenario import definition
from fake_marlin.emulator.sessions import detect
from fake_marlin.host.codecs import g2core as host_g2core
from fake_marlin.host.codecs import lines as host_lines
from fake_marlin.host.codecs import marlin as host_marlin
from fake_marlin.host.codecs import repetier as host_repetier
from fake_marlin.host.codecs import ultimaker as host_um
from fake_marlin.host.errors import CommandError
from fake_marlin.wire import commstack as wire_cs
from fake_marlin.wire import g2core as wire_g2
from fake_marlin.wire import repetier as wire_rep
from fake_marlin.wire import ultimaker as wire_um
from fake_marlin.wire import ultimaker_variants as lab
from fake_marlin.wire.gcode import canonical, remove_paren_comments, strip_comment

# -- bugs found and reported, not yet fixed ---------------------------------------------------
# Each has its input in fuzz/known/<target>/<name>, which tests/test_fuzz.py expects to fail
# until the bug is fixed. By default the targets find them again like any other bug; with
# FUZZ_SKIP_KNOWN=1 they step around them, so that a campaign can look past them.
KNOWN: dict[str, str] = {}  # none open: the last three were fixed in canonical() and LineBuffer
SKIP_KNOWN = os.environ.get("FUZZ_SKIP_KNOWN") == "1"


def known(hit: bool) -> bool:
    """Whether to step around a known bug here: only when told to."""
    return SKIP_KNOWN and hit


# -- helpers ----------------------------------------------------------------------------------
def split(data: bytes) -> tuple[int, list[bytes]]:
    """The input as (choice, pieces). data[0] picks the piece sizes: the whole stream at once
    if its top bit is set, else pieces alternately 1-8 and 1-16 bytes long as its low bits say
    (one-byte pieces cut every frame). data[1] is the target's own choices (queue size, ...).
    The rest is the byte stream."""
    head, choice, body = (data[0] if data else 0), (data[1] if len(data) > 1 else 0), data[2:]
    if head & 0x80:
        return choice, [body] if body else []
    sizes = ((head & 7) + 1, (head >> 3 & 15) + 1)
    out, at = [], 0
    while at < len(body):
        size = sizes[len(out) % 2]
        out.append(body[at:at + size])
        at += size
    return choice, out


def printable(data: bytes, limit: int) -> str:
    """A command a host could be asked to send, made from the input: printable ASCII without
    the characters every encoder refuses, so that most inputs reach the encoder's far side."""
    text = "".join(chr(b) for b in data if 0x20 <= b <= 0x7E and chr(b) not in ";\\*")
    return text[:limit].strip()


def resend_request(number: int) -> host_repetier.ResendRequest:
    """What the host reads of Repetier's `Resend:<number>` line."""
    return host_repetier.ResendRequest(number, f"Resend:{number}")


def host_events(parser, data: bytes) -> list:
    parser.receive_data(data)
    events = []
    while (event := parser.next_event()) is not None:
        events.append(event)
    return events


# -- the emulator's protocols: bytes from the host ---------------------------------------------
def marlin_receiver(data: bytes) -> None:
    """MarlinProtocol; each answer it gives must read back the same through the host's parser."""
    choice, chunks = split(data)
    advanced = bool(choice & 1)
    printer = marlin.MarlinProtocol(advanced_ok=advanced, queue_size=1 + (choice >> 1 & 3))
    printer.saving_to_sd = bool(choice & 8)
    host = host_marlin.LineParser()
    queued: list[int | None] = []  # line numbers of commands not yet answered `ok`

    def release() -> None:
        number = queued.pop(0)
        said = host_events(host, printer.send(CommandDone(number)))
        if advanced:
            expected = host_marlin.Ok("", number, 15, printer.queue_free)
        else:
            expected = host_marlin.Ok()
        assert said == [expected], (said, expected)

    def drain() -> None:
        while True:
            event = printer.next_event()
            if event is None:
                if printer.queue_free == 0:  # the host waits for an ok: the printer runs one
                    release()
                    continue
                return
            if isinstance(event, CommandReceived):
                assert event.text and event.text == event.text.strip(), event
                assert "*" not in event.text and not {"\r", "\n"} & set(event.text), event
                assert len(event.text) < marlin.MAX_CMD_SIZE, event
                assert event.number in (None, printer.last_n), event
                assert printer.data_to_send() == b""
                queued.append(event.number)
            elif isinstance(event, marlin.LineRejected):
                said = host_events(host, printer.data_to_send())
                assert len(said) == 3, said
                error, resend, ok = said
                kind = host_marlin.LineErrorKind[event.error.name]
                assert (error.kind, error.last_line) == (kind, printer.last_n), (said, event)
                # A negative counter (after `N-5 M110`) is said as `Resend: -4`, which no host
                # reads as a number: the host's ResendRequest then says None.
                assert resend.line == (event.resend if event.resend >= 0 else None), said
                assert ok == host_marlin.Ok(), said
            else:
                assert isinstance(event, marlin.EmergencyCommand), event
                assert event.text in ("M108", "M112", "M410") or event.text[:4] == "M876", event

    for piece in chunks:
        printer.receive_data(piece)
        drain()
        # The firmware reads on only while its queue has room: with room, it read everything.
        assert not printer._input or printer.queue_free == 0
        assert len(printer._line) < marlin.MAX_CMD_SIZE
        assert len(printer._emergency_line) <= marlin.MAX_CMD_SIZE
    while queued:
        release()
        drain()
    assert not printer._input and not printer._output


def variant_split(data: bytes) -> tuple[lab.Variants, int, list[bytes]]:
    """data[0] picks the protocol lab's variant set (lab.EVERY_SET, modulo 32); the rest is
    split() as every stream target's input."""
    variants = lab.EVERY_SET[(data[0] if data else 0) % len(lab.EVERY_SET)]
    return (variants, *split(data[1:]))


def ultimaker_receiver(data: bytes) -> None:
    """UltimakerProtocol, plain v3: as ultimaker_variant_receiver, with no variant."""
    _ultimaker_receiver(lab.PLAIN, *split(data))


def ultimaker_variant_receiver(data: bytes) -> None:
    """UltimakerProtocol with the lab's variants (data[0] picks the set): the boot line, every
    `a`, `o`, `r` frame and ProtoError line it says parse back the same on the host's
    FrameParser with the same variants, and a response line comes back as data."""
    _ultimaker_receiver(*variant_split(data))


def _ultimaker_receiver(variants: lab.Variants, choice: int, chunks: list[bytes]) -> None:
    printer = um.UltimakerProtocol(queue_size=1 + (choice & 7), variants=variants)
    packet = printer.format
    keep = printer.queue_size if choice & 8 else 0  # how many commands run late: QUEUE_FULL
    room = choice >> 4
    host = host_um.FrameParser(variants)
    boot = host_events(host, printer.send(um.OutOfBand(um.OutOfBandKind.LOG,
                                                       lab.boot_line(variants))))
    assert boot == [host_um.Line(host_um.LineKind.LOG, lab.boot_line(variants))], boot
    assert lab.announced(boot[0].text) == variants, boot
    said = host_events(host, printer.send(um.RoomChanged(room)))
    assert said == ([host_um.RoomInfo(room)] if room else []), said
    queued: list[tuple[int, str]] = []

    def release() -> None:
        seq, text = queued.pop(0)
        # The command's own text as its response, where plain v3 reads it as data at all (not a
        # frame, not an out-of-band line): compact-oob escapes what looks like its own lines.
        response = (text,) if host_um.parse_line(text) == host_um.Line(
            host_um.LineKind.RESPONSE, text) else ()
        said = host_events(host, printer.send(CommandDone(seq, room, response)))
        expected = [host_um.Line(host_um.LineKind.RESPONSE, line) for line in response]
        assert said == [*expected, host_um.Ack(seq, room)], (said, response)

    for piece in chunks:
        printer.receive_data(piece)
        while (event := printer.next_event()) is not None:
            if isinstance(event, CommandReceived):
                assert event.number == packet.next_seq(printer.expected_seq, -1), event
                assert wire_um.payload_error(event.text.encode("ascii")) is None, event
                out = printer.data_to_send()
                if variants.ack:
                    said = host_events(host, out)
                    assert said == [host_um.Received(event.number, printer.room)], (said, event)
                else:
                    assert out == b"", (out, event)
                queued.append((event.number, event.text))
                if len(queued) > keep:
                    release()
            else:
                assert isinstance(event, um.PacketRejected), event
                said = host_events(host, printer.data_to_send())
                expected = [
                    host_um.Line(host_um.LineKind.PROTO_ERROR, event.message),
                    host_um.Reject(event.expected, printer.room),
                ]
                assert said == expected, (said, expected)
        assert not printer._input and len(printer._payload) <= wire_um.MAX_PAYLOAD
        assert len(printer._check) <= packet.check_chars
        assert 0 <= printer.expected_seq < packet.sequence_modulus
        while queued:  # the printer catches up between two reads
            release()


def repetier_receiver(data: bytes) -> None:
    """RepetierProtocol, with its stall timeout now and then; every reply must read as Ok,
    Skip, Resend or an error line on the host."""
    choice, chunks = split(data)
    printer = rep.RepetierProtocol(queue_size=1 + (choice & 3))
    host = host_repetier.LineParser()

    def said() -> list:
        events = host_events(host, printer.data_to_send())
        for event in events:
            answer = (host_repetier.Ok, host_repetier.Skip, host_repetier.ResendRequest)
            is_error = isinstance(event, host_repetier.Line) and event.kind.name == "ERROR"
            assert isinstance(event, answer) or is_error, events
        return events

    clock = 0.0  # the firmware's time: a millisecond a piece, and the stalls
    for number, piece in enumerate(chunks):
        printer.receive_data(piece)
        while True:
            event = printer.next_event()
            if event is None:
                if printer.has_input and not printer.reading:  # the oldest command ran
                    printer.send(CommandDone())
                    continue
                break
            if isinstance(event, CommandReceived):
                assert said()[-1:] == [host_repetier.Ok(line_number=printer.act_line)], event
                if event.number is not None:
                    assert event.number == printer.last_line, event
            elif isinstance(event, rep.CommandRejected):
                events = said()
                resend = [resend_request(event.resend), host_repetier.Ok()]
                assert events[-2:] == resend, events
            else:
                assert isinstance(event, rep.EmergencyStop), event
        clock += 0.001
        printer.time_passed(clock)
        said()  # M110's ok, skips
        assert not printer._input or not printer.reading
        assert len(printer._command) < rep.MAX_CMD_SIZE
        stalled = printer.expects_more and printer.reading and not printer.has_input
        if choice >> (number % 6 + 2) & 1 and stalled:
            clock += rep.STALL_TIMEOUT  # 200 ms without a byte
            printer.time_passed(clock)
            assert said()[-2:] == [resend_request(printer.last_line + 1 & 0xFFFFFFFF),
                                   host_repetier.Ok()]
        if not printer.reading and not printer.has_input:
            printer.send(CommandDone())


def commstack_receiver(data: bytes) -> None:
    """CommStackProtocol; every answer must decode on the ESP's side as the packet meant."""
    choice, chunks = split(data)
    printer = cs.CommStackProtocol()
    answers = wire_cs.FrameSplitter()

    def answered(said: bytes | None = None) -> list[wire_cs.Decoded]:
        answers.receive_data(printer.data_to_send() if said is None else said)
        frames = []
        while (frame := answers.next_frame()) is not None:
            frames.append(wire_cs.decode_frame(frame))
        return frames

    def drain() -> None:
        while (event := printer.next_event()) is not None:
            if isinstance(event, cs.RequestReceived):
                assert answered() == []
                reply = cs.Response(event.task, bool(choice & 1), event.data[: wire_cs.MAX_DATA])
                comm_type = (wire_cs.CommType.RESPONSE_SUCCESS if reply.success
                             else wire_cs.CommType.RESPONSE_FAILED)
                expected = [wire_cs.Packet(reply.task, comm_type, reply.data)]
                assert answered(printer.send(reply)) == expected
            elif isinstance(event, cs.ResponseReceived):
                assert event.packet.comm_type != wire_cs.CommType.REQUEST, event
                assert answered() == []
            else:
                assert isinstance(event, cs.FrameRejected), event
                expected = [wire_cs.Packet(printer._last_task, wire_cs.CommType.RESPONSE_FAILED)]
                assert answered() == (expected if event.answered else []), event

    for number, piece in enumerate(chunks):
        printer.receive_data(piece)
        drain()
        printer.time_passed(2.0 * number)  # a piece every two seconds
        assert len(printer._frames._buffer) < cs.READ_LIMIT
        if choice >> (number % 7 + 1) & 1 and printer.reading:
            printer.time_passed(2.0 * number + cs.READ_TIMEOUT)  # the frame ends where it is
            drain()
            assert not printer.reading


def stk500_receiver(data: bytes) -> None:
    """Stk500Protocol up to the hand-over; each reply must read back as a message itself, and
    the hand-over must pass on exactly what followed LEAVE."""
    printer = stk500.Stk500Protocol()
    fed = b""
    for piece in split(data)[1]:
        printer.receive_data(piece)
        fed += piece
        while (event := printer.next_event()) is not None:
            if isinstance(event, stk500.LeftBootloader):
                assert fed.endswith(event.rest), event
                assert printer.next_event() is None
                return  # the firmware reads the rest; feeding the bootloader now is an error
            assert isinstance(event, stk500.MessageReceived), event
            assert 1 <= len(event.body) <= stk500.MAX_BODY, event
            message = stk500.encode_message(event.seq, event.body)
            assert message in fed, event
            body = stk500.answer(event.body)
            echo = stk500.Stk500Protocol()  # replies are framed as messages are
            echo.receive_data(printer.send(stk500.Answer(event.seq, body)))
            assert echo.next_event() == stk500.MessageReceived(event.seq, body)
        # Waiting for the rest of at most one message: header, the longest body, checksum.
        assert len(printer._input) <= stk500.HEADER_SIZE + stk500.MAX_BODY + 1


class _Session:
    """What the detector hands over to: records what it was fed."""

    def __init__(self, protocol: detect.Detected) -> None:
        self.protocol = protocol
        self.fed = bytearray()
        self.booted = False

    def boot(self) -> None:
        self.booted = True

    def feed(self, data: bytes) -> None:
        self.fed += data


def g2core_receiver(data: bytes) -> None:
    """G2coreProtocol, reading G-code now and then not (a full planner): every event is one it
    declares, each line's size is at least its own bytes, no data line is lost while reads are
    held, and each answer the board gives reads back through the host's parser as the same."""
    choice, chunks = split(data)
    protocol = g2.G2coreProtocol()
    events: list[object] = []
    for index, piece in enumerate(chunks):
        protocol.reading_gcode = not (choice >> (index % 8)) & 1
        protocol.receive_data(piece)
        while (event := protocol.next_event()) is not None:
            events.append(event)
    protocol.reading_gcode = True
    while (event := protocol.next_event()) is not None:
        events.append(event)
    assert protocol.waiting_lines == 0
    for event in events:
        assert isinstance(event, (CommandReceived, g2.JsonRequest, g2.BadRequest, g2.BadLine,
                                  g2.SingleCharacter)), event
        if isinstance(event, (CommandReceived, g2.JsonRequest, g2.BadRequest, g2.BadLine)):
            assert 1 <= event.size <= g2.RX_BUFFER_SIZE + 2, event
            status = 0 if isinstance(event, (CommandReceived, g2.JsonRequest)) else event.status
            answer = protocol.send(g2.Response({"n": 1}, status, event.size))
            reply = host_g2core.parse_line(answer.rstrip(b"\n"))
            assert isinstance(reply, host_g2core.Response), (answer, reply)
            assert (reply.status, reply.length) == (status, event.size)


def host_g2core_parser(data: bytes) -> None:
    """host ReplyReader (g2core): any bytes are events of its four kinds, never an exception;
    a response, report or banner the board can write reads back as that."""
    _parse_all(host_g2core.ReplyReader(), split(data)[1], host_g2core.Event)
    written = {
        wire_g2.response({"qr": 15}, 0, 8): host_g2core.Response,
        wire_g2.report("sr", {"stat": 5, "posx": wire_g2.Number(1.5, 3)}): host_g2core.Report,
        wire_g2.response({"fb": wire_g2.Number(101.03, 2), "msg": "SYSTEM READY"}, 0, 1):
            host_g2core.Boot,
    }
    for line, kind in written.items():
        assert isinstance(host_g2core.parse_line(line.rstrip(b"\n")), kind)


def protocol_detector(data: bytes) -> None:
    """DetectingSession.feed (its sans-IO part; the 200 ms give-up in run() needs trio's clock):
    at most one session, booted before fed; it gets an unbroken tail of the stream that starts
    with a byte that names its protocol; what is held while undecided stays small."""
    choice, chunks = split(data)
    bootloader = bool(choice & 1)
    made: list[_Session] = []

    def make(protocol: detect.Detected) -> _Session:
        assert not made, "a second session"
        made.append(_Session(protocol))
        return made[0]

    detector = detect.DetectingSession(make, bootloader)
    stream = b""
    for piece in chunks:
        detector.feed(piece)
        stream += piece
        if made:
            session = made[0]
            assert session.booted and detector.active is session
            assert session.fed and stream.endswith(session.fed), (stream, session.fed)
            assert detect.classify(session.fed[0], bootloader) is session.protocol
        else:
            assert detector.active is None
            assert stream.endswith(detector._held)
            assert len(detector._held) <= rep.MAX_CMD_SIZE  # a Repetier command is the longest wait


# -- the host's parsers: bytes from the printer -----------------------------------------------
def _parse_all(parser, chunks: list[bytes], event: object) -> None:
    """Feed the host parser the pieces: each event is one its codec declares (`event`, the
    codec's Event union), and its line buffer stays within MAX_LINE."""
    kinds = typing.get_args(event)
    for piece in chunks:
        for parsed in host_events(parser, piece):
            assert isinstance(parsed, kinds), parsed
        assert len(parser._lines._buffer) <= host_lines.MAX_LINE


def host_marlin_parser(data: bytes) -> None:
    """host LineParser (Marlin); and a line the host encodes must reach MarlinProtocol as the
    same command with the same number."""
    choice, chunks = split(data)
    parser = host_marlin.LineParser()
    _parse_all(parser, chunks, host_marlin.Event)
    command = printable(data[2:], host_marlin.MAX_COMMAND)
    number = 1 + choice**3  # 1 to 16581376: short numbers and long
    try:
        line = host_marlin.encode_line(number, host_marlin.check_command(command))
    except CommandError:
        return
    printer = marlin.MarlinProtocol()
    printer.last_n = number - 1
    printer.receive_data(line)
    events = []  # M112 and the like come first, then the line
    while (event := printer.next_event()) is not None:
        events.append(event)
    events = [event for event in events if not isinstance(event, marlin.EmergencyCommand)]
    text = remove_paren_comments(command).strip()  # ( ) comments are no part of the command
    assert events == ([CommandReceived(text, number)] if text else []), (line, events)


def host_ultimaker_parser(data: bytes) -> None:
    """host FrameParser, plain v3: as host_ultimaker_variant_parser, with no variant."""
    choice, chunks = split(data)
    _host_ultimaker_parser(lab.PLAIN, choice, chunks, data[0] if data else 0, data[2:])


def host_ultimaker_variant_parser(data: bytes) -> None:
    """host FrameParser with the lab's variants (data[0] picks the set): any bytes are events
    of its kinds; every frame and out-of-band line the printer can say parses back; a packet
    the host encodes in the variants' format reaches UltimakerProtocol as the same command."""
    variants, choice, chunks = variant_split(data)
    _host_ultimaker_parser(variants, choice, chunks, data[1] if len(data) > 1 else 0, data[2:])


def _host_ultimaker_parser(variants: lab.Variants, choice: int, chunks: list[bytes], room: int,
                           rest: bytes) -> None:
    parser = host_um.FrameParser(variants)
    _parse_all(parser, chunks, host_um.Event)
    packet = variants.packet
    seq = choice % packet.sequence_modulus
    for kind, event in (("o", host_um.Ack(seq, room)), ("r", host_um.Reject(seq, room)),
                        ("a", host_um.Received(seq, room)), ("q", host_um.RoomInfo(room))):
        assert host_um.parse_line(wire_um.frame_body(kind, seq, room), variants) == event
    text = printable(rest, wire_um.MAX_PAYLOAD)
    printer = um.UltimakerProtocol(variants=variants)
    if text:
        for said_as, line_kind in ((um.OutOfBandKind.LOG, host_um.LineKind.LOG),
                                   (um.OutOfBandKind.ERROR, host_um.LineKind.ERROR),
                                   (um.OutOfBandKind.WARNING, host_um.LineKind.WARNING)):
            said = host_events(host_um.FrameParser(variants),
                               printer.send(um.OutOfBand(said_as, text)))
            assert said == [host_um.Line(line_kind, text)], (said_as, text, said)
    try:
        encoded = host_um.encode_command(seq, text, packet)
    except CommandError:
        return
    if packet.armored:  # no byte of a sync-byte packet but its start may be SYN or above 0x7F
        body = encoded[packet.starts:]
        assert max(body) < 0x80 and lab.SYN not in body, encoded
    printer.expected_seq = seq
    printer.receive_data(encoded)
    assert printer.next_event() == CommandReceived(text, seq), encoded


def host_repetier_parser(data: bytes) -> None:
    """host LineParser (Repetier); a command the host encodes (binary where it fits) reaches
    RepetierProtocol as the same command, by canonical() as the journals compare them."""
    choice, chunks = split(data)
    parser = host_repetier.LineParser()
    _parse_all(parser, chunks, host_repetier.Event)
    command = printable(data[2:], host_marlin.MAX_COMMAND)
    number, version = choice**4, choice % 3  # 0 to 2^32 - 1; ASCII, V1 or V2
    try:
        checked = host_repetier.check_command(command)
        wire, binary = host_repetier.encode_command(number, checked, version)
    except CommandError:
        return
    printer = rep.RepetierProtocol()
    printer.last_line = (number - 1) & 0xFFFFFFFF
    printer.receive_data(wire)
    event = printer.next_event()
    if isinstance(event, CommandReceived):
        assert printer.last_was_binary == binary and event.number == number & 0xFFFF, (wire, event)
        assert canonical(event.text) == canonical(command), (wire, event, command)
    else:
        # The firmware's own reading: M112 anywhere stops it, a line without G, M or T is a
        # format error, and an M code is 16 bits (M65646 is M110, which answers nothing).
        assert isinstance(event, (rep.EmergencyStop, rep.CommandRejected)) or event is None, event


# -- the wire codecs ----------------------------------------------------------------------------
def commstack_frames(data: bytes) -> None:
    """FrameSplitter and decode_frame: no byte lost or invented, frames bounded; a packet
    re-encoded decodes the same; a frame with a sound header passes the detector's check."""
    splitter = wire_cs.FrameSplitter()
    frames, stream = [], b""
    for piece in split(data)[1]:
        splitter.receive_data(piece)
        stream += piece
        while (frame := splitter.next_frame()) is not None:
            assert len(frame) <= wire_cs.BUFFER_SIZE and 0 not in frame
            frames.append(frame)
        assert len(splitter._buffer) < wire_cs.BUFFER_SIZE and 0 not in splitter._buffer
    # Every 0x00 ends a frame and every other byte is in one (or still waits).
    assert b"".join(frames) + splitter._buffer == stream.replace(b"\0", b"")
    for frame in frames:
        decoded = wire_cs.decode_frame(frame)
        if isinstance(decoded, (wire_cs.Packet, wire_cs.BadData)):
            assert wire_cs.starts_with_header(frame + wire_cs.MARKER) is True, frame.hex()
        if isinstance(decoded, wire_cs.Packet):
            try:
                encoded = wire_cs.encode_packet(decoded)
            except ValueError:
                assert len(decoded.data) > wire_cs.MAX_DATA
                continue
            assert encoded[-1:] == wire_cs.MARKER and 0 not in encoded[:-1]
            assert wire_cs.decode_frame(encoded[:-1]) == decoded, frame.hex()


def repetier_binary(data: bytes) -> None:
    """command_size, decode, encode, to_gcode and from_gcode. The input is taken as a command
    twice: as it is (its checksum mostly wrong: BadChecksum) and with its checksum made right,
    so that the decoder's far side is reached."""
    sizes = {wire_rep.command_size(data[:length]) for length in range(2, 6)} - {None}
    assert len(sizes) <= 1 and all(size >= 4 for size in sizes), sizes  # one size, once known
    if not sizes or len(data) < min(sizes):
        return
    frame = data[: min(sizes)]
    try:
        wire_rep.decode(frame)
    except wire_rep.BadChecksum:
        pass
    body = frame[:-2]
    frame = body + bytes(wire_rep.fletcher16(body))
    command = wire_rep.decode(frame)
    text = wire_rep.to_gcode(command)
    printer = rep.RepetierProtocol()  # the emulator's reader, given a command that checks out
    printer.receive_data(frame)
    event = printer.next_event()
    assert event is None or isinstance(event, (CommandReceived, rep.CommandRejected,
                                               rep.EmergencyStop)), event
    try:
        encoded = wire_rep.encode(command)
    except ValueError:
        return
    assert wire_rep.command_size(encoded[:5]) == len(encoded), encoded.hex()
    assert repr(wire_rep.decode(encoded)) == repr(command), encoded.hex()  # repr: NaN == NaN
    again = wire_rep.from_gcode(text, command.n, command.v2)
    if again is not None:
        assert canonical(wire_rep.to_gcode(again)) == canonical(text), (text, again)


def gcode_parser(data: bytes) -> None:
    """gcode.parse (the printer model's) and canonical() (the journals'), on any text."""
    line = data.decode("utf-8", "replace")
    command = gcode.parse(line)
    assert command.text == strip_comment(line)
    # No command, a letter's code (G1, M105, T0, Prusa's D3) or a word's (Klipper's STATUS).
    assert command.code == "" or re.fullmatch(r"[GMTD][\d.]*|[A-Z][A-Z_][A-Z0-9_]*", command.code), command
    for letter, value in command.params.items():
        assert len(letter) == 1 and letter.isupper() and (value is None or isinstance(value, float))
        command.value(letter, 0.0)
    command.string_argument
    once = canonical(line)
    assert canonical(once) == once, (line, once)  # one spelling: the journals compare these
    move = gcode.plain_move(line)  # the quick way's reading of a move: parse()'s numbers
    if move is not None:
        first_feed, *axes, last_feed = move
        feed = last_feed if last_feed is not None else first_feed
        read = dict(zip("XYZEF", [*axes, feed]))
        assert command.code in ("G0", "G1") and command.params == {
            letter: float(number) for letter, number in read.items() if number is not None
        }, (line, move, command)


# -- the scenario loader ------------------------------------------------------------------------
_scenario_file: list[str] = []  # made on first use: one file per process, rewritten per input


def _scenario_path() -> str:
    if not _scenario_file:
        folder = tempfile.mkdtemp(prefix="fuzz-scenario-")
        atexit.register(shutil.rmtree, folder, True)  # (libFuzzer's exit skips this)
        _scenario_file.append(os.path.join(folder, "scenario.toml"))
    return _scenario_file[0]


def scenario_loader(data: bytes) -> None:
    """definition.load on the input as a scenario file (load takes only a path; the parsed
    table's readers are private). ScenarioError is its one documented error: "every mistake in
    a file is reported with the file, the key and the problem, never as a traceback"."""
    path = _scenario_path()
    with open(path, "wb") as file:
        file.write(data)
    try:
        scenario = definition.load(path)
    except definition.ScenarioError:
        return
    assert scenario.printer.protocol in definition.PROTOCOLS
    assert scenario.host_protocol in definition.HOST_PROTOCOLS
    assert 1 <= scenario.host.window <= 32


TARGETS: dict[str, Callable[[bytes], None]] = {
    target.__name__: target
    for target in (
        marlin_receiver, ultimaker_receiver, ultimaker_variant_receiver, repetier_receiver,
        commstack_receiver, stk500_receiver, g2core_receiver, protocol_detector,
        host_marlin_parser, host_ultimaker_parser, host_ultimaker_variant_parser,
        host_g2core_parser,
        host_repetier_parser, commstack_frames, repetier_binary, gcode_parser, scenario_loader,
    )
}
