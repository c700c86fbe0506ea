"""`fake-marlin report`: a wire trace (docs/trace.md) as one self-contained HTML page.

reader.py reads the trace, series.py and summary.py turn it into what the page shows,
plots.py draws the figure (matplotlib: the `report` extra), wirelog.py and page.py make the
page, build.py ties them together and writes index pages for many traces.
"""

from fake_marlin.emulator.report.build import (
    MissingPlotting,
    render_report,
    write_report,
    write_reports,
)
from fake_marlin.emulator.report.reader import Trace, TraceError, read_trace

__all__ = [
    "MissingPlotting", "Trace", "TraceError", "read_trace", "render_report", "write_report",
    "write_reports",
]
