"""The protocol lab's variants of Ultimaker's protocol (docs/protocols.md section 1.1), both
ends: the bytes each variant puts on the wire (vectors checked against the format rules and
independent CRCs), the printer's receiver and its resync, plain v3 left byte for byte as it
was, the 7-bit line, the host's ack timer and its VariantMismatch, and the ways a user asks
for a variant (command lines, scenario files, fuzz campaigns)."""

import binascii
import re
import subprocess
import sys
from pathlib import Path

import pytest
import trio
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from fake_marlin.emulator.faults.layer import FaultConfig, FaultLayer, LineFaults
from fake_marlin.emulator.protocols.base import CommandDone, CommandReceived, Output
from fake_marlin.emulator.protocols.ultimaker import (
    OutOfBand,
    OutOfBandKind,
    PacketRejected,
    RejectReason,
    RoomChanged,
    UltimakerProtocol,
)
from fake_marlin.emulator.scenario import campaign, fuzz
from fake_marlin.emulator.scenario.definition import ScenarioError, load
from fake_marlin.emulator.scenario.run import run_scenario
from fake_marlin.host import ClientOptions, PrinterReset, VariantMismatch, connect
from fake_marlin.host.codecs import ultimaker as host_um
from fake_marlin.host.codecs.ultimaker import (
    Ack,
    FrameParser,
    Line,
    LineKind,
    Received,
    Reject,
    RoomInfo,
    encode_command,
)
from fake_marlin.testing import memory_printer
from fake_marlin.wire import ultimaker as v3
from fake_marlin.wire import ultimaker_variants as lab
from fake_marlin.wire.ultimaker_variants import (
    NAMES,
    PLAIN,
    VariantError,
    Variants,
    announced,
    boot_line,
    parse_variants,
)

BIN = Path(sys.executable).parent
ALL_SETS = lab.EVERY_SET  # bit k of the index is NAMES[k]
V = parse_variants
JOB = ["G28", *(f"G1 X{n % 40} Y{n % 17} F6000" for n in range(60)), "M105", "M400"]


