"""The report as one self-contained HTML page: no network, no external file, opens from disk.

The figure is inline SVG. The wire log is embedded as one JSON array and shown a page of rows
at a time by a little inline script (assets.py), so a trace of 100,000
records stays a page a browser opens at once: the rows are not in the HTML, only the data.
"""

from html import escape

from fake_marlin import __version__
from fake_marlin.emulator.report.assets import SCRIPT, STYLE
from fake_marlin.emulator.report.summary import ExactlyOnce, Summary
from fake_marlin.emulator.report.wirelog import HIDDEN, LABELS, embed_json

SHOWN_PROBLEMS = 10  # missing and duplicated commands listed under a failed verdict
SHOWN_REASONS = 8
# The power-up and a host opening the port: every run has them, so they are no warning.
EXPECTED_RESETS = frozenset({"PowerUp", "External Reset"})


def render_page(summary: Summary, svg: str, kinds: list[str], rows: list[list[object]],
                trace_name: str) -> str:
    log = {"kinds": kinds, "labels": [LABELS[k] for k in kinds],
           "hidden": [k in HIDDEN for k in kinds], "rows": rows}
    title = escape(summary.title)
    return f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta name="generator" content="fake-marlin {escape(__version__)}">
<title>{title} · fake-marlin trace report</title>
<link rel="icon" href="data:,">
<style>
{STYLE}</style>
</head>
<body>
<header>
<h1>{title}</h1>
<p class="subtitle">Trace report of <code>{escape(trace_name)}</code> · made by fake-marlin {escape(__version__)}</p>
</header>
<main>
{_verdict(summary.verdict)}
{_cards(summary)}
{_tables(summary)}
{_notes(summary.notes)}
<section id="plots">
<h2>Over time</h2>
<figure class="plot">
{svg}
</figure>
</section>
<section id="log">
<h2>Wire log</h2>
<div class="controls">
<input id="search" type="search" placeholder="Search the log (press / to jump here)" autocomplete="off" aria-label="search the log">
<label class="goto">go to time <input id="goto" type="number" step="any" min="0" placeholder="s"></label>
<div class="presets">show <button id="preset-conversation" type="button">the conversation</button><button id="preset-problems" type="button">problems only</button><button id="preset-all" type="button">everything</button></div>
<div id="kinds" class="kinds" role="group" aria-label="show these kinds"></div>
</div>
<div class="pager"><button id="first" type="button">&laquo;</button><button id="prev" type="button">&lsaquo; earlier</button><span id="log-count"></span><button id="next" type="button">later &rsaquo;</button><button id="last" type="button">&raquo;</button></div>
<table id="log-table">
<thead><tr><th class="time" title="click a time to see that record in context">time (s)</th><th class="kind">kind</th><th>what</th></tr></thead>
<tbody></tbody>
</table>
</section>
</main>
<script type="application/json" id="log-data">{embed_json(log)}</script>
<script>
{SCRIPT}</script>
</body>
</html>
"""


def _verdict(verdict: ExactlyOnce | None) -> str:
    """A scenario's own verdict leads (it may expect commands lost: a halted print); the
    exactly-once finding follows. Without a scenario, exactly-once is the verdict."""
    if verdict is None:
        return ('<section id="verdict" class="verdict unknown"><p><strong>Exactly once: not '
                'judged.</strong> No job is known for this trace (a scenario run records its '
                'job; for a live printer, pass <code>--job JOB.gcode</code>).</p></section>')
    source = escape(verdict.source)
    if verdict.passed:
        once = (f"<strong>Exactly once:</strong> each of the {verdict.job:,} job commands ran "
                f"once, in order ({verdict.ran:,} commands executed; judged by {source}).")
    else:
        problems = [f"{len(verdict.missing):,} missing", f"{len(verdict.duplicated):,} duplicated"]
        if verdict.reordered:
            problems.append(f"{verdict.reordered:,} reordered")
        once = (f"<strong>Not exactly once:</strong> of {verdict.job:,} job commands, "
                f"{', '.join(problems)} (judged by {source}).")
    good = verdict.passed if verdict.scenario_passed is None else verdict.scenario_passed
    parts = [f'<section id="verdict" class="verdict {"pass" if good else "fail"}">']
    if verdict.scenario_passed is None:
        parts.append(f"<p>{'&#10003;' if good else '&#10007;'} {once}</p>")
    else:
        outcome = f" (outcome: {escape(verdict.outcome)})" if verdict.outcome else ""
        head = "passed its checks" if good else "FAILED its checks"
        parts.append(f"<p>{'&#10003;' if good else '&#10007;'} <strong>The scenario {head}"
                     f"</strong>{outcome}.</p>")
        parts.append(f"<p>{once}</p>")
    for name, commands in (("missing", verdict.missing), ("duplicated", verdict.duplicated)):
        if commands:
            shown = ", ".join(f"<code>{escape(c)}</code>" for c in commands[:SHOWN_PROBLEMS])
            more = f" and {len(commands) - SHOWN_PROBLEMS:,} more" if len(commands) > SHOWN_PROBLEMS else ""
            parts.append(f"<p class=\"problems\">{name}: {shown}{more}</p>")
    if verdict.text:
        parts.append(f"<details><summary>The verdict in full</summary><pre>{escape(verdict.text)}"
                     "</pre></details>")
    parts.append("</section>")
    return "\n".join(parts)


def _cards(summary: Summary) -> str:
    host = "" if summary.host_resends is None else f"the host counted {summary.host_resends:,}"
    faults = sum(fault.fired for fault in summary.faults)
    cards = [
        ("commands", f"{summary.commands:,}", "commands executed", "", ""),
        ("resends", f"{summary.resends:,}", "resends asked", host, "bad" if summary.resends else ""),
        ("timeouts", "—" if summary.timeouts is None else f"{summary.timeouts:,}", "host timeouts",
         ("the host gave none" if summary.verdict else "known for scenario runs")
         if summary.timeouts is None else "",
         "bad" if summary.timeouts else ""),
        ("errors", f"{summary.errors:,}", "error lines", "Error: / ProtoError:",
         "bad" if summary.errors else ""),
        ("faults", f"{faults:,}", "faults fired",
         f"{len(summary.faults)} kind{'s' * (len(summary.faults) != 1)}" if faults else "",
         "warn" if faults else ""),
        ("resets", f"{len(summary.resets):,}", "resets", ", ".join(dict.fromkeys(summary.resets)),
         "warn" if set(summary.resets) - EXPECTED_RESETS else ""),
        ("connects", f"{summary.connects:,}", "connects",
         f"{summary.disconnects:,} disconnects" if summary.disconnects else "", ""),
    ]
    html = ['<section id="summary" class="cards">']
    for key, value, label, note, tone in cards:
        html.append(f'<div class="card {tone}" data-key="{key}"><div class="value">{value}</div>'
                    f'<div class="label">{label}</div><div class="note">{escape(note)}</div></div>')
    html.append("</section>")
    return "\n".join(html)


def _tables(summary: Summary) -> str:
    facts = [*summary.facts, ("bytes to printer", f"{summary.bytes_in:,}"),
             ("bytes to host", f"{summary.bytes_out:,}")]
    run = "".join(f"<tr><th>{escape(k)}</th><td>{escape(v)}</td></tr>" for k, v in facts)
    if summary.faults:
        faults = "".join(
            f"<tr><td><code>{escape(f.kind)}</code></td><td class=\"n\">{f.fired:,}</td>"
            f"<td>{escape(f.detail)}</td></tr>" for f in summary.faults)
    else:
        faults = '<tr><td colspan="3" class="none">no faults fired</td></tr>'
    reasons = summary.resend_reasons[:SHOWN_REASONS]
    if reasons:
        why = "".join(f"<tr><td>{escape(r)}</td><td class=\"n\">{n:,}</td></tr>" for r, n in reasons)
        rest = summary.resend_reasons[SHOWN_REASONS:]
        if rest:
            why += f'<tr><td>{len(rest)} other reasons</td><td class="n">{sum(n for _, n in rest):,}</td></tr>'
    else:
        why = '<tr><td colspan="2" class="none">the printer asked for nothing again</td></tr>'
    resets = ", ".join(escape(r) or "?" for r in summary.resets) or "none"
    return f"""<section class="tables">
<div><h3>The run</h3><table class="facts">{run}<tr><th>resets</th><td>{resets}</td></tr></table></div>
<div><h3>Faults by kind</h3><table class="faults"><thead><tr><th>kind</th><th class="n">fired</th><th>size</th></tr></thead>{faults}</table></div>
<div><h3>Why the printer asked again</h3><table class="reasons"><thead><tr><th>reason</th><th class="n">times</th></tr></thead>{why}</table></div>
</section>"""


def _notes(notes: list[str]) -> str:
    if not notes:
        return ""
    return '<section class="notes">' + "".join(f"<p>{escape(n)}</p>" for n in notes) + "</section>"
