"""Marlin's line protocol, against GCodeQueue::get_serial_commands() and docs/protocols.md
section 6."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fake_marlin.emulator.protocols.marlin import (
    MAX_CMD_SIZE,
    EmergencyCommand,
    LineError,
    LineRejected,
    MarlinProtocol,
    xor_checksum,
)
from fake_marlin.emulator.protocols.base import CommandDone, CommandReceived, Output


def feed(protocol: MarlinProtocol, data: bytes, release: bool = True) -> list:
    """Feed bytes; with `release`, each command is acknowledged as the session would."""
    protocol.receive_data(data)
    events = []
    while (event := protocol.next_event()) is not None:
        events.append(event)
        if release and isinstance(event, CommandReceived):
            protocol.send(CommandDone())
    return events


def numbered(n: int, command: str, space: str = " ") -> bytes:
    body = f"N{n}{space}{command}"
    return f"{body}*{xor_checksum(body)}\n".encode()


@pytest.mark.parametrize(
    "wire, text, number",
    [
        (b"N0 M110 N0*125\n", "M110 N0", 0),
        (b"N1 G28*18\n", "G28", 1),
        (b"N2 M105*37\n", "M105", 2),
    ],
)
def test_reference_vectors_in_sequence(wire, text, number):
    protocol = MarlinProtocol()
    protocol.last_n = number - 1
    assert feed(protocol, wire) == [CommandReceived(text, number)]


def test_curas_form_without_a_space_after_the_number():
    protocol = MarlinProtocol()
    assert feed(protocol, b"N1G28*50\n") == [CommandReceived("G28", 1)]


@pytest.mark.parametrize(
    "wire, error, words",
    [
        (numbered(5, "G28"), LineError.LINE_NUMBER, "Line Number is not Last Line Number+1"),
        (b"N1 G28*19\n", LineError.CHECKSUM, "checksum mismatch"),
        (b"N1 G28\n", LineError.NO_CHECKSUM, "No Checksum with line number"),
    ],
)
def test_line_errors_say_error_resend_and_ok_in_one_write(wire, error, words):
    protocol = MarlinProtocol()
    assert feed(protocol, wire) == [LineRejected(error, 1)]
    assert protocol.data_to_send() == f"Error:{words}, Last Line: 0\nResend: 1\nok\n".encode()


def test_an_error_discards_the_rest_of_what_arrived():
    protocol = MarlinProtocol()
    events = feed(protocol, b"N1 G28*19\n" + numbered(1, "G28") + numbered(2, "M105"))
    assert events == [LineRejected(LineError.CHECKSUM, 1)]
    assert feed(protocol, numbered(1, "G28")) == [CommandReceived("G28", 1)]


@pytest.mark.parametrize("repeat", [4, 5])
def test_a_repeat_of_the_last_line_or_the_one_before_is_dropped_silently(repeat):
    protocol = MarlinProtocol()
    protocol.last_n = 5
    assert feed(protocol, numbered(repeat, "G1 X1")) == []
    assert protocol.data_to_send() == b""
    assert protocol.last_n == 5


def test_m110_sets_the_line_number_from_its_own_n_even_negative():
    protocol = MarlinProtocol()
    protocol.last_n = 41
    assert feed(protocol, numbered(-1, "M110 N-1")) == [CommandReceived("M110 N-1", -1)]
    assert feed(protocol, numbered(0, "G28")) == [CommandReceived("G28", 0)]


def test_bare_lines_are_accepted_and_do_not_count():
    protocol = MarlinProtocol()
    assert feed(protocol, b"M105\nG28 X Y\n") == [CommandReceived("M105", None), CommandReceived("G28 X Y", None)]
    assert protocol.last_n == 0


def test_empty_lines_are_ignored_never_answered():
    protocol = MarlinProtocol()
    assert feed(protocol, b"\n\r\n   \n;just a comment\n") == []
    assert protocol.data_to_send() == b""


def test_comments_escapes_and_backspace_as_the_firmware_strips_them():
    protocol = MarlinProtocol()
    events = feed(protocol, b"G1 X10 ; move\nG1 (inline) Y5\nM117 a\\;b\nG1 X9\x089\n")
    assert [e.text for e in events] == ["G1 X10", "G1  Y5", "M117 a;b", "G1 X9"]


def test_the_checksum_covers_a_paren_comment_as_the_host_sent_it():
    protocol = MarlinProtocol()
    wire = numbered(1, "G1 Z0.3 F600 (first layer)")
    assert feed(protocol, wire) == [CommandReceived("G1 Z0.3 F600", 1)]
    assert protocol.data_to_send() == b""


def test_a_nul_ends_the_line_as_in_a_c_string():
    protocol = MarlinProtocol()
    assert feed(protocol, b"\x00\x00N1 G28*18\n") == []  # read as an empty line
    assert feed(protocol, b"M105\x00junk\n") == [CommandReceived("M105", None)]


def test_an_overlong_line_is_cut_at_max_cmd_size():
    protocol = MarlinProtocol()
    (event,) = feed(protocol, b"M117 " + b"x" * 200 + b"\n")
    assert len(event.text) == 95  # MAX_CMD_SIZE - 1: the last byte holds the terminator


def test_reading_stops_while_the_command_queue_is_full():
    protocol = MarlinProtocol(queue_size=2)
    events = feed(protocol, b"G1 X1\nG1 X2\nG1 X3\n", release=False)
    assert [e.text for e in events] == ["G1 X1", "G1 X2"]
    protocol.send(CommandDone())
    assert feed(protocol, b"", release=False) == [CommandReceived("G1 X3", None)]


def test_the_emergency_parser_acts_even_with_a_full_queue():
    protocol = MarlinProtocol(queue_size=1)
    feed(protocol, b"G4 S10\n", release=False)
    events = feed(protocol, b"M108\nN7 M112*40\nM876 S1\n", release=False)
    assert events == [EmergencyCommand("M108"), EmergencyCommand("M112"), EmergencyCommand("M876 S1")]


def test_ok_forms():
    plain = MarlinProtocol()
    assert plain.send(CommandDone(3)) == b"ok\n"
    assert plain.send(CommandDone(ok_suffix="T:21.00 /0.00")) == b"ok T:21.00 /0.00\n"
    advanced = MarlinProtocol(advanced_ok=True)
    feed(advanced, numbered(1, "G1 X1"), release=False)
    assert advanced.send(CommandDone(1, room=14)) == b"ok N1 P14 B4\n"
    feed(advanced, b"G1 X2\n", release=False)
    assert advanced.send(CommandDone(room=13)) == b"ok P13 B4\n"
    assert advanced.send(Output("echo:x")) == b"echo:x\n"


def test_while_saving_to_sd_only_numbered_lines_and_m29_are_accepted():
    protocol = MarlinProtocol()
    protocol.saving_to_sd = True
    assert feed(protocol, b"G1 X1\n") == [LineRejected(LineError.NO_CHECKSUM, 1)]
    assert feed(protocol, numbered(1, "G1 X1") + b"M29\n") == [CommandReceived("G1 X1", 1), CommandReceived("M29", None)]


# A command starts with a letter: after `N12` with no space a leading digit would join the number,
# for Marlin as for us.
commands = st.builds(
    lambda letter, rest: letter + rest,
    st.sampled_from("GMTgmt"),
    st.text(
        alphabet=st.characters(min_codepoint=0x21, max_codepoint=0x7E, exclude_characters=";()*\\"),
        max_size=60,
    ),
)


@given(st.lists(commands, min_size=1, max_size=20), st.booleans())
def test_numbered_lines_round_trip(texts, spaced):
    protocol = MarlinProtocol()
    wire = b"".join(numbered(n + 1, text, " " if spaced else "") for n, text in enumerate(texts))
    events = feed(protocol, wire)
    assert [(e.text, e.number) for e in events] == [
        (text.strip(), n + 1) for n, text in enumerate(texts)
    ]


@settings(max_examples=300)
@given(st.lists(st.binary(max_size=80), max_size=20))
def test_arbitrary_bytes_never_crash_and_every_reply_is_ascii(chunks):
    protocol = MarlinProtocol()
    for chunk in chunks:
        for event in feed(protocol, chunk):
            assert isinstance(event, (CommandReceived, LineRejected, EmergencyCommand))
    protocol.data_to_send().decode("ascii")


class CharByChar(MarlinProtocol):
    """The receiver as the firmware runs it: process_stream_char() for every byte, and every
    line through the whole of get_serial_commands()'s rules."""

    def _stream_chars(self, data, start, stop):
        for position in range(start, stop):
            self._stream_char(data[position])

    def _whole_plain_line(self, data):
        return None

    def _scan_for_emergencies(self, data):
        self._scan_lines_for_emergencies(data)  # every line looked at, M or not