# -- the format rules, written out again here (not the code under test) ----------------------
def crc8_bitwise(data: bytes) -> int:
    """CRC-8/SMBUS bit by bit: poly 0x07, init 0, no reflection, no final XOR."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc << 1 ^ 0x07) & 0xFF if crc & 0x80 else crc << 1 & 0xFF
    return crc


def crc16(data: bytes) -> int:
    return binascii.crc_hqx(data, 0xFFFF)  # CRC-16/CCITT-FALSE


def reference_packet(variants: Variants, seq: int, payload: bytes) -> bytes:
    """A packet as the table in docs/protocols.md 1.1 lays it out."""
    armored = variants.sync_byte or variants.seven_bit
    start = b"\x16" if armored else b"\xff"
    starts = start * (1 if variants.crc8 else 2)
    raw = bytes((seq, len(payload))) + payload
    check = crc8_bitwise(raw) if variants.crc8 else crc16(raw)
    if not armored:
        return starts + raw + check.to_bytes(1 if variants.crc8 else 2, "big")
    digits = 2 if variants.crc8 else 3
    armor = bytes(0x40 + (check >> 6 * place & 0x3F) for place in reversed(range(digits)))
    return starts + bytes((0x20 + seq, 0x1F + len(payload))) + payload + armor


def frame(kind: str, seq: int, room: int) -> bytes:
    body = f"{kind}{seq:02X}{room:02X}"
    return f"\n{body}{crc8_bitwise(body.encode()):02X}\n".encode()


def feed(protocol: UltimakerProtocol, data: bytes) -> list:
    protocol.receive_data(data)
    events = []
    while (event := protocol.next_event()) is not None:
        events.append(event)
    return events


def parse_all(variants: Variants, data: bytes) -> list:
    parser = FrameParser(variants)
    parser.receive_data(data)
    events = []
    while (event := parser.next_event()) is not None:
        events.append(event)
    return events


# -- vectors ------------------------------------------------------------------------------------
# (variants, seq, payload, the packet in hex): computed once, checked by hand against the rules
# above (see /tmp/lab/vectors.md), and against reference_packet() in the test.
PACKETS = [
    ("", 0, "G28", "ffff0003473238c641"),
    ("", 1, "M105", "ffff01044d313035045a"),
    ("", 254, "M105", "fffffe044d31303550e5"),
    ("ack", 0, "G28", "ffff0003473238c641"),
    ("compact-oob", 1, "M105", "ffff01044d313035045a"),
    ("ack,compact-oob", 254, "M105", "fffffe044d31303550e5"),
    ("crc8", 0, "G28", "ff0003473238d1"),
    ("crc8", 1, "M105", "ff01044d3130353b"),
    ("crc8", 95, "M105", "ff5f044d3130356a"),
    ("crc8", 254, "M105", "fffe044d31303594"),
    ("sync-byte", 0, "G28", "161620224732384c5941"),
    ("sync-byte", 1, "M105", "161621234d31303540515a"),
    ("sync-byte", 95, "M105", "16167f234d3130354f516d"),
    ("7bit", 0, "G28", "161620224732384c5941"),
    ("7bit", 95, "M105", "16167f234d3130354f516d"),
    ("crc8,sync-byte", 0, "G28", "1620224732384351"),
    ("crc8,sync-byte", 1, "M105", "1621234d313035407b"),
    ("crc8,sync-byte", 95, "M105", "167f234d313035416a"),
    ("crc8,7bit", 1, "M105", "1621234d313035407b"),
    ("ack,compact-oob,crc8,sync-byte,7bit", 0, "G28", "1620224732384351"),
]


@pytest.mark.parametrize("variants, seq, payload, expected", PACKETS)
def test_packet_vectors(variants, seq, payload, expected):
    variants = V(variants)
    packet = encode_command(seq, payload, variants.packet)
    assert packet.hex() == expected
    assert packet == reference_packet(variants, seq, payload.encode())
    printer = UltimakerProtocol(variants=variants)
    printer.expected_seq = seq
    assert feed(printer, packet) == [CommandReceived(payload, seq)]


def test_the_checks_are_the_catalogue_crcs_and_the_digits_carry_them_six_bits_each():
    assert crc8_bitwise(b"123456789") == 0xF4 == lab.crc8_smbus(b"123456789")
    assert crc16(b"123456789") == 0x29B1
    # G28 at seq 0: CRC-16 c641 = 0b1100_011001_000001 -> 4c 59 41; CRC-8 d1 = 0b11_010001 -> 43 51
    raw = bytes((0, 3)) + b"G28"
    assert crc16(raw) == 0xC641 and crc8_bitwise(raw) == 0xD1
    assert V("sync-byte").packet.check_bytes(0xC641) == bytes.fromhex("4c5941")
    assert V("crc8,sync-byte").packet.check_bytes(0xD1) == bytes.fromhex("4351")
    for variants in ALL_SETS:
        packet = variants.packet
        assert packet.read_check(packet.check_bytes(0xC641 if packet.check_bits == 16 else 0xD1)) \
            == (0xC641 if packet.check_bits == 16 else 0xD1)


@pytest.mark.parametrize("variants, modulus", [("", 255), ("crc8", 255), ("ack", 255),
                                               ("sync-byte", 96), ("7bit", 96),
                                               ("crc8,sync-byte", 96)])
def test_sequence_numbers_wrap_at_the_formats_modulus(variants, modulus):
    variants = V(variants)
    printer = UltimakerProtocol(queue_size=10_000, variants=variants)
    seqs = [event.number for n in range(2 * modulus + 3)
            for event in feed(printer, encode_command(n % modulus, "M105", variants.packet))]
    assert seqs == [n % modulus for n in range(2 * modulus + 3)]
    # and the host's core numbers its packets the same way
    assert variants.packet.next_seq(modulus - 1) == 0


# What the printer says, per variant: (variants, what happens, the bytes that come out).
def _answers(variants: str, action) -> bytes:
    printer = UltimakerProtocol(variants=V(variants))
    return action(printer)


def _accept(seq):
    def action(printer):
        printer.send(RoomChanged(15))
        printer.data_to_send()
        printer.expected_seq = seq
        feed(printer, encode_command(seq, "M105", printer.format))
        return printer.data_to_send()
    return action


def _done(response):
    def action(printer):
        printer.send(RoomChanged(15))
        feed(printer, encode_command(0, "M105", printer.format))
        printer.data_to_send()
        return printer.send(CommandDone(0, 15, response))
    return action


def _reject(printer):
    printer.send(RoomChanged(15))
    printer.data_to_send()
    feed(printer, encode_command(5, "M105", printer.format))
    return printer.data_to_send()


def _say(kind, text):
    return lambda printer: printer.send(OutOfBand(kind, text))


ANSWERS = [
    ("", "boot", lambda p: p.send(OutOfBand(OutOfBandKind.LOG, boot_line(p.variants))),
     b"LOG:Marlin started\n"),
    ("", "boot q", lambda p: p.send(RoomChanged(15)), b"\nq000F98\n"),
    ("", "accepted: nothing until executed", _accept(0), b""),
    ("ack", "accepted seq 0", _accept(0), b"\na000FAA\n"),
    ("ack", "accepted seq 5", _accept(5), b"\na050F6A\n"),
    ("ack,crc8,sync-byte", "accepted seq 5", _accept(5), b"\na050F6A\n"),
    ("", "executed, with data", _done(("T:21",)), b"T:21\n\no000FF8\n"),
    ("ack", "executed, with data", _done(("T:21",)), b"T:21\n\no000FF8\n"),
    ("", "seq 5 where 0 is due", _reject,
     b"\nProtoError:Sequence number is unexpected (received, expected): 5,0\n\nr000F3E\n"),
    ("compact-oob", "seq 5 where 0 is due", _reject,
     b"p:Sequence number is unexpected (received, expected): 5,0\n\nr000F3E\n"),
    ("ack", "boot", lambda p: p.send(OutOfBand(OutOfBandKind.LOG, boot_line(p.variants))),
     b"LOG:Marlin started; protocol variants: ack\n"),
    ("compact-oob", "boot", lambda p: p.send(OutOfBand(OutOfBandKind.LOG, boot_line(p.variants))),
     b"l:Marlin started; protocol variants: compact-oob\n"),
    ("7bit,crc8,ack", "boot", lambda p: p.send(OutOfBand(OutOfBandKind.LOG, boot_line(p.variants))),
     b"LOG:Marlin started; protocol variants: ack,crc8,7bit\n"),
    ("", "Error", _say(OutOfBandKind.ERROR, "Heater failed"), b"\nError:Heater failed\n"),
    ("compact-oob", "Error", _say(OutOfBandKind.ERROR, "Heater failed"), b"e:Heater failed\n"),
    ("compact-oob", "WARNING", _say(OutOfBandKind.WARNING, "hot"), b"w:hot\n"),
    ("compact-oob", "LOG", _say(OutOfBandKind.LOG, "echo:busy"), b"l:echo:busy\n"),
    ("compact-oob", "data like e:", _done(("e:not an error",)), b"d:e:not an error\n\no000FF8\n"),
    ("compact-oob", "data like d:, l:, p:, w:", _done(("d:x", "l:y", "p:", "w:z")),
     b"d:d:x\nd:l:y\nd:p:\nd:w:z\n\no000FF8\n"),
    ("compact-oob", "plain data", _done(("T:21", "ok e:1")), b"T:21\nok e:1\n\no000FF8\n"),
    ("compact-oob", "unsolicited data", lambda p: p.send(Output("e:3")), b"d:e:3\n"),
    ("", "data like e: is plain v3's to send as is", _done(("e:x",)), b"e:x\n\no000FF8\n"),
]


@pytest.mark.parametrize("variants, what, action, expected", ANSWERS,
                         ids=[f"{v or 'v3'}: {w}" for v, w, _, _ in ANSWERS])
def test_what_the_printer_says(variants, what, action, expected):
    assert _answers(variants, action) == expected


def test_the_frames_are_plain_v3s_frames_whose_crc8_covers_the_kind():
    assert frame("a", 5, 15) == b"\na050F6A\n"
    assert frame("o", 5, 0x10) == bytes.fromhex("0a6f3035313036380a")
    assert frame("r", 0, 15) == b"\nr000F3E\n"
    assert frame("q", 0, 15) == bytes.fromhex("0a713030304639380a")


# What the host reads, per variant: (variants, the line, the event).
READS = [
    ("", "a050F6A", Received(5, 15)),
    ("ack", "a050F6A", Received(5, 15)),
    ("ack", "a050F6B", host_um.CorruptFrame("a050F6B")),
    ("ack", "o000FF8", Ack(0, 15)),
    ("ack", "r000F3E", Reject(0, 15)),
    ("ack", "q000F98", RoomInfo(15)),
    ("compact-oob", "p:Checksum mismatch", Line(LineKind.PROTO_ERROR, "Checksum mismatch")),
    ("compact-oob", "e:Heater failed", Line(LineKind.ERROR, "Heater failed")),
    ("compact-oob", "w:hot", Line(LineKind.WARNING, "hot")),
    ("compact-oob", "l:echo:busy", Line(LineKind.LOG, "echo:busy")),
    ("compact-oob", "d:e:not an error", Line(LineKind.RESPONSE, "e:not an error")),
    ("compact-oob", "d:d:x", Line(LineKind.RESPONSE, "d:x")),
    ("compact-oob", "LOG:old form", Line(LineKind.LOG, "old form")),  # both forms
    ("compact-oob", "ProtoError:old", Line(LineKind.PROTO_ERROR, "old")),
    ("", "e:Heater failed", Line(LineKind.RESPONSE, "e:Heater failed")),  # v3: just data
    ("", "d:x", Line(LineKind.RESPONSE, "d:x")),
    ("", "l:Marlin started; protocol variants: compact-oob",
     Line(LineKind.LOG, "Marlin started; protocol variants: compact-oob")),
    ("crc8", "l:Marlin started; protocol variants: compact-oob",
     Line(LineKind.LOG, "Marlin started; protocol variants: compact-oob")),
    ("", "l:echo:busy", Line(LineKind.RESPONSE, "l:echo:busy")),
]


@pytest.mark.parametrize("variants, line, event", READS)
def test_what_the_host_reads(variants, line, event):
    assert parse_all(V(variants), line.encode() + b"\n") == [event]


@pytest.mark.parametrize("text, variants", [
    ("Marlin started", PLAIN),
    ("Marlin started; protocol variants: ack", V("ack")),
    ("Marlin started; protocol variants: ack,compact-oob,crc8,sync-byte,7bit", ALL_SETS[31]),
    ("Marlin started; protocol variants: acx", None),  # damaged on the way: says nothing
    ("Marlin restarted", None),
    ("echo:busy", None),
])
def test_the_boot_line_names_the_variants(text, variants):
    assert announced(text) == variants


def test_every_variant_set_announces_itself_readably_to_every_host():
    for printer_side in ALL_SETS:
        said = UltimakerProtocol(variants=printer_side).send(
            OutOfBand(OutOfBandKind.LOG, boot_line(printer_side)))
        for host_side in ALL_SETS:
            (line,) = parse_all(host_side, said)
            assert line.kind is LineKind.LOG and announced(line.text) == printer_side


@pytest.mark.parametrize("text, message", [
    ("fast", "unknown protocol variant 'fast'"),
    ("ack,ACK", "unknown protocol variant 'ACK'"),
    ("ack,v3", "unknown protocol variant 'v3'"),
])
def test_a_variant_list_that_names_no_variant_is_refused(text, message):
    with pytest.raises(VariantError, match=re.escape(message)):
        parse_variants(text)


def test_variant_lists_in_any_order_and_spelling_are_the_same_set():
    assert V("crc8, ack") == V("ack,crc8") == lab.variants_of(["crc8", "ack"])
    assert V("") == V(None) == V("v3") == V(" , ") == PLAIN
    assert [str(v) for v in (PLAIN, V("7bit,ack"))] == ["v3", "ack,7bit"]


# -- hypothesis: the codecs ---------------------------------------------------------------------
variant_sets = st.sampled_from(ALL_SETS)
payloads = st.binary(min_size=1, max_size=96).map(lambda b: bytes(0x20 + x % 95 for x in b))


def chunked(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({cut % (len(data) + 1) for cut in cuts})
    return [data[a:b] for a, b in zip([0, *points], [*points, len(data)])]


@settings(max_examples=300, suppress_health_check=[HealthCheck.too_slow])
@given(variants=variant_sets, seq=st.integers(0, 254),
       packets=st.lists(payloads, min_size=1, max_size=6), cuts=st.lists(st.integers(0, 800)))
def test_any_packets_reach_the_printer_as_sent_however_the_reads_cut_them(variants, seq, packets,
                                                                         cuts):
    form = variants.packet
    seq %= form.sequence_modulus
    encoded = [encode_command(form.next_seq(seq, n), payload.decode(), form)
               for n, payload in enumerate(packets)]
    for packet in encoded:  # armored: characters only, and SYN only at the start
        body = packet[form.starts:]
        assert not form.armored or (max(body) < 0x80 and lab.SYN not in body), packet
    wire = b"".join(encoded)
    printer = UltimakerProtocol(queue_size=10, variants=variants)
    printer.expected_seq = seq
    events = []
    for piece in chunked(wire, cuts):
        events += feed(printer, piece)
    assert events == [CommandReceived(p.decode(), form.next_seq(seq, n))
                      for n, p in enumerate(packets)]
    # ack: one `a` for each, in order, before anything else; without: nothing yet
    said = parse_all(variants, printer.data_to_send())
    rooms = 15
    assert said == ([Received(form.next_seq(seq, n), rooms) for n in range(len(packets))]
                    if variants.ack else [])


@settings(max_examples=300)
@example(variants=V("compact-oob"), text="e:not an error")
@example(variants=V("ack,compact-oob"), text="d:")
@example(variants=V("compact-oob,crc8"), text="l:Marlin started; protocol variants: ack")
@example(variants=PLAIN, text="w:hot")
@given(variants=variant_sets, text=st.text(st.characters(min_codepoint=0x20, max_codepoint=0x7E),
                                           min_size=1, max_size=60))
def test_any_response_line_reads_back_as_data_under_every_variant(variants, text):
    # What plain v3 itself would read as data (not a frame, not a LOG:/Error: line): the same
    # text comes back as data with every variant, escaped where compact-oob needs it.
    if host_um.parse_line(text) != Line(LineKind.RESPONSE, text):
        return
    printer = UltimakerProtocol(variants=variants)
    feed(printer, encode_command(0, "M105", variants.packet))
    printer.data_to_send()
    said = parse_all(variants, printer.send(CommandDone(0, 15, (text,))))
    assert said == [Line(LineKind.RESPONSE, text), Ack(0, 15)]


@settings(max_examples=200)
@given(variants=variant_sets, kind=st.sampled_from(list(OutOfBandKind)),
       text=st.text(st.characters(min_codepoint=0x21, max_codepoint=0x7E), min_size=1,
                    max_size=40))
def test_any_out_of_band_line_reads_back_as_its_kind(variants, kind, text):
    said = parse_all(variants, UltimakerProtocol(variants=variants).send(OutOfBand(kind, text)))
    expected = {OutOfBandKind.LOG: LineKind.LOG, OutOfBandKind.ERROR: LineKind.ERROR,
                OutOfBandKind.WARNING: LineKind.WARNING}[kind]
    assert said == [Line(expected, text)]


# -- damaged packets ----------------------------------------------------------------------------
FORMAT_SETS = ["", "ack", "compact-oob", "crc8", "sync-byte", "7bit", "crc8,sync-byte",
               "ack,compact-oob,crc8,7bit"]


def damaged(variants: Variants, how: str) -> tuple[bytes, RejectReason, str]:
    form = variants.packet
    good = bytearray(encode_command(0, "G28", form))
    seq_at, len_at = form.starts, form.starts + 1
    if how == "seq":
        return (encode_command(3, "G28", form), RejectReason.UNEXPECTED_SEQUENCE,
                "Sequence number is unexpected (received, expected): 3,0")
    if how == "seq not a character":  # armored: a seq byte below 0x20
        good[seq_at] = 0x05
        return (bytes(good), RejectReason.UNEXPECTED_SEQUENCE,
                "Sequence number is unexpected (received, expected): 5,0")
    too_big = "Payload size is too big for packet with sequence number: 0"
    if how == "len 0":
        good[len_at] = form.len_byte(0)
        return bytes(good), RejectReason.BAD_LENGTH, too_big
    if how == "len 97":
        return (bytes(good[:len_at]) + bytes((form.len_byte(97),)) + b"x" * 97 + b"@@@",
                RejectReason.BAD_LENGTH, too_big)
    if how == "byte":
        good[len_at + 1 + 2] = 0x7F
        return (bytes(good), RejectReason.ILLEGAL_BYTE,
                "Payload byte not in acceptable (ASCII) range at position #2")
    mismatch = "Checksum mismatch for packet with sequence number: 0"
    if how == "check":
        good[-1] ^= 0x01
        return bytes(good), RejectReason.CHECKSUM_MISMATCH, mismatch
    if how == "check digit":  # armored: a digit outside 40..7f
        good[-form.check_chars] = 0x3F
        return bytes(good), RejectReason.CHECKSUM_MISMATCH, mismatch
    if how == "check over the wrong seq":  # the right check for seq 1, sent as seq 0
        other = encode_command(1, "G28", form)
        return (bytes(good[:-form.check_chars]) + other[-form.check_chars:],
                RejectReason.CHECKSUM_MISMATCH, mismatch)
    raise AssertionError(how)


HOW = ["seq", "len 0", "len 97", "byte", "check", "check over the wrong seq"]
ARMORED_HOW = ["seq not a character", "check digit"]


# Only sync-byte and 7bit carry their fields as characters, which can be no character.
DAMAGE = [(variants, how) for variants in FORMAT_SETS for how in HOW + ARMORED_HOW
          if how in HOW or V(variants).packet.armored]


@pytest.mark.parametrize("variants, how", DAMAGE)
def test_a_damaged_packet_is_refused_with_its_reason_then_r(variants, how):
    variants = V(variants)
    packet, reason, message = damaged(variants, how)
    printer = UltimakerProtocol(variants=variants)
    printer.send(RoomChanged(12))
    assert feed(printer, packet) == [PacketRejected(reason, message, 0)]
    prefix = b"p:" if variants.compact_oob else b"\nProtoError:"
    assert printer.data_to_send() == prefix + message.encode() + b"\n" + frame("r", 0, 12)
    # and nothing was lost of the receiver: the packet sent again is read
    assert feed(printer, encode_command(0, "G28", variants.packet)) == [CommandReceived("G28", 0)]


@pytest.mark.parametrize("variants", FORMAT_SETS)
def test_a_full_queue_refuses_until_a_command_is_done(variants):
    variants = V(variants)
    form = variants.packet
    printer = UltimakerProtocol(queue_size=2, variants=variants)
    events = [e for n in range(3) for e in feed(printer, encode_command(n, f"G1 X{n}", form))]
    assert events[:2] == [CommandReceived("G1 X0", 0), CommandReceived("G1 X1", 1)]
    assert events[2] == PacketRejected(
        RejectReason.QUEUE_FULL,
        "Received packet could not be handled (buffer full), packet with sequence number: 2", 2)
    said = parse_all(variants, printer.data_to_send())
    assert said[-2:] == [
        Line(LineKind.PROTO_ERROR, "Received packet could not be handled (buffer full), packet "
             "with sequence number: 2"), Reject(2, 15)]
    assert said[:-2] == ([Received(0, 15), Received(1, 15)] if variants.ack else [])
    printer.send(CommandDone(0, room=15))
    assert feed(printer, encode_command(2, "G1 X2", form)) == [CommandReceived("G1 X2", 2)]


# -- resync ----------------------------------------------------------------------------------
ARMORED_SETS = ["sync-byte", "7bit", "crc8,sync-byte", "crc8,7bit", "ack,compact-oob,sync-byte"]


@pytest.mark.parametrize("variants", ARMORED_SETS)
def test_a_packet_cut_anywhere_costs_only_itself_where_the_start_byte_is_in_no_packet(variants):
    variants = V(variants)
    form = variants.packet
    cut_from = encode_command(0, "G1 X100 Y200 F3000", form)
    following = encode_command(0, "M105", form)
    for at in range(1, len(cut_from)):
        printer = UltimakerProtocol(variants=variants)
        assert feed(printer, cut_from[:at] + following) == [CommandReceived("M105", 0)], at
        assert printer.data_to_send() == (b"\na000FAA\n" if variants.ack else b""), at


@pytest.mark.parametrize("variants", ["crc8", "ack,crc8"])
def test_crc8_restarts_on_ff_in_its_length_and_payload_not_in_its_check(variants):
    variants = V(variants)
    form = variants.packet
    cut_from = encode_command(0, "G1 X100 Y200 F3000", form)
    following = encode_command(0, "M105", form)
    for at in range(1, len(cut_from) - form.check_chars):
        printer = UltimakerProtocol(variants=variants)
        assert feed(printer, cut_from[:at] + following) == [CommandReceived("M105", 0)], at
    # 0xFF may be a check byte: a packet whose check is ff is read whole
    seq, payload = next((s, p) for s in range(255) for p in (f"G1 X{n}" for n in range(300))
                        if encode_command(s, p, form)[-1] == 0xFF)
    printer = UltimakerProtocol(variants=variants)
    printer.expected_seq = seq
    assert feed(printer, encode_command(seq, payload, form)) == [CommandReceived(payload, seq)]


@pytest.mark.parametrize("variants", FORMAT_SETS)
@pytest.mark.parametrize("run", [1, 2, 3, 7])
def test_a_run_of_start_bytes_syncs(variants, run):
    variants = V(variants)
    form = variants.packet
    printer = UltimakerProtocol(variants=variants)
    noise = bytes((form.start,)) * run
    assert feed(printer, noise + encode_command(0, "M105", form)) == [CommandReceived("M105", 0)]


@pytest.mark.parametrize("variants", ARMORED_SETS)
def test_text_between_armored_packets_is_ignored(variants):
    form = V(variants).packet
    printer = UltimakerProtocol(variants=V(variants))
    wire = (b"M105\r\n\xff\xff\x00" + encode_command(0, "G28", form) + b"N1 M110*1\n"
            + encode_command(1, "M105", form))
    assert feed(printer, wire) == [CommandReceived("G28", 0), CommandReceived("M105", 1)]


@settings(max_examples=200)
@given(variants=st.sampled_from([V(s) for s in ARMORED_SETS]), payload=payloads,
       at=st.integers(1, 200), garbage=st.binary(max_size=30))
def test_whatever_comes_before_a_syn_an_armored_packet_after_it_is_read(variants, payload, at,
                                                                        garbage):
    # a cut packet, then noise without SYN, then a whole packet: only the cut one is lost, or
    # the printer refused the noise (and then the packet sent again is read)
    form = variants.packet
    noise = garbage.replace(bytes((lab.SYN,)), b"")
    printer = UltimakerProtocol(variants=variants)
    cut_from = encode_command(0, "G1 X1 Y2", form)
    cut = cut_from[:1 + at % (len(cut_from) - 1)]  # 1 byte to all but the last
    whole = encode_command(0, payload.decode(), form)
    received = feed(printer, cut + noise + whole)
    if not any(isinstance(e, PacketRejected) for e in received):
        assert received == [CommandReceived(payload.decode(), 0)]
    else:
        assert feed(printer, whole) == [CommandReceived(payload.decode(), 0)]


# -- plain v3, byte for byte --------------------------------------------------------------------
def test_the_documented_v3_vectors_come_out_with_variants_plain():
    # docs/protocols.md section 1, "Vectors"
    assert PLAIN.packet.is_v3 and PLAIN.packet == lab.V3_PACKET
    assert encode_command(0, "G28", PLAIN.packet).hex() == "ffff0003473238c641"
    assert encode_command(1, "M105", PLAIN.packet).hex() == "ffff01044d313035045a"
    assert encode_command(0, "G28") == v3.encode_packet(0, b"G28")
    printer = UltimakerProtocol(variants=PLAIN)
    assert printer.send(RoomChanged(15)).hex() == "0a713030304639380a"
    feed(printer, encode_command(0, "G28", PLAIN.packet))
    assert printer.send(CommandDone(0, 15)).hex() == "0a6f3030304646380a"
    assert f"\n{v3.frame_body('o', 5, 0x10)}\n".encode().hex() == "0a6f3035313036380a"


class Recording:
    """A host's stream that keeps every byte each way, with when it crossed."""

    def __init__(self, inner) -> None:
        self.inner = inner
        self.sent: list[tuple[float, bytes]] = []
        self.received = bytearray()

    async def send_all(self, data: bytes) -> None:
        self.sent.append((trio.current_time(), data))
        await self.inner.send_all(data)

    async def receive_some(self, max_bytes: int = 4096) -> bytes:
        data = await self.inner.receive_some(max_bytes)
        self.received += data
        return data


