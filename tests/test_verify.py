"""`fake-marlin verify`: a job's commands against a journal, as sequences."""

import dataclasses
import itertools
import json
import random
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import fake_marlin.emulator.journal.verify as verify_module
from fake_marlin.emulator.cli.verify import report
from fake_marlin.emulator.journal.verify import Kind, job_commands, verify

MISSING, DUPLICATED, REORDERED, EXTRA = Kind.MISSING, Kind.DUPLICATED, Kind.REORDERED, Kind.EXTRA
DAMAGED = Kind.DAMAGED
BIN = Path(sys.executable).parent

# Job lines 2, 4, 5, 6, 7; line 1 is a comment and line 3 blank.
JOB = ["; a job", "G28", "", "G1 X1 ; first move", "G1 X2", "G92 E0", "G1 X3"]
RUN = ["G28", "G1 X1", "G1 X2", "G92 E0", "G1 X3"]
MOVES = [f"G1 X{n}" for n in range(1, 13)]


def problems(job: list[str], journal: list[str]) -> list[tuple]:
    result = verify(job_commands("\n".join(job)), journal)
    return [(p.kind, p.job_line, p.journal_line) for p in result.problems]


@pytest.mark.parametrize("job, journal, expected", [
    pytest.param(JOB, RUN, [], id="exact run"),
    pytest.param(JOB, RUN[:2] + RUN[3:], [(MISSING, 5, None)], id="missing"),
    pytest.param(JOB, RUN[:2] + ["G1 X1"] + RUN[2:], [(DUPLICATED, 4, 3)], id="duplicated in a row"),
    pytest.param(JOB, RUN[:4] + ["G1 X1"] + RUN[4:], [(DUPLICATED, 4, 5)], id="duplicated later"),
    pytest.param(JOB, RUN + RUN, [(DUPLICATED, n, k) for n, k in zip((2, 4, 5, 6, 7), range(6, 11))],
                 id="the whole job twice"),
    pytest.param(MOVES, MOVES[:9] + [MOVES[10], MOVES[9]] + MOVES[11:], [(REORDERED, 10, 11)],
                 id="lines 10 and 11 swapped"),
    pytest.param(MOVES, MOVES[1:5] + MOVES[:1] + MOVES[5:], [(REORDERED, 1, 5)], id="one moved later"),
    pytest.param(
        JOB, ["M110 N0", "M115", "M105", "M113 S2", *RUN[:3], "M105", *RUN[3:], "M400"],
        [(EXTRA, None, 1), (EXTRA, None, 2), (EXTRA, None, 3), (EXTRA, None, 4), (EXTRA, None, 8),
         (EXTRA, None, 11)],
        id="OctoPrint's extras"),
    pytest.param(JOB, ["M105", "M110 N-1", *RUN], [(EXTRA, None, 1), (EXTRA, None, 2)],
                 id="printcore's extras"),
    pytest.param(JOB, RUN[:2] + ["M1O5"] + RUN[2:], [(EXTRA, None, 3)], id="garbage"),
    pytest.param(["G28", "M105", "G1 X1", "M400"], ["G28", "M105", "M105", "G1 X1", "M400", "M400"],
                 [(EXTRA, None, 3), (EXTRA, None, 6)], id="host commands also in the job"),
    pytest.param(["G28", "M105", "G1 X1"], ["G28", "G1 X1"], [(MISSING, 2, None)],
                 id="a host command of the job missing"),
    pytest.param(
        ["G92 E0", "G1 X1", "G92 E0", "G1 X2", "G92 E0", "G1 X3"],
        ["G92 E0", "G1 X1", "G1 X2", "G92 E0", "G1 X3"],
        [(MISSING, 3, None)], id="which repeat is missing"),
    pytest.param(
        ["M106 S255", "G1 X1", "M106 S255", "G1 X2"],
        ["M106 S255", "G1 X1", "M106 S255", "G1 X2", "M106 S255"],
        [(DUPLICATED, 3, 5)], id="a repeat ran again later"),
    # difflib.SequenceMatcher explains this as line 1 reordered and line 2 missing.
    pytest.param(["G1 X1", "G1 X2", "G1 X1", "G1 X1"], ["G1 X1", "G1 X1", "G1 X1"],
                 [(MISSING, 2, None)], id="repeats around a missing line"),
    pytest.param(["G1 X1"] * 3, ["G1 X1"] * 3, [], id="identical lines, each once"),
    pytest.param(["G1 X1"] * 3, ["G1 X1"] * 4, [(DUPLICATED, 3, 4)], id="identical lines, one twice"),
    pytest.param(["G1 X1"] * 3, ["G1 X1"] * 2, [(MISSING, 3, None)], id="identical lines, one lost"),
    pytest.param([], [], [], id="empty job, empty journal"),
    pytest.param(["; only comments", ""], ["M105"], [(EXTRA, None, 1)], id="empty job"),
    pytest.param(JOB, [], [(MISSING, n, None) for n in (2, 4, 5, 6, 7)], id="empty journal"),
    pytest.param(JOB, ["", " G28\r", *RUN[1:], ""], [], id="blank lines and CRLF in the journal"),
    pytest.param(JOB, ["G28", "", "G1 X2"], [(MISSING, 4, None), (MISSING, 6, None),
                                             (MISSING, 7, None)], id="journal lines keep their numbers"),
    # A binary protocol brings commands back in its own spelling (found by fuzzing).
    pytest.param(["T00", "M0117 Hi", "M117  Hi there", "M23 part.gco"],
                 ["T0", "M117 Hi", "M117 Hi there", "M23  part.gco"], [], id="one spelling"),
    pytest.param(["M117 Hi  there"], ["M117 Hi there"], [(DAMAGED, 1, 1)],
                 id="a message's own spaces count"),
])
def test_cases(job, journal, expected):
    assert problems(job, journal) == expected


