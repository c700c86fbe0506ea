"""`fake-marlin report TRACE -o report.html`: a wire trace as one self-contained HTML page.

Exit codes: 0 the page was written, 2 a usage problem, a trace or job that cannot be read, a
page that cannot be written, or matplotlib missing (the `report` extra).
"""

import argparse
import sys
from pathlib import Path

from fake_marlin.emulator.cli.parsing import Commands

PROG = "fake-marlin report"


def configure(commands: Commands) -> None:
    """Add `report` to fake-marlin's commands (main.py)."""
    parser = commands.add_parser(
        "report", help="turn a --trace file into one HTML page",
        description="Turn a wire trace (--trace FILE; plain or .gz JSON lines, docs/trace.md) "
        "into one HTML page that opens from disk: commands per second, the planner's room, the "
        "heaters and marks for resends, errors, faults and resets on one time axis; a summary "
        "with the exactly-once verdict when the job is known; and the searchable wire log.",
    )
    parser.add_argument("trace", metavar="TRACE", help="the trace file")
    parser.add_argument("-o", "--output", metavar="FILE",
                        help="the page to write (default: TRACE's name with .html, beside it)")
    parser.add_argument("--job", metavar="JOB.gcode",
                        help="the G-code the host streamed: judge exactly-once against it (a "
                        "scenario run's trace carries its own verdict)")
    parser.set_defaults(run=run)


def main(argv: list[str] | None = None) -> int:
    """`fake-marlin report ARGV...`."""
    from fake_marlin.emulator.cli.main import main

    return main(["report", *(sys.argv[1:] if argv is None else argv)])


def run(args: argparse.Namespace) -> int:
    from fake_marlin.emulator.report.build import MissingPlotting, require_plotting

    try:
        require_plotting()
    except MissingPlotting as error:
        print(f"{PROG}: {error}", file=sys.stderr)
        return 2
    import matplotlib

    matplotlib.use("Agg")  # never a window, whatever the environment asks for
    from fake_marlin.emulator.report.build import render_report
    from fake_marlin.emulator.report.reader import TraceError, read_trace

    job = None
    if args.job is not None:
        try:
            job = Path(args.job).read_bytes().decode("utf-8-sig")
        except OSError as error:
            print(f"{PROG}: cannot read the job {args.job}: {error.strerror or error}", file=sys.stderr)
            return 2
        except UnicodeDecodeError:
            print(f"{PROG}: {args.job}: not UTF-8 text", file=sys.stderr)
            return 2
    try:
        trace = read_trace(args.trace)
        page = render_report(trace, job, Path(args.job).name if args.job else "the job")
    except (TraceError, MissingPlotting) as error:
        print(f"{PROG}: {error}", file=sys.stderr)
        return 2
    out = Path(args.output) if args.output else Path(args.trace).with_name(f"{trace.name}.html")
    try:
        out.write_text(page, encoding="utf-8")
    except OSError as error:
        print(f"{PROG}: cannot write {out}: {error.strerror or error}", file=sys.stderr)
        return 2
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
