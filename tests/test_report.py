"""`fake-marlin report`: reading traces, the series and summary, the page, the command line."""

import gzip
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from fake_marlin.emulator.report import TraceError, read_trace, render_report, write_reports
from fake_marlin.emulator.report.series import MAX_BINS, bin_width, build_series
from fake_marlin.emulator.report.summary import summarise
from fake_marlin.emulator.report.wirelog import embed_json, log_rows, show_bytes
from tests.trace_samples import TraceBuilder, big_trace, marlin_print

pytest.importorskip("matplotlib", reason="the report needs the `report` extra (matplotlib)")

BIN = Path(sys.executable).parent
ROOT = Path(__file__).resolve().parent.parent


def fake_marlin(*args, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([BIN / "fake-marlin", *map(str, args)], capture_output=True, text=True,
                          timeout=120, env=env)


def job_of(trace: TraceBuilder) -> str:
    return "".join(r["c"] + "\n" for r in trace.records if r["k"] == "cmd")


# -- reading -------------------------------------------------------------------------------

def test_a_gzip_trace_reads_as_the_plain_one(tmp_path):
    sample = marlin_print()
    plain = read_trace(sample.write(tmp_path / "print.trace.jsonl"))
    packed = read_trace(sample.write(tmp_path / "print.trace.jsonl.gz"))
    assert packed.records == plain.records
    assert plain.records[-1] == plain.end and plain.begin["protocol"] == "marlin"
    assert packed.name == plain.name == "print"


def test_unknown_kinds_are_skipped_and_counted(tmp_path):
    sample = TraceBuilder()
    sample.cmd("G28").record("lasers", power=3).record("lasers", power=4).cmd("M105").end()
    trace = read_trace(sample.write(tmp_path / "t.jsonl"))
    assert [r["k"] for r in trace.records] == ["cmd", "cmd", "end"]
    assert trace.skipped == {"lasers": 2}
    assert "2 'lasers'" in " ".join(summarise(trace).notes)


def test_a_trace_without_its_end_record_is_read(tmp_path):
    sample = TraceBuilder().cmd("G28")
    trace = read_trace(sample.write(tmp_path / "t.jsonl"))
    assert trace.end is None
    assert "no end record" in summarise(trace).notes[0]


BEGIN = '{"t":0,"w":0,"k":"begin","version":1,"protocol":"marlin","planner":15}\n'
BAD_FILES = [
    # (what the file holds, the line named, words of the message)
    ("", None, "empty"),
    (BEGIN + '{"t":1,"w":0,"k":"cmd","c":"G28"}\n{"t":1,"k":"cmd", "c"\n', 3, "not JSON"),
    (BEGIN[:-10], 1, "ends in the middle of a record"),  # nothing whole to show
    ('{"t":0,"w":0,"k":"cmd","c":"G28"}\n', 1, "not a fake-marlin trace"),
    ('{"t":0,"w":0,"k":"begin","version":7}\n', 1, "trace version 7"),
    (BEGIN + '[1, 2]\n', 2, "not a JSON object"),
    (BEGIN + '{"w":0,"k":"cmd","c":"G28"}\n', 2, "without its time"),
    (BEGIN + '{"t":1,"w":0,"c":"G28"}\n', 2, "without its kind"),
    (BEGIN + '{"t":1,"w":0,"k":"temp","c":20,"s":0}\n', 2, "'h' is missing"),
    (BEGIN + '{"t":1,"w":0,"k":"room","v":"many"}\n', 2, "'v' is not a number"),
    (BEGIN + '{"t":1,"w":0,"k":"end"}\n{"t":1,"w":0,"k":"cmd","c":"G28"}\n', 3, "after the 'end'"),
    (BEGIN + '{"t":NaN,"w":0,"k":"cmd","c":"G28"}\n', 2, "at no real time"),
    (BEGIN + '{"t":Infinity,"w":0,"k":"cmd","c":"G28"}\n', 2, "at no real time"),
    (BEGIN + '{"t":5,"w":0,"k":"cmd","c":"G28"}\n{"t":-1e9,"w":0,"k":"cmd","c":"G1"}\n', 3,
     "time never goes back"),
    (BEGIN + '{"t":1,"w":0,"k":"verdict","passed":true,"host":3}\n', 2, "'host' is not an object"),
    (BEGIN + '{"t":1,"w":0,"k":"verdict","passed":true,"missing":"G1"}\n', 2, "not a list"),
]


@pytest.mark.parametrize("text, line, words", BAD_FILES)
def test_a_bad_trace_is_one_line_naming_the_file_and_line(tmp_path, text, line, words):
    path = tmp_path / "bad.jsonl"
    path.write_text(text)
    with pytest.raises(TraceError) as raised:
        read_trace(path)
    message = str(raised.value)
    assert "\n" not in message and words in message
    assert message.startswith(f"{path}:{line}:" if line else f"{path}:")


def test_bytes_that_are_no_utf8_are_named_by_line(tmp_path):
    path = tmp_path / "bad.jsonl"
    path.write_bytes(BEGIN.encode() + b'{"t":1,"w":0,"k":"cmd","c":"G\xff"}\n')
    with pytest.raises(TraceError, match=r"bad.jsonl:2: not UTF-8"):
        read_trace(path)


def test_a_gzip_trace_cut_short_shows_what_came_before_and_says_so(tmp_path):
    """A printer killed while writing its trace: its last records are the ones wanted most."""
    text = marlin_print().text()
    packed = gzip.compress(text.encode())
    path = tmp_path / "cut.jsonl.gz"
    path.write_bytes(packed[: len(packed) // 2])
    trace = read_trace(path)
    assert 0 < len(trace.records) < text.count("\n") - 1 and trace.end is None
    assert re.search(r"cut.jsonl.gz:\d+: the compressed file is cut short", trace.cut_short)
    assert "stops short" in summarise(trace).notes[0]


def test_a_plain_trace_cut_mid_record_shows_the_whole_records(tmp_path):
    path = tmp_path / "cut.jsonl"
    path.write_text(BEGIN + '{"t":1,"w":0,"k":"cmd","c":"G28"}\n{"t":2,"w":0,"k":"cmd","c":"G1')
    trace = read_trace(path)
    assert [r["c"] for r in trace.records] == ["G28"]
    assert trace.cut_short.startswith(f"{path}:3: the file ends in the middle of a record")


def test_a_missing_file_is_a_trace_error(tmp_path):
    with pytest.raises(TraceError, match="cannot read: No such file"):
        read_trace(tmp_path / "nowhere.jsonl")


# -- series and summary --------------------------------------------------------------------

def test_series_of_a_noisy_print(tmp_path):
    sample = marlin_print(moves=60, noise_every=17)
    series = build_series(read_trace(sample.write(tmp_path / "t.jsonl")))
    assert series.bin_seconds == 1.0 and series.planner == 15
    assert round(sum(series.rate) * series.bin_seconds) == sample.commands == 64
    # The planner fills (no room left) while the host streams, and drains at the end.
    assert min(series.room) == 0 and series.room[-1] == 15
    assert series.room.index(0) < len(series.room) - 15
    assert list(series.heaters) == ["T0", "B"]
    assert max(series.heaters["T0"].target) == 200 and series.heaters["T0"].target[-1] == 0
    faults = [r["t"] for r in sample.records if r["k"] == "fault"]
    assert [m.t for m in series.marks["resends"]] == faults and len(faults) == 3
    assert [m.t for m in series.marks["errors"]] == faults
    assert series.marks["errors"][0].label.startswith("Error:checksum mismatch")
    assert [m.label for m in series.marks["resets"]] == ["PowerUp", "External Reset"]
    assert len(series.marks["connects"]) == 1 and len(series.marks["fault: bit-errors"]) == 3


def test_an_error_line_split_across_chunks_is_one_mark(tmp_path):
    sample = TraceBuilder().printer("ok\nErr").at(2).printer("or:Printer halted\nok\n").end()
    trace = read_trace(sample.write(tmp_path / "t.jsonl"))
    assert [(m.t, m.label) for m in build_series(trace).marks["errors"]] == [(2, "Error:Printer halted")]
    assert summarise(trace).errors == 1


@pytest.mark.parametrize("seconds, width", [(0, 1), (600, 1), (601, 2), (3600, 10), (86400, 300)])
def test_commands_are_binned_to_at_most_600_bins(seconds, width):
    assert bin_width(seconds) == width


def test_summary_counts_what_went_wrong(tmp_path):
    sample = marlin_print(moves=60, noise_every=17)
    summary = summarise(read_trace(sample.write(tmp_path / "t.jsonl")))
    assert summary.title == "hand-made noisy print"
    assert (summary.commands, summary.resends, summary.errors) == (64, 3, 3)
    assert summary.resend_reasons == [("checksum mismatch", 3)]
    assert (summary.host_resends, summary.timeouts) == (3, 0)
    assert [(f.kind, f.fired, f.detail) for f in summary.faults] == [("bit-errors", 3, "3 bits flipped")]
    assert summary.resets == ["PowerUp", "External Reset"] and summary.connects == 1
    assert (summary.bytes_in, summary.bytes_out) == (sample.bytes_in, sample.bytes_out)
    verdict = summary.verdict
    assert verdict is not None and verdict.passed and verdict.scenario_passed
    assert (verdict.job, verdict.ran, verdict.source) == (64, 64, "the scenario run")


def test_a_live_trace_is_judged_against_a_job_given(tmp_path):
    sample = marlin_print(verdict=False)
    trace = read_trace(sample.write(tmp_path / "t.jsonl"))
    assert summarise(trace).verdict is None
    good = summarise(trace, job_of(sample), "print.gcode").verdict
    assert good is not None and good.passed and good.source == "print.gcode"
    longer = job_of(sample) + "G1 X99 Y99\n"
    bad = summarise(trace, longer, "print.gcode").verdict
    assert bad is not None and not bad.passed and bad.missing == ("G1 X99 Y99",)


def test_a_scenario_that_expects_lost_commands_passes_though_not_exactly_once(tmp_path):
    sample = TraceBuilder(scenario="halted").cmd("G28").at(3).record(
        "verdict", passed=True, outcome="failed", job=3, ran=1, exactly_once=False,
        missing=["G1 X1", "G1 X2"], duplicated=[], host={}, text="PASS  halted").end()
    trace = read_trace(sample.write(tmp_path / "halted.trace.jsonl"))
    verdict = summarise(trace).verdict
    assert verdict is not None and verdict.scenario_passed and not verdict.passed
    page = render_report(trace)
    assert '<section id="verdict" class="verdict pass">' in page
    assert "The scenario passed its checks</strong> (outcome: failed)" in page
    assert "Not exactly once:</strong> of 3 job commands, 2 missing, 0 duplicated" in page
    assert "missing: <code>G1 X1</code>, <code>G1 X2</code>" in page
    index = write_reports([tmp_path / "halted.trace.jsonl"], tmp_path / "out").read_text()
    assert '<td class="pass">passed</td><td>no: 2 missing, 0 duplicated</td>' in index


# -- the log and the page ------------------------------------------------------------------

def test_bytes_show_as_text_with_the_rest_escaped():
    assert show_bytes("N1 G28*18\r\n") == "N1 G28*18\\r\\n"
    assert show_bytes("\xff\xff\x00\x09G28\\") == "\\xff\\xff\\x00\\x09G28\\\\"


def test_embedded_json_cannot_end_its_script():
    text = embed_json(["</script><script>alert(1)</script>", "<!--"])
    assert "<" not in text and json.loads(text)[0].startswith("</script>")


def test_the_log_holds_every_record_in_order(tmp_path):
    sample = marlin_print()
    kinds, rows = log_rows(read_trace(sample.write(tmp_path / "t.jsonl")))
    assert len(rows) == len(sample.records)
    assert [kinds[row[1]] for row in rows] == [r["k"] for r in sample.records]
    assert rows[1][2] == "PowerUp"


def test_the_page_is_self_contained(tmp_path):
    page = render_report(read_trace(marlin_print().write(tmp_path / "t.jsonl")))
    assert page.startswith("<!DOCTYPE html>") and page.count("<svg") == 1
    # Nothing that loads: no src, no link to another file, no url() or @import in the style.
    loads = re.findall(r"""\bsrc\s*=|href\s*=\s*["']?(?!#|data:)[^"'\s>]+|url\((?!#)|@import""", page)
    assert loads == []
    assert "hand-made noisy print" in page and "Exactly once:" in page
    assert "<dc:date>" not in page


def test_a_trace_with_nothing_in_it_still_makes_a_page(tmp_path):
    page = render_report(read_trace(TraceBuilder().write(tmp_path / "empty.jsonl")))
    for empty in ("no commands were executed", "no planner samples", "no heater samples",
                  "nothing went wrong"):
        assert empty in page
    assert "Exactly once: not judged." in page


@pytest.mark.e2e
def test_the_same_trace_gives_the_same_page_in_another_process(tmp_path):
    """No date and no random ids: the bytes depend on the trace alone (the wall times are
    in the trace, so a second run's trace with other `w` differs only where they show)."""
    trace = marlin_print().write(tmp_path / "t.jsonl")
    pages = []
    for seed in ("1", "2"):
        out = tmp_path / f"r{seed}.html"
        done = fake_marlin("report", trace, "-o", out, env={**os.environ, "PYTHONHASHSEED": seed})
        assert done.returncode == 0, done.stderr
        pages.append(out.read_bytes())
    assert pages[0] == pages[1]


# e2e for its time alone: a trace at real size, whose 100,000 records take 2.5 s to make, read
# and draw.
@pytest.mark.e2e
def test_a_big_trace_makes_a_page_of_a_few_megabytes(tmp_path):
    trace = read_trace(big_trace(100_000).write(tmp_path / "big.jsonl.gz"))
    page = render_report(trace)
    assert len(trace.records) >= 99_999
    # The figure is thinned to what a screen shows; the log is the bulk, as data.
    figure = page[page.index("<svg"):page.index("</svg>")]
    assert len(figure) < 400_000
    assert len(page.encode()) < 8_000_000


def test_write_reports_writes_an_index(tmp_path):
    noisy = marlin_print().write(tmp_path / "noisy.trace.jsonl.gz")
    live = marlin_print(verdict=False).write(tmp_path / "live.trace.jsonl")
    broken = tmp_path / "broken.trace.jsonl"
    broken.write_text("nonsense\n")
    index = write_reports([noisy, live, broken], tmp_path / "out")
    assert index == tmp_path / "out" / "index.html"
    assert sorted(p.name for p in index.parent.iterdir()) == ["index.html", "live.html", "noisy.html"]
    text = index.read_text()
    assert 'href="noisy.html">hand-made noisy print</a>' in text
    assert '<td class="pass">passed</td><td>yes</td>' in text
    assert "3 traces: 1 passed, 0 failed, 1 unreadable" in text
    assert 'href="live.html">' in text and "no verdict" in text
    assert "unreadable" in text and "broken.trace.jsonl:1: not JSON" in text


# -- the command line ----------------------------------------------------------------------

@pytest.mark.e2e
def test_cli_writes_the_page_and_says_where(tmp_path):
    trace = marlin_print().write(tmp_path / "print.trace.jsonl")
    done = fake_marlin("report", trace, "-o", tmp_path / "page.html")
    assert done.returncode == 0 and done.stdout.strip() == str(tmp_path / "page.html")
    assert "<svg" in (tmp_path / "page.html").read_text()
    done = fake_marlin("report", trace)  # beside the trace, named after it
    assert done.returncode == 0 and (tmp_path / "print.html").exists()


@pytest.mark.e2e
def test_cli_judges_a_live_trace_against_its_job(tmp_path):
    sample = marlin_print(verdict=False)
    trace = sample.write(tmp_path / "live.jsonl")
    (tmp_path / "job.gcode").write_text("; the job\n" + job_of(sample))
    done = fake_marlin("report", trace, "--job", tmp_path / "job.gcode", "-o", tmp_path / "p.html")
    assert done.returncode == 0, done.stderr
    assert "Exactly once:</strong> each of the 64 job commands" in (tmp_path / "p.html").read_text()


@pytest.mark.e2e
@pytest.mark.parametrize("case", ["bad trace", "no trace", "no job", "unwritable"])
def test_cli_problems_are_one_line_and_exit_2(tmp_path, case):
    trace = marlin_print().write(tmp_path / "t.jsonl")
    args = {
        "bad trace": [tmp_path / "bad.jsonl"],
        "no trace": [tmp_path / "missing.jsonl"],
        "no job": [trace, "--job", tmp_path / "missing.gcode"],
        "unwritable": [trace, "-o", tmp_path / "no" / "such" / "dir.html"],
    }[case]
    (tmp_path / "bad.jsonl").write_text(BEGIN + "{oops\n")
    done = fake_marlin("report", *args)
    assert done.returncode == 2
    assert done.stderr.startswith("fake-marlin report: ") and done.stderr.count("\n") == 1
    assert "Traceback" not in done.stderr


@pytest.mark.e2e
@pytest.mark.parametrize("stand_in, reason", [
    ("raise ModuleNotFoundError(\"No module named 'matplotlib'\", name='matplotlib')",
     "which is not installed"),
    ("raise ImportError('libfreetype.so.6: cannot open')",
     "which does not load (libfreetype.so.6: cannot open)"),
])
def test_cli_without_matplotlib_says_how_to_install_it(tmp_path, stand_in, reason):
    # A stand-in for matplotlib, found first, that cannot be imported: as if the extra were
    # not installed, or installed broken.
    blocker = tmp_path / "blocker" / "matplotlib"
    blocker.mkdir(parents=True)
    (blocker / "__init__.py").write_text(stand_in + "\n")
    env = {**os.environ, "PYTHONPATH": str(blocker.parent)}
    done = fake_marlin("report", marlin_print().write(tmp_path / "t.jsonl"), env=env)
    assert done.returncode == 2
    assert done.stderr == f"fake-marlin report: reports need matplotlib, {reason}: " \
                          "pip install 'fake-marlin[report]'\n"


# -- a real trace --------------------------------------------------------------------------

@pytest.mark.e2e
def test_the_noisy_um3_scenario_shows_its_resends_and_planner(tmp_path):
    trace_path = tmp_path / "um3.trace.jsonl.gz"
    done = fake_marlin("scenario", "run", ROOT / "scenarios" / "um3-noisy-serial.toml",
                       "--trace", trace_path)
    assert done.returncode == 0, done.stdout + done.stderr
    trace = read_trace(trace_path)
    series, summary = build_series(trace), summarise(trace)
    faults = [r["t"] for r in trace.records if r["k"] == "fault" and r.get("dir") == "to-printer"]
    resends = [m.t for m in series.marks["resends"]]
    assert resends and summary.resends == len(resends)
    # Every resend follows a bit flipped on the way to the printer, within a few (simulated)
    # seconds: the report shows them where the noise hit.
    assert all(any(0 <= t - fault < 5.0 for fault in faults) for t in resends)
    # The planner fills to its last block and drains to empty once the job is sent.
    assert min(series.room) <= 1 and series.room[-1] == series.planner == 15
    assert summary.verdict is not None and summary.verdict.passed
    assert summary.faults[0].kind == "bit-errors"


@pytest.mark.e2e
def test_scenario_run_report_writes_a_page_per_scenario_and_an_index(tmp_path):
    out = tmp_path / "reports"
    names = ["marlin-cable-unplugged", "marlin-lost-oks"]
    done = fake_marlin("scenario", "run", *(ROOT / "scenarios" / f"{n}.toml" for n in names),
                       "--report", out)
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"reports: {out / 'index.html'}\n" in done.stdout
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["index.html", *(f"{n}.html" for n in names), *(f"{n}.trace.jsonl.gz" for n in names)])
    index = (out / "index.html").read_text()
    assert "2 traces: 2 passed, 0 failed" in index
    assert 'href="marlin-cable-unplugged.html">' in index and "no: " in index  # the host gave up
    assert "Marlin: lost oks" in (out / "marlin-lost-oks.html").read_text()


@pytest.mark.e2e
def test_scenario_run_report_problems_are_one_line(tmp_path):
    (tmp_path / "taken").write_text("a file")
    scenario = ROOT / "scenarios" / "marlin-lost-oks.toml"
    done = fake_marlin("scenario", "run", scenario, "--report", tmp_path / "taken")
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.startswith(f"fake-marlin scenario: --report {tmp_path / 'taken'}: cannot make")
    blocker = tmp_path / "blocker" / "matplotlib"
    blocker.mkdir(parents=True)
    (blocker / "__init__.py").write_text(
        "raise ModuleNotFoundError(\"No module named 'matplotlib'\", name='matplotlib')\n")
    done = fake_marlin("scenario", "run", scenario, "--report", tmp_path / "out",
                       env={**os.environ, "PYTHONPATH": str(blocker.parent)})
    assert done.returncode == 2 and done.stdout == "" and not (tmp_path / "out").exists()
    assert "pip install 'fake-marlin[report]'" in done.stderr and done.stderr.count("\n") == 1


def test_a_trace_of_years_still_makes_a_page_of_few_bins(tmp_path):
    path = tmp_path / "long.jsonl"
    path.write_text(BEGIN + '{"t":1,"w":0,"k":"cmd","c":"G28"}\n{"t":1e15,"w":0,"k":"cmd","c":"G1"}\n')
    series = build_series(read_trace(path))
    assert 1 < len(series.rate) <= MAX_BINS + 1