_plain = st.text("G1 XYEF0123456789.-", max_size=40)
_long = st.text("G1 XYEF0123456789.-", min_size=84, max_size=96)  # about what the buffer holds
_one_odd_character = st.builds(lambda before, odd, after: before + odd + after, _plain,
                               st.sampled_from("*();\r\\\x08\x00"), _plain)


@settings(max_examples=300)
@given(st.lists(st.tuples(st.integers(-2, 4),
                          st.text("G1 XYEF0123456789.-*() ;", max_size=30)
                          | _plain | _long | _long | _one_odd_character,
                          st.booleans()), max_size=20))
def test_the_usual_line_read_in_one_match_is_read_as_the_rules_read_it(lines):
    """Numbered lines near the expected number, right or wrong checksums, stray `*` and `(`,
    line ends, escapes, backspaces and NULs inside, lines too long for the buffer: each in a
    read of its own, as a host sends them."""
    fast, slow = MarlinProtocol(), CharByChar()
    for offset, text, right in lines:
        body = f"N{fast.last_n + offset} {text}"
        wire = f"{body}*{xor_checksum(body) if right else 0}\n".encode()
        assert feed(fast, wire) == feed(slow, wire)
        assert fast.last_n == slow.last_n
    assert fast.data_to_send() == slow.data_to_send()