def test_extras_fail_only_when_strict():
    result = verify(job_commands("\n".join(JOB)), ["M110 N0", *RUN, "M400"])
    assert result.passed() and not result.passed(strict=True)
    assert result.count(EXTRA) == 2 and result.failures() == ()
    assert [p.command for p in result.failures(strict=True)] == ["M110 N0", "M400"]
    assert (result.job_commands, result.journal_commands) == (5, 7)
    with pytest.raises(dataclasses.FrozenInstanceError):
        result.approximate = True


def test_problems_come_in_journal_order_a_missing_one_where_it_was_due():
    journal = ["G28", "G1 X2", "G1 X1", "M105", "G92 E0", "G92 E0"]
    assert problems(JOB, journal) == [
        (REORDERED, 4, 3), (EXTRA, None, 4), (MISSING, 7, None), (DUPLICATED, 6, 6),
    ]


# --- properties -------------------------------------------------------------------------------

commands = st.one_of(
    st.sampled_from(["G92 E0", "M106 S255", "G1 E-0.8 F2100", "G1 X1", "G1 X2"]),
    st.integers(0, 30).map(lambda n: f"G1 X{n} Y{n}"),
)
host_extras = st.sampled_from(
    ["M110 N0", "M115", "M105", "M113 S2", "M400", "M110 N-1", "M1O5", "G1 X1 Y", "N7G1*"]
)


@st.composite
def jobs(draw, commands=commands, min_size=0):
    """(line number, command) pairs, the numbers with gaps as comments and blank lines make."""
    texts = draw(st.lists(commands, min_size=min_size, max_size=40))
    gaps = draw(st.lists(st.integers(1, 3), min_size=len(texts), max_size=len(texts)))
    return list(zip(itertools.accumulate(gaps), texts))


def texts_of(job):
    return [command for _, command in job]


def without_line(job, line):
    return [command for number, command in job if number != line]


@given(jobs(st.one_of(commands, st.sampled_from(["M105", "M400"]))), st.data())
def test_a_journal_with_host_extras_inserted_verifies_clean(job, data):
    journal = texts_of(job)
    extras = data.draw(st.lists(st.tuples(st.integers(0, len(journal)), host_extras), max_size=10))
    for position, extra in extras:
        journal.insert(position, extra)
    result = verify(job, journal)
    assert result.passed(), result.problems
    assert result.count(EXTRA) == len(extras)
    assert result.passed(strict=True) == (not extras)


