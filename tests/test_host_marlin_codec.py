"""The host's Marlin codec: what it sends, checked by the printer's own state machine, and how it
reads every kind of line Marlin says."""

import itertools

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fake_marlin.emulator.protocols.base import CommandReceived
from fake_marlin.emulator.protocols.marlin import (
    EmergencyCommand,
    LineRejected,
    MarlinProtocol,
)
from fake_marlin.host.codecs.marlin import (
    MAX_COMMAND,
    PROBE,
    Line,
    LineError,
    LineErrorKind,
    LineKind,
    LineParser,
    Ok,
    ResendRequest,
    check_command,
    encode_line,
    encode_sync,
    parse_line,
)
from fake_marlin.host.errors import CommandError

TEMPERATURES = "T:21.00 /0.00 B:21.00 /0.00 @:0 B@:0"


@pytest.mark.parametrize(
    "text, event",
    [
        ("ok", Ok()),
        (f"ok {TEMPERATURES}", Ok(TEMPERATURES)),
        ("ok N5 P15 B3", Ok("", 5, 15, 3)),
        ("ok P14 B2", Ok("", None, 14, 2)),
        ("ok N12", Ok("", 12)),
        ("Resend: 5", ResendRequest(5, "Resend: 5")),
        ("Resend:5", ResendRequest(5, "Resend:5")),
        ("rs 17", ResendRequest(17, "rs 17")),
        ("rs N17", ResendRequest(17, "rs N17")),
        ("RESEND: N:3", ResendRequest(3, "RESEND: N:3")),
        ("Resend: ?", ResendRequest(None, "Resend: ?")),  # still a line error's middle line
        (
            "Error:Line Number is not Last Line Number+1, Last Line: 4",
            LineError(LineErrorKind.LINE_NUMBER, 4, "Error:Line Number is not Last Line Number+1, Last Line: 4"),
        ),
        (
            "Error:checksum mismatch, Last Line: 0",
            LineError(LineErrorKind.CHECKSUM, 0, "Error:checksum mismatch, Last Line: 0"),
        ),
        (
            "Error:No Checksum with line number, Last Line: 99",
            LineError(LineErrorKind.NO_CHECKSUM, 99, "Error:No Checksum with line number, Last Line: 99"),
        ),
        (
            "Error:checksum mismatch, Last Line: \x004",  # the number damaged: no number
            LineError(LineErrorKind.CHECKSUM, None, "Error:checksum mismatch, Last Line: \x004"),
        ),
        ("Error:Printer halted. kill() called!", Line(LineKind.HALTED, "Error:Printer halted. kill() called!")),
        (
            "Error:Thermal Runaway, system stopped! Heater_ID: 0",
            Line(LineKind.HALTED, "Error:Thermal Runaway, system stopped! Heater_ID: 0"),
        ),
        (
            "Error:MAXTEMP triggered, system stopped! Heater_ID: bed",
            Line(LineKind.HALTED, "Error:MAXTEMP triggered, system stopped! Heater_ID: bed"),
        ),
        (
            "Error:Heating failed, system stopped! Heater_ID: 0",
            Line(LineKind.HALTED, "Error:Heating failed, system stopped! Heater_ID: 0"),
        ),
        ("Error:volume.init failed", Line(LineKind.ERROR, "Error:volume.init failed")),
        ("echo:busy: processing", Line(LineKind.BUSY, "echo:busy: processing")),
        ("busy: paused for user", Line(LineKind.BUSY, "busy: paused for user")),
        ("echo:busy: paused for input", Line(LineKind.BUSY, "echo:busy: paused for input")),
        ("wait", Line(LineKind.WAIT, "wait")),
        ("start", Line(LineKind.START, "start")),
        ("echo: External Reset", Line(LineKind.START, "echo: External Reset")),
        ("echo:PowerUp", Line(LineKind.START, "echo:PowerUp")),
        (" External Reset", Line(LineKind.START, " External Reset")),  # Marlin 2.1: no echo:
        ("echo:Printer locked! (Unlock with M511 or LCD)",
         Line(LineKind.LOCKED, "echo:Printer locked! (Unlock with M511 or LCD)")),
        ('echo:Unknown command: "M9999"', Line(LineKind.ECHO, 'echo:Unknown command: "M9999"')),
        ("//action:poweroff", Line(LineKind.ACTION, "//action:poweroff")),
        (TEMPERATURES, Line(LineKind.REPORT, TEMPERATURES)),
        (f"{TEMPERATURES} W:?", Line(LineKind.REPORT, f"{TEMPERATURES} W:?")),
        ("X:1.00 Y:0.00 Z:0.00 E:0.00", Line(LineKind.REPORT, "X:1.00 Y:0.00 Z:0.00 E:0.00")),
        ("X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0", Line(LineKind.DATA, "X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0")),
        ("Cap:EEPROM:1", Line(LineKind.DATA, "Cap:EEPROM:1")),
        ("okay", Line(LineKind.DATA, "okay")),  # not an ok: damaged, or something else
        ("okecho:busy: processing", Line(LineKind.DATA, "okecho:busy: processing")),  # a lost line end
        ("rs232 ready", Line(LineKind.DATA, "rs232 ready")),
        ("Marlin 2.1.2.1", Line(LineKind.DATA, "Marlin 2.1.2.1")),
    ],
)
def test_every_kind_of_line(text, event):
    assert parse_line(text) == event