COMPACT_LINE = re.compile(rb"^(p|e|w|l|d):", re.MULTILINE)
ACK_FRAME = re.compile(rb"^a[0-9A-F]{6}$", re.MULTILINE)


async def test_a_plain_printer_and_host_never_say_a_variants_word(autojump_clock):
    # bit errors to the printer: ProtoErrors and `r`s too, all in v3's own words
    noisy = [{"kind": "bit-errors", "direction": "to-printer", "rate": 3e-4},
             {"kind": "firmware-error", "text": "Injected", "nth": 5}]
    async with memory_printer(protocol="ultimaker", faults=noisy, seed=4) as printer:
        stream = Recording(printer.open())
        async with connect(stream, options=ClientOptions(max_transmissions=50)) as host:
            summary = await host.print_commands(JOB)
        assert printer.journal == JOB
    said = bytes(stream.received)
    assert summary.rejects > 0 and b"\nProtoError:" in said and b"\nError:Injected\n" in said
    assert said.startswith(b"LOG:Marlin started\n")
    assert not ACK_FRAME.search(said) and not COMPACT_LINE.search(said)
    assert b"variants" not in said
    sent = b"".join(data for _, data in stream.sent)
    assert sent.startswith(encode_command(0, "G28")) and lab.SYN not in sent[:2]