@given(jobs(min_size=1), st.data())
def test_a_deleted_command_is_reported_missing_at_its_line(job, data):
    i = data.draw(st.integers(0, len(job) - 1))
    journal = texts_of(job)
    del journal[i]
    (problem,) = verify(job, journal).problems
    assert problem.kind is MISSING and problem.command == job[i][1]
    # With repeats, any of the same command whose loss explains the journal is right.
    assert without_line(job, problem.job_line) == journal
    if texts_of(job).count(job[i][1]) == 1:
        assert problem.job_line == job[i][0]


@given(jobs(min_size=1), st.data())
def test_a_command_run_again_is_reported_duplicated_with_its_line(job, data):
    i = data.draw(st.integers(0, len(job) - 1))
    position = data.draw(st.integers(i + 1, len(job)))  # right after it, or any time later
    journal = texts_of(job)
    journal.insert(position, job[i][1])
    (problem,) = verify(job, journal).problems
    assert problem.kind is DUPLICATED and problem.command == job[i][1]
    assert dict(job)[problem.job_line] == job[i][1]
    assert journal[:problem.journal_line - 1] + journal[problem.journal_line:] == texts_of(job)
    if texts_of(job).count(job[i][1]) == 1:
        assert problem.job_line == job[i][0]


@given(jobs(min_size=2), st.data())
def test_two_swapped_commands_are_reported_reordered(job, data):
    i = data.draw(st.integers(0, len(job) - 2))
    journal = texts_of(job)
    journal[i], journal[i + 1] = journal[i + 1], journal[i]
    result = verify(job, journal)
    if journal == texts_of(job):
        assert result.problems == ()
        return
    (problem,) = result.problems
    assert problem.kind is REORDERED
    assert without_line(job, problem.job_line) == (
        journal[:problem.journal_line - 1] + journal[problem.journal_line:])
    if texts_of(job).count(job[i][1]) == texts_of(job).count(job[i + 1][1]) == 1:
        assert problem.job_line in (job[i][0], job[i + 1][0])


@settings(max_examples=300)
@given(jobs(), st.lists(st.one_of(commands, host_extras), max_size=40))
def test_every_job_command_and_journal_line_is_accounted_for(job, journal):
    result = verify(job, journal)
    commands = dict(job)
    for problem in result.problems:
        if problem.job_line is not None:
            assert commands[problem.job_line] == problem.command
        if problem.journal_line is not None:
            ran_as = problem.ran_as if problem.kind is DAMAGED else problem.command
            assert journal[problem.journal_line - 1] == ran_as
    damaged = result.count(DAMAGED)
    in_place = len(job) - result.count(MISSING) - result.count(REORDERED) - damaged
    ran = in_place + result.count(REORDERED) + result.count(DUPLICATED) + result.count(EXTRA)
    assert ran + damaged == len(journal) == result.journal_commands
    assert not result.approximate
    # As many run in place as any alignment could manage: an exact longest common subsequence.
    runs = [command for command in journal if command in commands.values()]
    assert in_place == longest_common_subsequence(texts_of(job), runs)


def test_a_command_changed_where_it_was_due_ran_damaged_not_missing():
    job = job_commands("G28\nG1 X37 Y4 F6000\nG1 X1\nM400\n")
    # '3' -> '1' and '7' -> '5': the same bit of two characters, which XOR cannot see.
    (problem,) = verify(job, ["G28", "G1 X15 Y4 F6000", "G1 X1", "M400"]).problems
    assert (problem.kind, problem.job_line, problem.journal_line) == (DAMAGED, 2, 2)
    assert problem.ran_as == "G1 X15 Y4 F6000"
    assert not verify(job, ["G28", "G1 X15 Y4 F6000", "G1 X1", "M400"]).passed()
    assert verify(job, ["G28", "G1 X15 Y4 F6000", "G1 X1", "M400"]).passed(allow_undetectable=True)


def test_a_line_cut_short_at_a_damaged_star_ran_damaged():
    """`N67 G1 X65 Y65 E48.80 F3000*50` with `.` -> `*` and `F` -> `B` (one bit, twice) passes
    the XOR checksum, and Marlin runs it up to the first `*`."""
    job = job_commands("G1 X64 Y84 E48.00 F3000\nG1 X65 Y65 E48.80 F3000\nG1 X85 Y65\n")
    journal = ["G1 X64 Y84 E48.00 F3000", "G1 X65 Y65 E48", "G1 X85 Y65"]
    (problem,) = verify(job, journal).problems
    assert (problem.kind, problem.job_line, problem.ran_as) == (DAMAGED, 2, "G1 X65 Y65 E48")
    # N516 G1$X77 Y57 E408*00 F3000*59: a space and a `.`, one bit each, in the same bit.
    journal = ["G1 X64 Y84 E48.00 F3000", "G1$X65 Y65 E48", "G1 X85 Y65"]
    (problem,) = verify(job, journal).problems
    assert (problem.kind, problem.job_line) == (DAMAGED, 2)