def test_the_parser_splits_lines_however_they_arrive():
    parser = LineParser()
    events = []
    for chunk in (b"o", b"k\r\nResend: ", b"3\n\nok T:21.00 /0", b".00\n", b"wait\n"):
        parser.receive_data(chunk)
        while (event := parser.next_event()) is not None:
            events.append(event)
    assert events == [Ok(), ResendRequest(3, "Resend: 3"), Ok("T:21.00 /0.00"), Line(LineKind.WAIT, "wait")]
    assert parser.garbled == 0


def test_damaged_lines_are_counted_and_an_endless_line_is_cut():
    parser = LineParser()
    parser.receive_data(b"o\xebk\n" + b"x" * 5000)
    assert parser.next_event() == Line(LineKind.DATA, "o\ufffdk")
    assert parser.garbled == 1
    assert parser.next_event() == Line(LineKind.DATA, "x" * 4096)
    assert parser.next_event() is None


@given(st.lists(st.binary(max_size=300), max_size=20))
def test_arbitrary_bytes_never_crash_the_parser(chunks):
    parser = LineParser()
    for chunk in chunks:
        parser.receive_data(chunk)
        while (event := parser.next_event()) is not None:
            assert isinstance(event, Ok | ResendRequest | LineError | Line)


@given(st.text(max_size=200))
def test_arbitrary_text_parses_as_some_event(text):
    assert isinstance(parse_line(text), Ok | ResendRequest | LineError | Line)


# -- what the host sends -------------------------------------------------------------------
def test_the_reference_vectors():
    assert encode_sync("M110 N0") == b"\nN0 M110 N0*125\n"
    assert encode_line(1, "G28") == b"N1 G28*18\n"
    assert encode_line(2, "M105") == b"N2 M105*37\n"


@pytest.mark.parametrize(
    "command, problem",
    [
        ("", "white space"),
        (" G28", "white space"),
        ("M117 caf\u00e9", "printable ASCII"),
        ("M117 " + "x" * MAX_COMMAND, "fit on a line"),
        ("G1 X1 ; comment", "comment"),
        ("M117 a*b", "checksum"),
        ("M117 back\\slash", "escape"),
        ("M110 N5", "line number"),
        ("m110", "line number"),
        ("M118 M110", "line number"),  # Marlin finds M110 anywhere in a line
    ],
)
def test_commands_that_cannot_go_on_a_marlin_line(command, problem):
    with pytest.raises(CommandError, match=problem):
        check_command(command)


_COMMAND_CHARS = st.sampled_from("GMTXYZEFSPN0123456789.-+ :/_#abcxyz\"'")