# -- the 7-bit line ---------------------------------------------------------------------------
async def read_until(stream, marker: bytes, got: bytearray) -> bytearray:
    while marker not in got:
        got += await stream.receive_some(4096)
    return got


@pytest.mark.parametrize("variants, journal", [("7bit", ["G28"]), ("crc8,7bit", ["G28"]),
                                               ("sync-byte", [])])
async def test_a_7_bit_uart_clears_the_top_bit_of_every_byte(autojump_clock, variants, journal):
    # The same packet with every top bit set: a 7-bit printer reads the packet; an 8-bit one
    # reads bytes no packet has (no SYN, even), and ignores them.
    form = V(variants).packet
    async with memory_printer(protocol="ultimaker", variants=variants) as printer:
        stream = printer.open()
        await read_until(stream, b"\nq000F98\n", bytearray())
        await stream.send_all(bytes(byte | 0x80 for byte in encode_command(0, "G28", form)))
        got = bytearray()
        with trio.move_on_after(30):
            await read_until(stream, b"\no000", got)
        assert printer.journal == journal
        assert (b"\no000FF8\n" in got) == bool(journal)


@pytest.mark.parametrize("variants, bits", [("7bit", 9), ("sync-byte", 10), ("crc8,7bit", 9)])
async def test_the_line_is_paced_at_bits_per_byte(autojump_clock, variants, bits):
    baud = 9600
    form = V(variants).packet
    async with memory_printer(protocol="ultimaker", variants=variants, baud=baud) as printer:
        stream = printer.open()
        await read_until(stream, b"\nq000F98\n", bytearray())
        packet = encode_command(0, "M105", form)
        start = trio.current_time()
        await stream.send_all(packet)
        got = await read_until(stream, b"\no000FF8\n", bytearray())
        took = trio.current_time() - start
    assert got.startswith(b"T:") and got.endswith(b"\no000FF8\n")
    assert took == pytest.approx((len(packet) + len(got)) * bits / baud, rel=1e-6)


