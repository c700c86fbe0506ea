"""g2core's JSON protocol (wire/g2core.py, emulator/protocols/g2core.py, the session): vectors read
from g2core's source (docs/protocols.md section 7), and a board in memory on trio's autojump clock."""

import json

import pytest
import trio
from hypothesis import given, strategies as st

from fake_marlin.emulator.protocols.base import CommandReceived
from fake_marlin.emulator.protocols.g2core import (
    BadLine,
    BadRequest,
    G2coreProtocol,
    JsonRequest,
    SingleCharacter,
)
from fake_marlin.testing import memory_printer
from fake_marlin.wire import g2core
from fake_marlin.wire.g2core import NULL, Number, RelaxedJsonError


@pytest.mark.parametrize("line, pairs", [
    ("{ej:1}", {"ej": 1}),
    ('{"SR":N}', {"sr": NULL}),  # lower-cased, n is null: a GET
    ('{"qr":""}', {"qr": NULL}),  # "" too
    ("{sr:{stat:t,line:t,posx:t}}", {"sr": {"stat": True, "line": True, "posx": True}}),
    ("{ he1st : 200.5 }", {"he1st": 200.5}),
    ("{xvm:f}", {"xvm": False}),
    ('{gc:"G1 X10 (Keep This)"}', {"gc": "g1x10(Keep This)"}),  # normalized, but in comments
])
def test_relaxed_json_reads_as_g2cores_parser_does(line, pairs):
    assert g2core.parse_request(line) == pairs


@pytest.mark.parametrize("line, status", [
    ("{toolong:1}", 107),  # a name of more than 6 characters
    ("{a:.5}", 111),  # a number may not start with a point
    ("{a:[1]}", 116),  # arrays are not taken
    ("{a:1e999}", 102),
    ("{a:1", 111),
    ("{" + ",".join(f"a{i}:1" for i in range(40)) + "}", 112),
    ("{a:'" + "x" * 600 + "'}", 107),
])
def test_requests_the_parser_refuses_say_its_status(line, status):
    with pytest.raises(RelaxedJsonError) as refused:
        g2core.parse_request(line)
    assert refused.value.status == status


@given(st.text(max_size=80))
def test_any_request_text_parses_or_is_refused_with_a_status(text):
    try:
        g2core.parse_request("{" + text)
    except RelaxedJsonError as refused:
        assert refused.status in g2core.STATUS_MESSAGES


def test_numbers_are_written_as_floattoa_writes_them():
    assert [g2core.format_number(value, places) for value, places in [
        (0.0, 3), (20.1, 3), (-10.0, 3), (101.03, 2), (0.99, 2), (1.23456, 5), (-0.0001, 3)]] == [
        "0", "20.1", "-10", "101.03", "0.99", "1.23456", "0"]
    body = {"fv": Number(0.99, 2), "fb": Number(101.03, 2), "fbs": "101.03",
            "fbc": "settings_default.h", "hp": "g2v9", "hv": "k", "id": "0084-d639-18c6-7bd0",
            "msg": "SYSTEM READY"}
    assert g2core.response(body, 0, 1) == (
        b'{"r":{"fv":0.99,"fb":101.03,"fbs":"101.03","fbc":"settings_default.h","hp":"g2v9",'
        b'"hv":"k","id":"0084-d639-18c6-7bd0","msg":"SYSTEM READY"},"f":[1,0,1]}\n')


def test_the_machine_reads_controls_ahead_of_queued_gcode_and_counts_each_lines_bytes():
    protocol = G2coreProtocol()
    protocol.reading_gcode = False  # the planner is full
    protocol.receive_data(b'N12G1X5\nG1 X10\n{"qr":""}\n{"ej":1}\r\n!~\x05N1 G1*99\nG1 X1*63\n')
    events = []
    while (event := protocol.next_event()) is not None:
        events.append(event)
    # Sizes as g2core's footer says them (a capture of 100.17: {"qr":""} 11, {"ej":1} 10).
    assert events == [JsonRequest({"qr": NULL}, 11), JsonRequest({"ej": 1}, 11),
                      SingleCharacter(ord("!")), SingleCharacter(ord("~")), SingleCharacter(5)]
    protocol.reading_gcode = True
    while (event := protocol.next_event()) is not None:
        events.append(event)
    assert events[5:] == [CommandReceived("G1X5", 12, 8), CommandReceived("G1 X10", None, 7),
                          BadLine(118, 9), BadLine(120, 9)]


