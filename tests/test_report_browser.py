"""A `fake-marlin report` page in a real browser: Debian's Chromium, headless, driven by
playwright-core (tests/hosts/report_page_driver.js), as a person would open it from disk.

It must load with no console errors and fetch nothing, show its figure, and filter the wire
log as one types in the search box; ticking kinds and clicking a record's time must work too.
Chromium comes from Debian's packages (tests/hosts/apt.py) and playwright-core from npm into the
cache outside the checkout (tests/hosts/npm.py), both installed by `python -m
tests.hosts.install`; no browser is downloaded. Where either is missing, the tests skip and
name that command.
"""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from fake_marlin.emulator.report import read_trace
from tests.hosts import apt, npm
from tests.trace_samples import big_trace

pytest.importorskip("matplotlib", reason="the report needs the `report` extra (matplotlib)")
pytestmark = pytest.mark.e2e

ROOT = Path(__file__).resolve().parent.parent
FAKE_MARLIN = Path(sys.executable).parent / "fake-marlin"
DRIVER = Path(__file__).parent / "hosts" / "report_page_driver.js"
DRIVER_TIMEOUT = 180


def open_page(browser, page: Path, screenshot: Path, search: str) -> dict:
    install, chromium = browser
    command = [install.node, str(DRIVER), str(page), str(screenshot), search, chromium]
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=DRIVER_TIMEOUT,
                              cwd=install.path, env={"NODE_PATH": str(install.path / "node_modules"),
                                                     "PATH": "/usr/bin:/bin", "HOME": str(Path.home())})
    except subprocess.TimeoutExpired:
        pytest.fail(f"the browser did not finish with the page in {DRIVER_TIMEOUT} s")
    if done.returncode != 0:
        pytest.fail(f"report_page_driver.js exited {done.returncode}:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def shown(count_text: str) -> int:
    """How many records the page says it shows: `records 1–88 of 88 shown (...)`."""
    found = re.search(r"of ([\d,]+) shown", count_text)
    assert found, count_text
    return int(found.group(1).replace(",", ""))


def png_size(path: Path) -> tuple[int, int]:
    header = path.read_bytes()[:24]
    assert header[:8] == b"\x89PNG\r\n\x1a\n"
    return int.from_bytes(header[16:20], "big"), int.from_bytes(header[20:24], "big")


def report(trace: Path, page: Path) -> None:
    done = subprocess.run([FAKE_MARLIN, "report", trace, "-o", page], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr


def test_the_noisy_um3_report_reads_in_a_browser(browser, tmp_path):
    trace = tmp_path / "um3.trace.jsonl.gz"
    run = subprocess.run([FAKE_MARLIN, "scenario", "run", ROOT / "scenarios" / "um3-noisy-serial.toml",
                          "--trace", trace], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    report(trace, tmp_path / "um3.html")
    seen = open_page(browser, tmp_path / "um3.html", tmp_path / "um3.png", "Resend")

    assert seen["console_errors"] == [] and seen["requests"] == []
    assert seen["title"].startswith("UM3 noisy serial line")
    assert seen["verdict"].startswith("✓ The scenario passed its checks (outcome: completed).")
    assert "Exactly once: each of the 1,510 job commands ran once, in order" in seen["verdict"]
    assert seen["cards"] == 7
    # The figure is there, drawn, and as wide as the page's column.
    assert seen["svgs"] == 1 and seen["svg_paths"] > 50 and seen["svg_box"]["width"] > 1000
    # The log shows a page of rows, of the conversation (no room or heater samples by default).
    assert seen["rows_before"] == 200
    assert dict(seen["kinds"]) | {"room": False, "temp": False} == dict(seen["kinds"])
    # Typing in the search box leaves the rows that hold the text, and marks it in each.
    after = shown(seen["count_after"])
    assert 0 < after < shown(seen["count_before"]) and seen["rows_after"] == after
    assert all("resend" in text.lower() for text in seen["texts_after"])
    assert seen["marks_after"] >= after
    # With only `reject` ticked, the rows are the printer's refusals, as many as it made.
    assert set(seen["kinds_only_reject"]) == {"reject"}
    rejects = sum(r["k"] == "reject" for r in read_trace(trace).records)
    assert shown(seen["count_only_reject"]) == rejects > 0
    # A click on a refusal's time shows it among what was said before and after it.
    assert seen["context_target"] == ["reject"]
    assert {"in", "out", "cmd", "fault", "reject"} <= set(seen["context_kinds"])
    width, height = png_size(tmp_path / "um3.png")
    assert width == 1400 and height > 2000


def test_a_report_of_100000_records_stays_usable(browser, tmp_path):
    trace = big_trace(100_000).write(tmp_path / "long.trace.jsonl.gz")
    report(trace, tmp_path / "long.html")
    seen = open_page(browser, tmp_path / "long.html", tmp_path / "long.png", "N4242 ")

    assert seen["console_errors"] == []
    assert seen["svgs"] == 1
    assert seen["rows_before"] == 200  # one page of rows in the document, not 100,000
    assert "in the trace" in seen["count_before"] and "100,0" in seen["count_before"]
    assert shown(seen["count_after"]) == seen["rows_after"] == 1
    assert seen["texts_after"][0].startswith("N4242 G1")
    assert set(seen["kinds_only_reject"]) == {"reject"}