@pytest.mark.parametrize("variants, flipped", [("7bit", {1 << b for b in range(7)}),
                                               ("sync-byte", {1 << b for b in range(8)})])
def test_bit_errors_on_a_7_bit_line_flip_one_of_its_7_bits(variants, flipped):
    layer = FaultLayer(FaultConfig(to_printer=LineFaults(bit_error_rate=1.0)))
    layer.set_protocol("ultimaker", V(variants))
    data = bytes(range(0x20, 0x80)) * 10
    out = b"".join(segment.data for segment in layer.to_printer(data))
    assert {a ^ b for a, b in zip(data, out)} == flipped


# -- the host's core on a printer in memory ---------------------------------------------------
def resend_delays(stream: Recording, payload: bytes) -> list[float]:
    """How long after its first transmission each copy of the packet carrying `payload` went."""
    times = [when for when, data in stream.sent if payload in data]
    return [when - times[0] for when in times[1:]]


async def print_recorded(job: list[str], variants: str = "", faults=()):
    """Our host prints `job` to a memory printer at 250000 baud, every command run once: its
    summary, and the stream that saw what it sent."""
    async with memory_printer(protocol="ultimaker", variants=variants, faults=faults,
                              baud=250000) as printer:
        stream = Recording(printer.open())
        async with connect(stream, options=ClientOptions(variants=variants)) as host:
            summary = await host.print_commands(job)
        assert printer.journal == job
    return summary, stream


