"""The printer model on its own: simulated time goes in, replies come out."""

import pytest

from emulator.printer.model import Printer, Reply, Sleep


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


def test_m105_reports_in_marlins_format():
    reply, _ = run(Printer(), "M105", 0.0)
    assert reply == Reply(ok_suffix="T:21.00 /0.00 B:21.00 /0.00 @:0 B@:0")


def test_m114_reports_in_marlins_format():
    printer = Printer()
    run(printer, "G1 X10 Y20.5 Z0.3 E1 F3000", 0.0)
    reply, _ = run(printer, "M400", 0.0)
    reply, _ = run(printer, "M114", 100.0)
    assert reply.lines == ("X:10.00 Y:20.50 Z:0.30 E:1.00 Count X:800 Y:1640 Z:120",)


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
    assert run(Printer(), "M9999 S1", 0.0)[0].lines == ('echo:Unknown command: "M9999 S1"',)
    assert run(Printer(), "FOO", 0.0)[0].lines == ('echo:Unknown command: "FOO"',)
    assert run(Printer(), "; only a comment", 0.0)[0] == Reply()


def test_heaters_warm_toward_target_and_report_it():
    printer = Printer()
    run(printer, "M104 S200", 0.0)
    run(printer, "M140 S60", 0.0)
    early, _ = run(printer, "M105", 10.0)
    late, _ = run(printer, "M105", 600.0)
    assert early.ok_suffix.startswith("T:6") and "@:127" in early.ok_suffix
    assert late.ok_suffix.startswith("T:200.00 /200.00 B:60.00 /60.00")


def test_reset_stops_motion_and_heaters_but_not_physics():
    printer = Printer()
    run(printer, "M104 S200", 0.0)
    run(printer, "G1 X100 F600", 0.0)
    printer.reset(30.0)
    assert printer.room(30.0) == 15 and printer.motion.position == [0.0] * 4
    reply, _ = run(printer, "M105", 30.0)
    assert reply.ok_suffix.startswith("T:1") and "/0.00" in reply.ok_suffix