def test_a_checksum_is_checked_as_g2core_checks_it_and_line_numbers_never_are():
    """gcode_parser.cpp _verify_checksum(): the XOR of what precedes the first `*`, compared with
    strtol() of what follows it, before the `N` is looked for; the line ends at the `*`."""
    def events(data: bytes) -> list:
        protocol = G2coreProtocol()
        protocol.receive_data(data)
        return list(iter(protocol.next_event, None))

    assert events(b"*999\n*0\nG1 X1*5\n") == [BadLine(118, 5), BadLine(120, 3), BadLine(118, 8)]
    # A line feed lost between two lines: the first one's checksum still checks out (strtol stops
    # at the `N`), and the second is cut off with the rest.
    assert events(b"N12 G1 X5*86\x0bN13 G1 X6*37\n") == [CommandReceived("G1 X5", 12, 26)]
    # No sequence: the same N twice, or one going back, runs (cm_check_linenum() never does).
    assert events(b"N7 G1*47\nN7 G1*47\nN3 G1*43\n") == [
        CommandReceived("G1", 7, 9), CommandReceived("G1", 7, 9), CommandReceived("G1", 3, 9)]
    # Digits of other scripts are no line number.
    assert events("N\u00b2 G1\n".encode("latin-1")) == [CommandReceived("N\u00b2 G1", None, 6)]


def test_a_line_the_parser_refuses_is_an_event_not_an_exception():
    protocol = G2coreProtocol()
    protocol.receive_data(b"{a:.5}\n")
    assert protocol.next_event() == BadRequest(111, "{a:.5}", 8)


class Board:
    """A host's end of a g2core board's USB line: JSON lines back."""

    def __init__(self, stream) -> None:
        self.stream = stream
        self.buffer = b""

    async def line(self) -> dict:
        while b"\n" not in self.buffer:
            self.buffer += await self.stream.receive_some(4096)
        line, self.buffer = self.buffer.split(b"\n", 1)
        return json.loads(line)

    async def ask(self, text: bytes) -> dict:
        """Send a line; the board's response to it (reports before it are skipped)."""
        await self.stream.send_all(text)
        while "f" not in (reply := await self.line()):
            pass
        return reply


async def test_a_board_answers_a_cncjs_style_start_and_runs_a_job_with_a_feedhold(autojump_clock):
    async with memory_printer(firmware="g2core", protocol="g2core") as printer:
        board = Board(printer.open())
        banner = await board.line()
        assert banner["r"]["msg"] == "SYSTEM READY" and banner["f"] == [1, 0, 1]
        assert banner["r"]["fb"] == 101.03 and banner["r"]["hp"] == "g2v9"
        assert await board.ask(b"{ej:1}\n") == {"r": {"ej": 1}, "f": [1, 0, 8]}
        assert await board.ask(b"{jv:4}\n") == {"r": {"jv": 4}, "f": [1, 0, 8]}
        assert await board.ask(b"{qv:1}\n") == {"r": {"qv": 1}, "f": [1, 0, 8]}
        assert await board.ask(b"{spe:n}\n") == {"r": {"spe": None}, "f": [1, 100, 9]}
        assert (await board.ask(b"{jv:9}\n"))["f"] == [1, 109, 8]
        sr = await board.ask(b"{sr:{stat:t,line:t,posx:t}}\n")
        assert sr == {"r": {"sr": {"stat": 1, "line": 0, "posx": 0}}, "f": [1, 0, 29]}
        assert (await board.ask(b"{qr:n}\n"))["r"] == {"qr": 48}  # PLANNER_QUEUE_SIZE
        assert await board.ask(b"N1G1X40F600\n") == {"r": {"n": 1}, "f": [1, 0, 12]}
        report = await board.line()
        while "sr" not in report:
            report = await board.line()
        assert report["sr"]["stat"] == 5 and report["sr"]["line"] == 1
        await trio.sleep(1)  # under way
        await board.stream.send_all(b"!")
        while (report := await board.line()).get("sr", {}).get("stat") != 6:
            pass
        held = (await board.ask(b"{sr:n}\n"))["r"]["sr"]["posx"]
        assert 0 < held < 40
        assert (await board.ask(b"{sr:n}\n"))["r"]["sr"]["posx"] == held  # it stays there
        await board.stream.send_all(b"~")
        while (report := await board.line()).get("sr", {}).get("stat") != 3:
            pass
        assert report["sr"]["posx"] == 40
        assert await board.ask(b"N2G1X5Q\n") == {"r": {"n": 2}, "f": [1, 0, 8]}
        assert (await board.ask(b"M9999\n"))["f"][1] == 132  # an M code it lacks
        assert printer.journal == ["G1X40F600", "G1X5Q"]


