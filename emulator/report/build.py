"""A trace to a report page, and many traces to reports with an index page linking them.

Needs matplotlib (the `report` extra); MissingPlotting says how to get it.
"""

from dataclasses import dataclass
from html import escape
from pathlib import Path

from fake_marlin.emulator.report.assets import STYLE
from fake_marlin.emulator.report.reader import Trace, TraceError, read_trace
from fake_marlin.emulator.report.series import build_series
from fake_marlin.emulator.report.summary import Summary, summarise
from fake_marlin.emulator.report.wirelog import log_rows

INSTALL_HINT = "pip install 'fake-marlin[report]'"


class MissingPlotting(RuntimeError):
    """matplotlib is not installed: str() says in one line how to install it."""


def require_plotting() -> None:
    try:
        import matplotlib  # noqa: F401
    except ImportError as error:  # ModuleNotFoundError too, for matplotlib or what it needs
        missing = isinstance(error, ModuleNotFoundError) and error.name == "matplotlib"
        why = "which is not installed" if missing else f"which does not load ({error})"
        raise MissingPlotting(f"reports need matplotlib, {why}: {INSTALL_HINT}") from None


def render_report(trace: Trace, job: str | None = None, job_name: str = "the job") -> str:
    """The HTML page for one trace; `job`: the G-code it ran, to judge exactly-once by."""
    return _render(trace, summarise(trace, job, job_name))


def _render(trace: Trace, summary: Summary) -> str:
    require_plotting()
    from fake_marlin.emulator.report.page import render_page
    from fake_marlin.emulator.report.plots import figure_svg

    svg = figure_svg(build_series(trace))
    kinds, rows = log_rows(trace)
    return render_page(summary, svg, kinds, rows, trace.path.name)


def write_report(trace_path: Path, out: Path, job: str | None = None, job_name: str = "the job") -> Summary:
    """Read the trace, write its page to `out`; TraceError if the trace cannot be read, OSError
    if the page cannot be written."""
    trace = read_trace(trace_path)
    summary = summarise(trace, job, job_name)
    out.write_text(_render(trace, summary), encoding="utf-8")
    return summary


@dataclass(frozen=True)
class _Entry:
    trace: Path
    page: str | None  # the report's file name in the index's directory
    summary: Summary | None
    error: str | None


def write_reports(traces: list[Path], outdir: Path) -> Path:
    """One report per trace in `outdir` (named after the trace), and `outdir`/index.html
    linking them with each one's verdict. A trace that cannot be read gets a row saying why
    instead of a report. Returns the index's path."""
    require_plotting()
    outdir.mkdir(parents=True, exist_ok=True)
    entries = []
    taken: set[str] = {"index.html"}
    for path in traces:
        try:
            trace = read_trace(path)
        except TraceError as error:
            entries.append(_Entry(path, None, None, str(error)))
            continue
        name = f"{trace.name}.html"
        number = 1
        while name in taken:
            number += 1
            name = f"{trace.name}-{number}.html"
        taken.add(name)
        summary = summarise(trace)
        (outdir / name).write_text(_render(trace, summary), encoding="utf-8")
        entries.append(_Entry(path, name, summary, None))
    index = outdir / "index.html"
    index.write_text(_index_page(entries), encoding="utf-8")
    return index


def _index_page(entries: list[_Entry]) -> str:
    rows = []
    verdicts = [e.summary.verdict for e in entries if e.summary is not None]
    passed = sum(1 for v in verdicts if v is not None and v.scenario_passed)
    failed = sum(1 for v in verdicts if v is not None and v.scenario_passed is False)
    for entry in entries:
        if entry.summary is None or entry.page is None:
            rows.append(f'<tr><td>{escape(entry.trace.name)}</td><td class="fail">unreadable</td>'
                        f'<td colspan="6">{escape(entry.error or "")}</td></tr>')
            continue
        summary = entry.summary
        verdict = summary.verdict
        if verdict is None or verdict.scenario_passed is None:
            word, tone = "no verdict", ""
        else:
            word, tone = ("passed", "pass") if verdict.scenario_passed else ("FAILED", "fail")
        if verdict is None:
            once = "—"
        elif verdict.passed:
            once = "yes"
        else:
            once = f"no: {len(verdict.missing):,} missing, {len(verdict.duplicated):,} duplicated"
        faults = sum(fault.fired for fault in summary.faults)
        simulated = dict(summary.facts).get("simulated time", "")
        rows.append(
            f'<tr><td><a href="{escape(entry.page)}">{escape(summary.title)}</a></td>'
            f'<td class="{tone}">{word}</td><td>{once}</td><td class="n">{summary.commands:,}</td>'
            f'<td class="n">{summary.resends:,}</td><td class="n">{faults:,}</td>'
            f'<td class="n">{len(summary.resets):,}</td><td class="n">{escape(simulated)}</td></tr>'
        )
    unreadable = len(entries) - len(verdicts)
    counts = f"{len(entries)} traces: {passed} passed, {failed} failed" + (
        f", {unreadable} unreadable" if unreadable else "")
    return f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>Scenario reports · fake-marlin</title>
<link rel="icon" href="data:,">
<style>
{STYLE}</style>
</head>
<body>
<header><h1>Scenario reports</h1>
<p class="subtitle">{counts}</p></header>
<main>
<section class="tables"><div>
<table class="index">
<thead><tr><th>scenario</th><th>verdict</th><th>exactly once</th><th class="n">commands</th><th class="n">resends</th>
<th class="n">faults</th><th class="n">resets</th><th class="n">simulated time</th></tr></thead>
{"".join(rows)}
</table>
</div></section>
</main>
</body>
</html>
"""