BUSY_JOB = ["M105", "G4 S30", "M114"]  # the last packet lost while the printer dwells
LOSE_THIRD = [{"kind": "drop", "direction": "to-printer", "nth": 3}]


@pytest.mark.parametrize("variants", ["ack", "ack,crc8", "ack,compact-oob,sync-byte",
                                      "ack,crc8,7bit"])
async def test_with_ack_a_lost_packet_is_resent_at_once_though_the_printer_is_busy(
        autojump_clock, variants):
    summary, stream = await print_recorded(BUSY_JOB, variants, LOSE_THIRD)
    (delay,) = resend_delays(stream, b"M114")
    assert delay < 0.1  # a round trip or two, not the 2 s timeout: G4 dwells for 30 s
    assert (summary.resends, summary.timeouts) == (1, 1)
    assert 30 <= summary.elapsed < 31


async def test_without_ack_the_same_loss_waits_for_the_timeout_after_the_printer_is_done(
        autojump_clock):
    summary, stream = await print_recorded(BUSY_JOB, faults=LOSE_THIRD)
    (delay,) = resend_delays(stream, b"M114")
    assert 32 <= delay < 32.1  # G4's 30 s, then 2 s of silence
    assert (summary.resends, summary.timeouts) == (1, 1)


@pytest.mark.parametrize("variants", ["", "ack", "crc8,sync-byte"])
async def test_a_lost_packet_with_one_behind_it_is_resent_for_the_r_that_one_draws(
        autojump_clock, variants):
    lose_second = [{"kind": "drop", "direction": "to-printer", "nth": 2}]
    job = ["M105", "M114", "M115"]
    summary, stream = await print_recorded(job, variants, lose_second)
    (delay,) = resend_delays(stream, b"M114")
    assert delay < 0.1 and summary.rejects >= 1


@pytest.mark.parametrize("variants", ["ack", "compact-oob", "crc8", "sync-byte", "7bit",
                                      "ack,compact-oob,crc8,sync-byte,7bit"])
async def test_each_variant_prints_a_noisy_job_exactly_once(autojump_clock, variants):
    noisy = [{"kind": "bit-errors", "direction": "to-printer", "rate": 2e-4},
             {"kind": "bit-errors", "direction": "to-host", "rate": 1e-4},
             {"kind": "drop", "direction": "to-printer", "probability": 0.02}]
    async with memory_printer(protocol="ultimaker", variants=variants, faults=noisy,
                              seed=7) as printer:
        async with connect(printer.open(), options=ClientOptions(
                variants=variants, max_transmissions=50)) as host:
            summary = await host.print_commands(JOB)
        assert printer.journal == JOB
    assert summary.resends > 0


MISMATCHES = [
    ("", "ack", "(plain v3): it speaks variants ack;"),
    ("ack", "", "(variants ack): it speaks plain v3;"),
    ("crc8", "compact-oob", "(variants crc8): it speaks variants compact-oob;"),
    ("", "compact-oob", "(plain v3): it speaks variants compact-oob;"),
    ("compact-oob", "", "(variants compact-oob): it speaks plain v3;"),
    ("", "crc8", "(plain v3): it speaks variants crc8;"),
    ("sync-byte", "7bit", "(variants sync-byte): it speaks variants 7bit;"),
    ("7bit", "sync-byte", "(variants 7bit): it speaks variants sync-byte;"),
    ("ack,crc8", "ack", "(variants ack,crc8): it speaks variants ack;"),
    ("ack", "ack,compact-oob", "(variants ack): it speaks variants ack,compact-oob;"),
    ("compact-oob,crc8", "ack,crc8", "(variants compact-oob,crc8): it speaks variants ack,crc8;"),
]