async def test_a_marlin_host_on_the_same_port_is_answered_in_marlins_words(autojump_clock):
    async with memory_printer(firmware="g2core") as printer:
        stream = printer.open()
        await stream.send_all(b"N0 M110 N0*125\n")
        data = b""
        while b"ok\n" not in data:
            data += await stream.receive_some(4096)
        assert data == b"ok\n"  # and no banner: a Marlin host spoke within its 2 s
        await stream.send_all(b"M115\n")
        while b"UUID:" not in data:
            data += await stream.receive_some(4096)
        assert b"FIRMWARE_NAME:Marlin g2core-101.03 SOURCE_CODE_URL:https://github.com/synthetos/g2" in data
        await stream.send_all(b'{"fb":n}\nM105\n')  # JSON is still g2core's, in JSON
        while b"ok T:" not in data:
            data += await stream.receive_some(4096)
        assert b'{"r":{"fb":101.03},"f":[1,0,10]}\nok T:21 /0 B:21 /0 @:0 B@:0\n' in data
        with trio.move_on_after(3):
            data += await stream.receive_some(4096)
        assert b"SYSTEM READY" not in data


async def test_the_next_connection_after_a_marlin_host_starts_in_g2cores_protocol(autojump_clock):
    async with memory_printer(firmware="g2core") as printer:
        marlin = printer.open()
        await marlin.send_all(b"M105\n")
        data = b""
        while b"ok T:" not in data:
            data += await marlin.receive_some(4096)
        board = Board(printer.open())  # the port opened again: the banner, and JSON
        start = trio.current_time()
        while (await board.line()).get("r", {}).get("msg") != "SYSTEM READY":
            pass
        assert trio.current_time() - start == pytest.approx(2.0, abs=0.05)
        assert await board.ask(b"{fb:n}\n") == {"r": {"fb": 101.03}, "f": [1, 0, 8]}
        assert await board.ask(b"N1G1X5F600\n") == {"r": {}, "f": [1, 0, 11]}
        again = printer.open()  # and a Marlin host once more
        await again.send_all(b"N0 M110 N0*125\n")
        data = b""
        while b"ok\n" not in data:
            data += await again.receive_some(4096)
        assert "G1X5F600" in printer.journal


async def test_g2cores_gcode_and_the_switch_to_marlins_meanings(autojump_clock):
    async with memory_printer(firmware="g2core", protocol="g2core") as printer:
        board = Board(printer.open())
        await board.line()  # the banner
        assert (await board.ask(b"G28.2 X0 Y0 Z0\n"))["f"][1] == 0  # g2core's homing
        assert printer.server.printer.motion.homed == {"X", "Y", "Z"}
        await board.ask(b"G1 X30 Y20 F3000\n")
        await board.ask(b"G28.1\n")  # keep this position for G28
        await board.ask(b"G1 X5 Y5\n")
        await board.ask(b"G28\n")  # g2core's G28: back to the G28.1 position, no homing
        await board.ask(b"M400\n")
        assert printer.server.printer.motion.position[:2] == [30.0, 20.0]
        assert (await board.ask(b"M100 ({he1st:180})\n"))["f"][1] == 0  # in order with moves
        await trio.sleep(2)
        assert printer.server.printer.hotends[0].target == 180
        await board.ask(b"M101 ({he1at:t})\n")  # waits, and holds the next line unread
        start = trio.current_time()
        await board.ask(b"G1 X1\n")
        assert trio.current_time() - start > 10 and printer.server.printer.hotends[0].temperature(
            trio.current_time()) > 179
        assert (await board.ask(b"M100.1 ({he3st:60})\n"))["r"]["he3st"] == 60
        assert (await board.ask(b"G1 X10 E1.5\n"))["f"][1] == 0  # an E word: Marlin's meanings
        await board.ask(b"G28\n")  # ...so G28 homes now
        await board.ask(b"M400\n")
        assert printer.server.printer.motion.position[:3] == [0.0, 0.0, 0.0]
        assert printer.journal[:2] == ["G28.2 X0 Y0 Z0", "G1 X30 Y20 F3000"]
        assert "M100" in printer.journal and "M101" in printer.journal  # (comments go, as ever)


async def test_motion_modes_probing_machine_coordinates_and_the_program_end(autojump_clock):
    async with memory_printer(firmware="g2core", protocol="g2core") as printer:
        board = Board(printer.open())
        await board.line()
        await board.ask(b"{sr:{momo:t,stat:t,posz:t}}\n")
        await board.ask(b"G0 X10\n")
        assert (await board.ask(b"{sr:n}\n"))["r"]["sr"]["momo"] == 0
        await board.ask(b"G38.2 Z-5 F100\n")
        await board.ask(b"G53 G0 X0\n")
        await board.ask(b"G2 X10 Y0 I5 J0 F600\n")
        assert (await board.ask(b"{sr:n}\n"))["r"]["sr"]["momo"] == 2
        await board.ask(b"M30\n")
        assert (await board.ask(b"{sr:n}\n"))["r"]["sr"]["stat"] == 5  # M30 waits its turn
        while (report := await board.line()).get("sr", {}).get("stat") != 4:
            pass
        assert printer.server.printer.motion.position[:3] == [10.0, 0.0, -5.0]