@pytest.mark.parametrize("length", range(MAX_CMD_SIZE - 4, MAX_CMD_SIZE + 3))
def test_a_line_about_as_long_as_the_buffer_is_read_as_the_rules_read_it(length):
    # The firmware keeps MAX_CMD_SIZE - 1 characters of a line; a longer one loses its end.
    lines = (f"{body}*{xor_checksum(body)}" for body in (f"N1 G1 X{'1' * digits}{end}"
                                                         for digits in range(length)
                                                         for end in ("", " ")))
    wire = next(line for line in lines if len(line) == length).encode() + b"\n"
    fast, slow = MarlinProtocol(), CharByChar()
    assert feed(fast, wire) == feed(slow, wire)
    assert fast.data_to_send() == slow.data_to_send()


@settings(max_examples=300)
@given(st.lists(st.binary(max_size=120) | st.sampled_from(
    [b"N1 G1 X1*", b";", b"(", b")", b"\\", b"\x08", b"\n", b"\r", b"M112\n", b"x" * 100,
     b"M", b"11", b"2", b"M108", b"N3 M410\r"]
), max_size=30))
def test_reading_a_stretch_at_once_is_reading_it_char_by_char(chunks):
    fast, slow = MarlinProtocol(), CharByChar()
    for chunk in chunks:
        assert feed(fast, chunk) == feed(slow, chunk)
    assert fast.data_to_send() == slow.data_to_send()