def test_a_line_shortened_by_drops_whose_xors_cancel_ran_damaged():
    """Campaign 2032, case 448: `G1 X74 Y94 E80.00 F3000` lost a `4`, had a `0` flipped to `4`
    and lost a `0` (0x34 ^ 0x04 ^ 0x30 = 0: XOR cannot see it), and ran as `G1 X74 Y9 E80.4`.
    Shorter, but no line cut at a damaged `*`: it ran damaged, it was not lost."""
    job = job_commands("G1 X54 Y94 E79.20 F3000\nG1 X74 Y94 E80.00 F3000\nG1 X74 Y74\n")
    journal = ["G1 X54 Y94 E79.20 F3000", "G1 X74 Y9 E80.4 F3000", "G1 X74 Y74"]
    (problem,) = verify(job, journal).problems
    assert (problem.kind, problem.job_line, problem.ran_as) == (DAMAGED, 2, "G1 X74 Y9 E80.4 F3000")


def test_a_line_whose_space_after_its_number_flipped_ran_damaged():
    """`N464!G1 X104 Y84 E366.40 G3000*15`: a space and an F, each one bit off, in the same bit."""
    job = job_commands("G1 X84 Y84\nG1 X104 Y84 E366.40 F3000\nG1 X104 Y104\n")
    journal = ["G1 X84 Y84", "!G1 X104 Y84 E366.40 G3000", "G1 X104 Y104"]
    (problem,) = verify(job, journal).problems
    assert (problem.kind, problem.job_line) == (DAMAGED, 2)


def test_something_else_where_a_command_was_due_is_no_damage():
    job = job_commands("G1 X2 Y2\nG1 X5\nM400\n")
    kinds = [p.kind for p in verify(job, ["G1 X9 Y9 Z9 E9", "G1 X5", "M400"]).problems]
    assert kinds == [MISSING, EXTRA]
    kinds = [p.kind for p in verify(job, ["G1", "G1 X5", "M400"]).problems]
    assert kinds == [MISSING, EXTRA]


def test_a_changed_copy_far_from_where_it_was_due_is_no_damage():
    job = job_commands("G28\nG1 X37 Y4 F6000\nG1 X1\nM400\n")
    kinds = [p.kind for p in verify(job, ["G28", "G1 X1", "M400", "G1 X15 Y4 F6000"]).problems]
    assert kinds == [MISSING, EXTRA]


def longest_common_subsequence(a, b):
    lengths = [[0] * (len(b) + 1) for _ in range(len(a) + 1)]
    for i, j in itertools.product(range(len(a)), range(len(b))):
        lengths[i + 1][j + 1] = (lengths[i][j] + 1 if a[i] == b[j]
                                 else max(lengths[i][j + 1], lengths[i + 1][j]))
    return lengths[-1][-1]


def test_past_max_edits_anchors_split_the_work_and_only_a_foreign_stretch_is_rough(monkeypatch):
    monkeypatch.setattr(verify_module, "MAX_EDITS", 3)
    job = [(n, f"G1 X{n}") if n % 3 else (n, "G92 E0") for n in range(1, 61)]
    run = [command for number, command in job if number not in (5, 17, 29, 41, 53)]
    result = verify(job, run)
    assert [(p.kind, p.job_line) for p in result.problems] == [(MISSING, n) for n in (5, 17, 29, 41, 53)]
    assert not result.approximate
    # A stretch run backwards has more than 3 differences: only that stretch is a rough guess.
    rough = verify(job, run[:20] + run[20:35][::-1] + run[35:])
    assert rough.approximate and not rough.passed()
    assert [(p.kind, p.job_line) for p in rough.problems[:2] + rough.problems[-2:]] == [
        (MISSING, 5), (MISSING, 17), (MISSING, 41), (MISSING, 53)]
    assert "rough guess" in report(rough)