async def test_each_board_has_its_own_id(autojump_clock):
    ids = []
    for seed in (1, 2):  # (a farm's printers differ by number as by seed: the identity's)
        async with memory_printer(firmware="g2core", protocol="g2core", seed=seed) as printer:
            board = Board(printer.open())
            ids.append((await board.line())["r"]["id"])
    assert ids[0] != ids[1] and all(len(i) == 19 and i.count("-") == 3 for i in ids)


async def test_a_queue_flush_in_a_hold_drops_the_moves_and_stays_where_it_stopped(autojump_clock):
    async with memory_printer(firmware="g2core", protocol="g2core") as printer:
        board = Board(printer.open())
        await board.line()
        await board.ask(b"G1 X40 F600\n")
        await board.ask(b"G1 Y40\n")
        await trio.sleep(1)
        await board.stream.send_all(b"!")
        await trio.sleep(1)
        await board.stream.send_all(b"%\n")
        sr = (await board.ask(b"{sr:n}\n"))["r"]["sr"]
        assert sr["stat"] == 3 and 0 < sr["posx"] < 40 and sr["posy"] == 0
        await trio.sleep(10)
        assert (await board.ask(b"{sr:n}\n"))["r"]["sr"]["posx"] == sr["posx"]  # nothing ran on
        assert printer.server.printer.motion.position[0] == sr["posx"]


async def test_a_dwell_is_seconds_and_queued_so_the_next_lines_are_read(autojump_clock):
    async with memory_printer(firmware="g2core", protocol="g2core") as printer:
        board = Board(printer.open())
        await board.line()
        await board.ask(b"G1 X10 F600\n")
        start = trio.current_time()
        await board.ask(b"G4 P2\n")
        assert (await board.ask(b"G1 X20\n"))["f"][1] == 0
        assert trio.current_time() - start < 0.1  # read on, not waited for
        await board.ask(b"{sr:{stat:t,posx:t}}\n")
        while (report := await board.line()).get("sr", {}).get("stat") != 3:
            pass
        assert report["sr"]["posx"] == 20
        assert 1 + 2 + 1 - 0.1 < trio.current_time() - start < 1 + 2 + 1 + 0.6  # moves + dwell


async def test_a_thermal_fault_is_an_alarm_that_refuses_lines_until_clear(autojump_clock):
    from fake_marlin.emulator.printer.failures import Failure, FailureKind, apply

    async with memory_printer(firmware="g2core", protocol="g2core") as printer:
        board = Board(printer.open())
        while (await board.line()).get("r", {}).get("msg") != "SYSTEM READY":
            pass
        server = printer.server
        server.announce(apply(server.printer, Failure(FailureKind.THERMAL_RUNAWAY, "T0"),
                              trio.current_time()))
        report = await board.line()
        while "er" not in report:
            report = await board.line()
        assert report["er"]["st"] == 18 and report["er"]["msg"].startswith("System alarm - ")
        assert await board.ask(b"N7G1X5\n") == {"r": {}, "f": [1, 204, 7]}
        assert (await board.ask(b"{he1st:200}\n"))["f"][1] == 204  # a SET too
        assert (await board.ask(b"{sr:n}\n"))["r"]["sr"]["stat"] == 2  # a GET still works
        assert (await board.ask(b"{clear:n}\n"))["f"][1] == 0
        assert (await board.ask(b"N8G1X5\n"))["f"][1] == 0
        assert printer.journal == ["G1X5"]


async def test_a_refused_code_takes_no_line_number(autojump_clock):
    async with memory_printer(firmware="g2core", protocol="g2core") as printer:
        board = Board(printer.open())
        await board.ask(b"{jv:4}\n")
        assert await board.ask(b"N5G1X1\n") == {"r": {"n": 5}, "f": [1, 0, 7]}
        assert await board.ask(b"N6M9999\n") == {"r": {}, "f": [1, 132, 8]}
        assert (await board.ask(b"{n:n}\n"))["r"]["n"] == 5


async def test_the_canary_line_reaches_marlins_protocol_as_it_came(autojump_clock):
    async with memory_printer(firmware="g2core") as printer:
        stream = printer.open()
        await stream.send_all(b"N0 M110 N0*125\nN1 M105*38\n")
        data = b""
        while b"ok T:" not in data:
            data += await stream.receive_some(4096)
        assert printer.journal[:2] == ["M110 N0", "M105"]  # its N0 argument kept
