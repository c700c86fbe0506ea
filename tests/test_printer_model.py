"""The printer model on its own: simulated time goes in, replies come out."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fake_marlin.emulator.firmware import Firmware
from fake_marlin.emulator.printer.gcode import is_plain_move, parse, plain_move
from fake_marlin.emulator.printer.model import Printer, Reply, Sleep
from fake_marlin.emulator.printer.planner import MAX_MOVES, Block, Planner


def run(printer: Printer, line: str, now: float) -> tuple[Reply, float]:
    """Drive one command to completion; returns its reply and the time it finished."""
    steps = printer.execute(line, now)
    try:
        step = next(steps)
        while True:
            if isinstance(step, Sleep):
                assert step.until >= now, "the model asked to sleep into the past"
                now = step.until
            step = steps.send(now)
    except StopIteration as finished:
        return finished.value, now


MARLIN = Firmware.make().words  # the model states; these tests read it in Marlin's words


def said(reply: Reply) -> tuple[str, ...]:
    return tuple(MARLIN.lines(reply.lines))


def answer(reply: Reply) -> str:
    return MARLIN.one_line(reply.answer) if reply.answer is not None else ""


def test_m105_reports_in_marlins_format():
    reply, _ = run(Printer(), "M105", 0.0)
    assert said(reply) == () and answer(reply) == "T:21.00 /0.00 B:21.00 /0.00 @:0 B@:0"


def test_m114_reports_in_marlins_format():
    printer = Printer()
    run(printer, "G1 X10 Y20.5 Z0.3 E1 F3000", 0.0)
    reply, _ = run(printer, "M400", 0.0)
    reply, _ = run(printer, "M114", 100.0)
    assert said(reply) == ("X:10.00 Y:20.50 Z:0.30 E:1.00 Count X:800 Y:1640 Z:120",)


def test_moves_fill_the_planner_and_room_drains_back_with_time():
    printer = Printer()
    now = 0.0
    for n in range(15):
        _, now = run(printer, f"G1 X{(n + 1) * 10} F1200", now)
    assert now == 0.0 and printer.room(now) == 0
    _, now = run(printer, "G1 X160", now)  # the 16th must wait for the first to finish
    assert now > 0.0 and printer.room(now) == 0
    _, done = run(printer, "M400", now)
    assert printer.room(done) == 15
    # 16 moves of 10 mm at 20 mm/s take 8 s, plus the ramps from and to the 10 mm/s junctions.
    assert 8.02 < done < 8.1


def test_acceleration_makes_short_moves_slower_than_distance_over_feedrate():
    printer = Printer()
    run(printer, "G1 X1 F6000", 0.0)
    _, done = run(printer, "M400", 0.0)
    assert done > 1 / 100


def test_dwell_waits_for_moves_then_the_time_given():
    printer = Printer()
    run(printer, "G1 X10 F600", 0.0)
    _, moved = run(printer, "M400", 0.0)
    printer2 = Printer()
    run(printer2, "G1 X10 F600", 0.0)
    _, done = run(printer2, "G4 P500", 0.0)
    assert done == pytest.approx(moved + 0.5)
    assert run(Printer(), "G4 S2", 5.0)[1] == 7.0


def test_relative_and_absolute_modes():
    printer = Printer()
    for line in ["G91", "G1 X5 E1", "G1 X5 E1", "G90", "M83", "G1 Y3 E2", "G1 E2", "G92 E0"]:
        run(printer, line, 0.0)
    assert printer.motion.position == [10.0, 3.0, 0.0, 0.0]


def test_homing_takes_time_and_zeroes_the_named_axes():
    printer = Printer()
    run(printer, "G92 X50 Y60 Z5", 0.0)
    _, done = run(printer, "G28 X Y", 0.0)
    assert done > 1.0
    assert printer.motion.position[:3] == [0.0, 0.0, 5.0]


def test_unknown_commands_answer_like_marlin():
    assert said(run(Printer(), "M9999 S1", 0.0)[0]) == ('echo:Unknown command: "M9999 S1"',)
    assert said(run(Printer(), "FOO", 0.0)[0]) == ('echo:Unknown command: "FOO"',)
    assert run(Printer(), "; only a comment", 0.0)[0] == Reply()


def test_heaters_warm_toward_target_and_report_it():
    printer = Printer()
    run(printer, "M104 S200", 0.0)
    run(printer, "M140 S60", 0.0)
    early, _ = run(printer, "M105", 10.0)
    late, _ = run(printer, "M105", 600.0)
    assert answer(early).startswith("T:6") and "@:127" in answer(early)
    assert answer(late).startswith("T:200.00 /200.00 B:60.00 /60.00")


def test_reset_stops_motion_and_heaters_but_not_physics():
    printer = Printer()
    run(printer, "M104 S200", 0.0)
    run(printer, "G1 X100 F600", 0.0)
    printer.reset(30.0)
    assert printer.room(30.0) == 15 and printer.motion.position == [0.0] * 4
    reply, _ = run(printer, "M105", 30.0)
    assert answer(reply).startswith("T:1") and "/0.00" in answer(reply)


def test_arcs_end_where_asked_and_take_their_length_in_time():
    printer = Printer()
    run(printer, "G1 X10 Y0 F6000", 0.0)
    _, t0 = run(printer, "M400", 0.0)
    run(printer, "G2 X-10 Y0 I-10 J0 F600", t0)  # a half circle of radius 10: 31.4 mm at 10 mm/s
    _, done = run(printer, "M400", t0)
    assert printer.motion.position[:2] == [-10.0, 0.0]
    assert 3.1 < done - t0 < 3.3
    run(printer, "G3 X10 Y0 R10", done)
    assert printer.motion.position[:2] == [10.0, 0.0]


def test_firmware_retraction_moves_filament_but_not_the_coordinates():
    printer = Printer()
    run(printer, "M207 S4 F2400", 0.0)
    run(printer, "G1 E10 F600", 0.0)
    run(printer, "G10", 0.0)
    assert printer.motion.position[3] == 10.0 and printer.motion.retracted
    assert printer.planner.moves(0.0) == 2
    run(printer, "G10", 0.0)  # already retracted: nothing more
    assert printer.planner.moves(0.0) == 2
    run(printer, "G11", 0.0)
    assert not printer.motion.retracted and printer.planner.moves(0.0) == 3


def test_probing_needs_homing_then_reports_three_points():
    printer = Printer()
    assert said(run(printer, "G29", 0.0)[0]) == ("echo:Home XYZ First",)
    run(printer, "G28", 0.0)
    reply, done = run(printer, "G29", 0.0)
    assert [line.split(" Z:")[0] for line in said(reply)[:3]] == [
        "Bed X: 20.000 Y: 20.000", "Bed X: 180.000 Y: 20.000", "Bed X: 100.000 Y: 180.000"
    ]
    assert done > 5.0


def test_fans_clip_to_0_255_and_speed_factor_scales_moves():
    printer = Printer()
    run(printer, "M106 S300", 0.0)
    assert printer.fans[0] == 255
    run(printer, "M106 S-4", 0.0)
    assert printer.fans[0] == 0
    run(printer, "M106", 0.0)
    assert printer.fans[0] == 255
    run(printer, "M107", 0.0)
    assert printer.fans[0] == 0
    assert said(run(printer, "M220", 0.0)[0]) == ("FR:100%",)
    run(printer, "M220 S200", 0.0)
    run(printer, "G1 X100 F600", 0.0)
    _, done = run(printer, "M400", 0.0)
    assert 5.0 < done < 5.1  # 100 mm at twice 10 mm/s


def test_messages_and_debug():
    printer = Printer()
    assert said(run(printer, "M118 Hello there", 0.0)[0]) == ("Hello there",)
    assert said(run(printer, "M118 E1 A1 pause", 0.0)[0]) == ("echo://pause",)
    assert said(run(printer, "M111 S3", 0.0)[0]) == ("echo:DEBUG:ECHO,INFO",)
    assert said(run(printer, "M111 S0", 0.0)[0]) == ("echo:DEBUG:OFF",)


@pytest.mark.parametrize("line", ["\x0e1190 G1 X35.5 Y22.5", "O101 G1 X5", "1190 G1 X1", "*G1 X2"])
def test_a_line_that_does_not_start_with_its_command_is_unknown_and_does_not_move(line):
    """Marlin reads the command letter where the line starts; a damaged leading N leaves junk
    there, and the G1 behind it must not run (its numbered original is resent and runs)."""
    command = parse(line)
    assert command.code == "" and command.params == {}


# -- the straight move's quick way (a session's most common command) ------------------------
_number = st.from_regex(r"-?[0-9]{1,4}(\.[0-9]{0,3})?", fullmatch=True)
# Mostly the plain form (`G1 X10.4 Y10.0 E0.020 F6000`), with the few things that make a line
# take parse() instead: other letters and codes, no number, no space or two, a comment.
_plain_word = st.tuples(st.sampled_from("XYZEF"), _number, st.just(" "))
_other_word = st.tuples(st.sampled_from("XYZEFxSI"), _number | st.just(""),
                        st.sampled_from([" ", "", "  "]))
_move_lines = st.builds(
    lambda code, words, end: code + "".join(space + letter + number
                                            for letter, number, space in words) + end,
    st.sampled_from(["G1", "G1", "G0", "G01", "g1", "G2"]),
    st.lists(_plain_word | _plain_word | _other_word, min_size=1, max_size=6),
    st.sampled_from(["", "", "", " ", " ;c"]),
)


@given(_move_lines)
def test_a_plain_move_is_a_straight_move_with_numbers_for_the_axes_and_feedrate_only(line):
    command = parse(line)
    if is_plain_move(line):
        assert command.code in ("G0", "G1") and command.text == line
        assert all(letter in "XYZEF" and value is not None
                   for letter, value in command.params.items())


# A move as hosts send it: the axes in order, each at most once, F before or after them.
_plain_moves = st.builds(
    lambda code, numbers: code + "".join(f" {letter}{number}"
                                         for letter, number in zip("FXYZEF", numbers)
                                         if number is not None),
    st.sampled_from(["G0", "G1"]),
    st.tuples(*[st.none() | _number] * 6).filter(lambda numbers: any(n is not None
                                                                        for n in numbers)),
)


@given(_plain_moves)
def test_a_move_as_hosts_send_it_is_plain(line):
    assert is_plain_move(line)


@pytest.mark.parametrize("line", ["G1 Y10 X5", "G1 X5 X6", "G1 E1 Z2", "G1", "G1 X5 ;c", "G1 X",
                                  "G1 F100 F200 F300", "G1 x5"])
def test_a_move_in_another_form_takes_the_general_way(line):
    assert not is_plain_move(line)  # parse() and execute() read it as they read any line


# Between moves: what changes how a move is planned (limits, speed factor, modes, position) or
# waits for the planner (M400).
_other_lines = st.sampled_from(["M203 X50", "M220 S50", "M220 S100", "G92 X0 E0", "G91", "G90",
                                "M83", "M82", "M400", "M114", "M105", "G4 P1"])


@given(st.lists(st.tuples(_plain_moves | _plain_moves | _move_lines | _other_lines
                          | st.just("reset"),
                          st.sampled_from([0.0, 0.001, 0.01, 0.5]), st.booleans()),
                min_size=1, max_size=40),
       st.booleans())
def test_a_move_at_once_is_the_move_execute_makes(steps, relative):
    # The same lines through execute() and, where they are plain moves the planner has room
    # for, through move_at_once(), which plans later: looked at now and then (or only at the
    # end), the same planner, position and feedrate.
    general, quick = Printer(), Printer()
    now = 0.0
    for printer in (general, quick):
        run(printer, "G91" if relative else "G90", now)
    for line, pause, look in steps:
        now += pause
        if line == "reset":  # a new boot: what was not planned yet is gone with the rest
            general.reset(now)
            quick.reset(now)
            continue
        reply, after = run(general, line, now)
        move = plain_move(line)
        if not (move is not None and quick.move_at_once(move, now)):
            assert run(quick, line, now) == (reply, after)
        else:
            assert after == now and reply == Reply()
            quick.catch_up()  # as the session does once the `ok` is out
        now = after
        if look:
            assert planned(quick, now) == planned(general, now)
    assert planned(quick, now) == planned(general, now)
    assert quick.motion == general.motion


def planned(printer: Printer, now: float) -> list[Block]:
    """The moves planned and not finished at `now`."""
    printer.planner.moves(now)  # retires the finished ones
    return list(printer.planner._blocks)


def test_a_move_not_planned_yet_starts_where_the_move_before_it_ended():
    # Planned later than it arrived, a move still starts at the end of the move it followed,
    # even when that move has finished by the time the next one comes.
    quick = Printer()
    assert quick.move_at_once(plain_move("G1 X100 F6000"), 0.0)
    first = quick.planner._blocks[0]
    assert quick.move_at_once(plain_move("G1 X200"), 0.01)  # while the first still runs
    # The first has ended by the third's time, not the second:
    assert quick.move_at_once(plain_move("G1 X300"), first.end + 0.5)
    second, third = quick.planner._blocks
    assert (second.start, third.start) == (first.end, second.end)


@given(st.lists(st.tuples(st.floats(0, 0.05), st.floats(0.001, 0.05)), min_size=1, max_size=15),
       st.lists(st.floats(0.001, 0.05), max_size=5), st.floats(0, 0.2))
def test_a_batch_of_moves_leaves_the_planner_as_adding_them_one_by_one_would(
        steps, before, later):
    # A batch is added at its moves' own times; the blocks held after it, and the times
    # asked of the planner later, are those of one add() for each.
    moves, now = [], 0.05
    for gap, duration in steps[:MAX_MOVES - len(before)]:
        now += gap
        moves.append((now, duration, (0.0,), (float(len(moves)),)))
    one_by_one, batch = Planner(), Planner()
    for planner in (one_by_one, batch):
        for duration in before:  # moves planned earlier, some still running
            planner.add(0.0, duration, (0.0,), (0.0,))
    for move in moves:
        one_by_one.add(*move)
    batch.add_all(moves)
    assert list(batch._blocks) == list(one_by_one._blocks)
    at = now + later
    assert batch.next_change(at) == one_by_one.next_change(at)
    assert batch.drained_at(at) == one_by_one.drained_at(at)
    assert batch.room(at) == one_by_one.room(at)