@pytest.mark.parametrize("host_side, printer_side, names", MISMATCHES)
async def test_a_host_and_printer_with_other_variants_stop_before_anything_runs(
        autojump_clock, host_side, printer_side, names):
    async with memory_printer(protocol="ultimaker", variants=printer_side) as printer:
        with pytest.raises(VariantMismatch) as stopped:
            async with connect(printer.open(),
                               options=ClientOptions(variants=host_side)) as host:
                await host.print_commands(JOB)
        assert printer.journal == []
    assert str(stopped.value) == (f"the printer does not speak this host's protocol {names} give "
                                  "both sides the same --variant")


LOSE_BOOT_LINE = [{"kind": "drop", "direction": "to-host", "pattern": "Marlin started"}]


async def test_with_the_boot_line_lost_the_first_a_frame_gives_an_ack_printer_away(
        autojump_clock):
    async with memory_printer(protocol="ultimaker", variants="ack",
                              faults=LOSE_BOOT_LINE) as printer:
        with pytest.raises(VariantMismatch, match=r"\(plain v3\): it acknowledges receipt with "
                           r"`a` frames \(variant ack\)"):
            async with connect(printer.open()) as host:
                await host.print_commands(JOB)
        assert printer.journal == JOB[:len(printer.journal)] and len(printer.journal) <= 3


async def test_with_the_boot_line_lost_an_ack_host_knows_a_plain_printer_by_ten_o_frames(
        autojump_clock):
    async with memory_printer(protocol="ultimaker", faults=LOSE_BOOT_LINE) as printer:
        with pytest.raises(VariantMismatch, match=r"\(variants ack\): it executes packets but "
                           r"never says it received one \(no `a` frames\)"):
            async with connect(printer.open(), options=ClientOptions(variants="ack")) as host:
                await host.print_commands(JOB)
        assert printer.journal == JOB[:len(printer.journal)]
        assert 10 <= len(printer.journal) <= 13  # ten `o`s, and the window behind the tenth


async def test_a_printer_that_announced_ack_is_not_said_to_lack_it_when_a_frames_are_lost(
        autojump_clock):
    lose_ten_a_frames = [{"kind": "drop", "direction": "to-host", "pattern": "^a", "times": 10}]
    async with memory_printer(protocol="ultimaker", variants="ack",
                              faults=lose_ten_a_frames) as printer:
        lines = []
        async with connect(printer.open(), options=ClientOptions(variants="ack"),
                           on_line=lines.append) as host:
            summary = await host.print_commands(JOB)
        assert lines[0] == Line(LineKind.LOG, "Marlin started; protocol variants: ack")
        assert printer.journal == JOB and summary.commands == len(JOB)


@pytest.mark.parametrize("variants", ["ack", "compact-oob", "crc8,7bit"])
async def test_a_boot_line_once_synchronised_is_a_reset(autojump_clock, variants):
    async with memory_printer(protocol="ultimaker", variants=variants) as printer:
        with pytest.raises(PrinterReset, match="started again"):
            async with connect(printer.open(), options=ClientOptions(variants=variants)) as host:
                await host.print_commands(JOB[:10])
                printer.open()  # someone else opened the port: the printer boots again
                await host.print_commands(JOB[10:])
        assert printer.journal[:10] == JOB[:10]


async def test_a_variant_host_option_that_names_no_variant_is_a_usage_error(autojump_clock):
    from fake_marlin.host import UsageError

    async with memory_printer(protocol="ultimaker") as printer:
        with pytest.raises(UsageError, match="unknown protocol variant 'fast'"):
            async with connect(printer.open(), options=ClientOptions(variants="fast")):
                pass
        with pytest.raises(UsageError, match="are Ultimaker's; marlin has none"):
            async with connect(printer.open(), "marlin", ClientOptions(variants="ack")):
                pass
    with pytest.raises(ValueError, match="are Ultimaker's: they need protocol ultimaker"):
        async with memory_printer(protocol="marlin", variants="ack"):
            pass


# -- the command lines ---------------------------------------------------------------------------
CLI_ERRORS = {
    "no protocol": (["fake-marlin", "--variant", "ack"],
                    "fake-marlin: error: argument --variant: the variants (ack) are Ultimaker's "
                    "protocol's: give --protocol ultimaker (auto never guesses a variant)"),
    "protocol marlin": (["fake-marlin", "--protocol", "marlin", "--variant", "crc8"],
                        "fake-marlin: error: argument --variant: the variants (crc8) are "
                        "Ultimaker's protocol's: give --protocol ultimaker (auto never guesses "
                        "a variant)"),
    "unknown name": (["fake-marlin", "--protocol", "ultimaker", "--variant", "ack,fast"],
                     "fake-marlin: error: argument --variant: unknown protocol variant 'fast'; "
                     "choose from ack, compact-oob, crc8, sync-byte, 7bit (comma-separated)"),
    "host marlin": (["fake-marlin-host", "print", "--protocol", "marlin", "--variant", "ack",
                     "/nonexistent/port", "/nonexistent/job.gcode"],
                    "fake-marlin-host: error: --variant ack: the variants are Ultimaker's; give "
                    "--protocol ultimaker"),
    "host unknown name": (["fake-marlin-host", "send", "--variant", "fast", "/nonexistent/port",
                           "M105"],
                          "fake-marlin-host send: error: argument --variant: unknown protocol "
                          "variant 'fast'; choose from ack, compact-oob, crc8, sync-byte, 7bit "
                          "(comma-separated)"),
    "fuzz marlin": (["fake-marlin", "scenario", "fuzz", "--protocol", "marlin", "--variant",
                     "ack", "--runs", "1", "--seed", "1", "--out", "{tmp}/out"],
                    "fake-marlin scenario fuzz: error: --variant: the protocol lab's variants "
                    "are Ultimaker's; give --protocol ultimaker"),
    "fuzz unknown name": (["fake-marlin", "scenario", "fuzz", "--protocol", "ultimaker",
                           "--variant", "each", "--variant", "fast", "--runs", "1", "--seed",
                           "1", "--out", "{tmp}/out"],
                          "fake-marlin scenario fuzz: error: --variant: unknown protocol variant "
                          "'fast'; choose from ack, compact-oob, crc8, sync-byte, 7bit "
                          "(comma-separated)"),
}