@given(
    st.lists(
        st.text(_COMMAND_CHARS, min_size=1, max_size=MAX_COMMAND)
        .map(str.strip)
        .filter(lambda text: text and "M110" not in text.upper()),
        min_size=1,
        max_size=20,
    ),
    st.integers(min_value=0, max_value=10**8),
)
def test_numbered_lines_reach_the_printer_as_sent(commands, first):
    printer = MarlinProtocol(queue_size=len(commands))
    printer.last_n = first
    for number, command in enumerate(commands, start=first + 1):
        check_command(command)
        printer.receive_data(encode_line(number, command))
        event = printer.next_event()
        if isinstance(event, EmergencyCommand):  # M108/M112/M410 are also seen at once
            event = printer.next_event()
        assert event == CommandReceived(command, number)
    assert printer.data_to_send() == b""


@pytest.mark.parametrize("counter", [-1, 0, 1, 2, 57])
def test_the_probe_is_always_refused_and_tells_the_counter(counter):
    printer = MarlinProtocol()
    printer.last_n = counter
    printer.receive_data(PROBE)
    event = printer.next_event()
    assert isinstance(event, LineRejected) and event.resend == counter + 1
    said = printer.data_to_send().decode().splitlines()
    assert said == [f"Error:checksum mismatch, Last Line: {counter}", f"Resend: {counter + 1}", "ok"]
    assert printer.last_n == counter


@pytest.mark.parametrize("counter", [0, 1, 2, 57])
def test_no_single_bit_flip_makes_the_probe_move_the_counter(counter):
    """A damaged probe is refused or dropped; if its leading N is hit, Marlin reads it as a bare
    line (unchecked, as every host's lines are), but nothing numbered is ever accepted."""
    body = PROBE[1:]  # the line itself; its leading line feed only ends a partial line
    for index in range(len(body)):
        for bit in range(8):
            damaged = bytearray(body)
            damaged[index] ^= 1 << bit
            printer = MarlinProtocol()
            printer.last_n = counter
            printer.receive_data(bytes(damaged) + b"\n")
            while (event := printer.next_event()) is not None:
                assert not (isinstance(event, CommandReceived) and event.number is not None)
            assert printer.last_n == counter, bytes(damaged)


def test_no_two_bit_flips_make_the_probe_an_emergency_command():
    """The emergency parser runs M108/M112/M410 on arrival, unchecked: a probe damaged into one
    would stop the printer (kill) in the middle of recovering from a noisy line."""
    body = PROBE[1:]
    flips = [(index, bit) for index in range(len(body) - 1) for bit in range(8)]
    for first, second in itertools.combinations_with_replacement(flips, 2):
        damaged = bytearray(body)
        for index, bit in {first, second}:
            damaged[index] ^= 1 << bit
        printer = MarlinProtocol()
        printer.receive_data(bytes(damaged))
        while (event := printer.next_event()) is not None:
            assert not isinstance(event, EmergencyCommand), bytes(damaged)


def test_the_probe_ends_a_partial_line_instead_of_joining_it():
    """A line whose end was lost, then the probe: the partial line is judged on its own and the
    counter stays right. Without the probe's leading line feed, Marlin would find M110 in the
    joined line, take its number from the probe's N0, and run the line with counter 0."""
    printer = MarlinProtocol()
    printer.last_n = 86
    line = encode_line(87, "G1 X36 Y2 F6000").rstrip(b"\n")
    printer.receive_data(line + PROBE)
    assert printer.next_event() == CommandReceived("G1 X36 Y2 F6000", 87)
    assert isinstance(printer.next_event(), LineRejected)
    assert printer.last_n == 87
    joined = MarlinProtocol()
    joined.last_n = 86
    joined.receive_data(line + PROBE[1:])
    # With both line feeds lost, the probe's own checksum is the joined line's last: refused,
    # the counter unchanged (without it: CommandReceived("G1 X36 Y2 F6000", 0), counter 0).
    assert isinstance(joined.next_event(), LineRejected)
    assert joined.last_n == 86