# --- size -------------------------------------------------------------------------------------

def slicer_job(lines: int) -> list[str]:
    """Like a slicer's output: unique moves, and per layer the same few commands again."""
    rng = random.Random(0)
    job = ["M140 S60", "M104 S200", "G28", "M190 S60", "M109 S200"]
    for layer in range(1, lines):
        job += [f";LAYER:{layer}", "G92 E0", "M106 S255", f"G1 Z{layer * 0.2:.2f} F600"]
        for n in range(rng.randint(50, 300)):
            if rng.random() < 0.1:
                job += ["G1 E-0.8 F2100", f"G0 X{rng.uniform(0, 200):.3f} Y{rng.uniform(0, 200):.3f}",
                        "G1 E0 F2100"]
            job.append(f"G1 X{rng.uniform(0, 200):.3f} Y{rng.uniform(0, 200):.3f} E{n * 0.05:.3f}")
        if len(job) >= lines:
            return job[:lines - 2] + ["M400", "M84"]


# e2e for its time alone: a job at real size, whose 100,000 lines take 3 s to spell one way.
@pytest.mark.e2e
def test_a_100k_line_job_with_host_polls_and_three_faults():
    job = job_commands("\n".join(slicer_job(100_000)))
    run = [command for _, command in job]
    lost, repeated = run[50_000], run[70_000]
    del run[50_000]
    run.insert(70_000, repeated)
    run[10], run[11] = run[11], run[10]
    journal = ["M110 N0", "M115"]
    for n, command in enumerate(run):
        journal += [command, "M105"] if n % 100 == 99 else [command]
    journal.append("M400")
    result = verify(job, journal)
    failures = result.failures()
    assert [p.kind for p in failures] == [REORDERED, MISSING, DUPLICATED]
    assert failures[1].command == lost and failures[1].job_line == job[50_000][0]
    assert failures[2].command == repeated
    assert result.count(EXTRA) == 3 + len(run) // 100
    assert not result.approximate


# --- the console script -----------------------------------------------------------------------

def fake_marlin(*args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [BIN / "fake-marlin", "verify", *map(str, args)], capture_output=True, text=True, timeout=60
    )


@pytest.mark.e2e
def test_the_console_script(tmp_path):
    job = tmp_path / "job.gcode"
    job.write_text("\n".join(JOB) + "\n")
    good = tmp_path / "good.log"
    good.write_text("\n".join(["M110 N0", *RUN, "M105"]) + "\n")
    bad = tmp_path / "bad.log"
    bad.write_text("\n".join(RUN[:2] + RUN[3:] + ["G1 X3"]) + "\n")

    ok = fake_marlin(job, good)
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.startswith("OK: each of the 5 job commands ran once, in order\n")
    assert "2 extra" in ok.stdout and ok.stderr == ""
    strict = fake_marlin(job, good, "--strict")
    assert strict.returncode == 1
    assert "extra       journal line 1, not the job's: M110 N0" in strict.stdout

    failed = fake_marlin(job, bad)
    assert failed.returncode == 1
    assert failed.stdout.splitlines() == [
        "FAILED: 1 missing, 1 duplicated, 0 reordered",
        "  missing     job line 5 never ran: G1 X2",
        "  duplicated  job line 7 ran again at journal line 5: G1 X3",
    ]
    as_json = fake_marlin(job, bad, "--json")
    assert as_json.returncode == 1
    summary = json.loads(as_json.stdout)
    assert summary["ok"] is False and summary["counts"]["missing"] == 1
    assert summary["problems"][0] == {
        "kind": "missing", "job_line": 5, "journal_line": None, "command": "G1 X2"
    }

    undecodable = tmp_path / "latin1.gcode"
    undecodable.write_bytes(b"G28\nM117 \xe9t\xe9\n")
    for args, message in [
        ((tmp_path / "absent.gcode", good), "cannot read"),
        ((job, tmp_path), "Is a directory"),
        ((undecodable, good), "latin1.gcode:2: not UTF-8 text"),
        ((job,), "required"),
    ]:
        error = fake_marlin(*args)
        assert error.returncode == 2 and error.stdout == ""
        assert message in error.stderr and "Traceback" not in error.stderr
    assert len(fake_marlin(job, tmp_path).stderr.splitlines()) == 1