@pytest.fixture(scope="module")
def cli_errors(tmp_path_factory) -> dict[str, subprocess.CompletedProcess]:
    """Every refused command line, run at once (each is a fresh interpreter)."""
    tmp = tmp_path_factory.mktemp("cli")
    running = {
        name: subprocess.Popen([str(BIN / argv[0]), *(a.format(tmp=tmp) for a in argv[1:])],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env={"PATH": "/usr/bin:/bin", "COLUMNS": "80"})
        for name, (argv, _) in CLI_ERRORS.items()
    }
    results = {}
    for name, process in running.items():
        out, err = process.communicate(timeout=60)
        results[name] = subprocess.CompletedProcess(process.args, process.returncode, out, err)
    return results


@pytest.mark.parametrize("name", CLI_ERRORS)
def test_a_refused_variant_on_the_command_line_is_one_line_and_exit_2(cli_errors, name):
    result = cli_errors[name]
    assert result.returncode == 2 and result.stdout == ""
    assert "Traceback" not in result.stderr
    lines = result.stderr.splitlines()
    assert lines[0].startswith("usage: ")
    assert [line for line in lines if "error:" in line] == [lines[-1]]
    assert lines[-1] == CLI_ERRORS[name][1]


# -- scenario files -----------------------------------------------------------------------------
@pytest.mark.parametrize("text, printer_side, host_side", [
    ('[printer]\nprotocol = "ultimaker"\nvariants = ["ack", "crc8"]\n', "ack,crc8", "ack,crc8"),
    ('[printer]\nprotocol = "ultimaker"\nvariants = "crc8, ack"\n', "ack,crc8", "ack,crc8"),
    ('[printer]\nprotocol = "ultimaker"\nvariants = "ack"\n[host]\nvariants = []\n', "ack", ""),
    ('[printer]\nprotocol = "ultimaker"\n[host]\nvariants = "7bit"\n', "", "7bit"),
    ('[printer]\nprotocol = "ultimaker"\nvariants = "v3"\n', "", ""),
    ('[printer]\nprotocol = "marlin"\nvariants = []\n', "", ""),
])
def test_scenario_files_name_variants_as_a_list_or_a_string(tmp_path, text, printer_side,
                                                             host_side):
    path = tmp_path / "lab.toml"
    path.write_text(text)
    scenario = load(path)
    assert scenario.printer.variants == V(printer_side)
    assert scenario.host_variants == V(host_side)
    assert scenario.printer.server_config(scenario.faults).variants == V(printer_side)


@pytest.mark.parametrize("text, message", [
    ('[printer]\nprotocol = "ultimaker"\nvariants = ["ack", "fast"]\n',
     "[printer] variants: unknown protocol variant 'fast'"),
    ('[printer]\nprotocol = "ultimaker"\n[host]\nvariants = "fast"\n',
     "[host] variants: unknown protocol variant 'fast'"),
    ('[printer]\nvariants = ["ack"]\n[host]\nprotocol = "ultimaker"\n',
     "[printer] variants: are Ultimaker's: give protocol = \"ultimaker\""),
    ('[printer]\nprotocol = "marlin"\nvariants = "ack"\n',
     "[printer] variants: are Ultimaker's: give protocol = \"ultimaker\""),
    ('[printer]\nprotocol = "marlin"\n[host]\nvariants = "ack"\n',
     "[host] variants: are Ultimaker's: the host must speak ultimaker"),
    ('[printer]\nprotocol = "ultimaker"\nvariants = [1]\n',
     "[printer] variants: must be a list of variant names, or one string of them"),
    ('[printer]\nprotocol = "ultimaker"\nvariants = 3\n',
     "[printer] variants: must be a string or a list, not 3"),
])
def test_a_bad_variants_key_names_the_file_and_the_key(tmp_path, text, message):
    path = tmp_path / "lab.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as refused:
        load(path)
    assert str(refused.value).startswith(f"{path}: {message}")


def test_a_scenario_of_mismatched_sides_fails_with_variant_mismatch_and_runs_nothing(tmp_path):
    path = tmp_path / "mismatch.toml"
    path.write_text('[printer]\nprotocol = "ultimaker"\nvariants = ["ack", "crc8"]\n'
                    '[host]\nvariants = "crc8"\n[job]\nmoves = 20\n'
                    '[expect]\noutcome = "failed"\nerror = "VariantMismatch"\n')
    result = run_scenario(load(path))
    assert result.passed and result.outcome == "failed" and result.journal == []
    assert "VariantMismatch" in result.error and "(variants crc8)" in result.error


# -- fuzz campaigns -----------------------------------------------------------------------------
@pytest.mark.parametrize("variants", ["ack", "ack,crc8", "compact-oob,sync-byte,7bit"])
def test_a_variant_case_has_the_faults_of_the_plain_case_of_its_seed_and_number(tmp_path,
                                                                                 variants):
    variant_set = V(variants)
    for number in range(1, 9):
        plain = fuzz.generate("ultimaker", 1, number)
        lab_case = fuzz.generate("ultimaker", 1, number, variants=variant_set)
        assert lab_case["name"] == f"ultimaker-{variants.replace(',', '+')}-1-{number}"
        assert f"--variant {variants} --seed 1:" in lab_case["description"]
        assert lab_case["printer"] == {**plain["printer"], "variants": list(variant_set.names)}
        for key in ("seed", "fault", "job", "host", "expect"):
            assert lab_case.get(key) == plain.get(key), key
        path = tmp_path / f"{lab_case['name']}.toml"
        path.write_text(fuzz.scenario_text(lab_case), encoding="utf-8")
        scenario = load(path)
        assert scenario.printer.variants == scenario.host_variants == variant_set
    assert [case.name for case in campaign.cases("ultimaker", 1, 7, variants=variant_set)][-1] \
        == f"ultimaker-{variants.replace(',', '+')}-1-7"
    with pytest.raises(ValueError, match="Ultimaker's"):
        fuzz.generate("marlin", 1, 1, variants=variant_set)


def test_a_variant_fuzz_case_runs_and_passes():
    case = campaign.cases("ultimaker", 3, 1, moves=30, variants=V("ack,crc8,sync-byte"))[0]
    result = campaign.run_case(case.name, case.text)
    assert result.passed, result.reason


def test_every_variant_name_is_one_of_the_five():
    assert NAMES == ("ack", "compact-oob", "crc8", "sync-byte", "7bit")
    assert len(set(ALL_SETS)) == 32 and ALL_SETS[0] == PLAIN
    assert [ALL_SETS[1 << bit].names for bit in range(5)] == [(name,) for name in NAMES]
