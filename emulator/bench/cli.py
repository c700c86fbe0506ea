"""`fake-marlin bench`: measure the emulator and the hosts, each figure against a reference
measured side by side in the same run, and print the table (or `--json`).

Sections (`--only`, comma-separated; default all, in this order):
  hosts    host throughput, 2,000 moves of 0.4 mm: each host to fake-marlin and to the bare
           ok-responder (our host in Marlin, OctoPrint's comm layer, printcore; our host in
           Ultimaker to fake-marlin alone)
  cpu      the printer's CPU time per command, against the bare responder's
  baud     our Ultimaker host at 250000 baud, against the wire's limit
  latency  30 ms each way: Ultimaker windowed against Marlin stop-and-wait
  simhour  wall seconds one simulated hour of printing takes at --speed 1000
  farm     `--printers N`: 200 idle (CPU, memory per printer), 50 streaming at once
  lab      the protocol lab: Ultimaker's variants against plain v3, on simulated time
           (docs/protocol-lab.md)

The JSON object: version, quick, moves, rounds, cpus, load_average (before, after), goals
{met, missed}, and sections {name: {title, rows, notes, seconds}}; each row has figure,
measured, reference, ratio, goal, met (true, false, or null where no goal applies or nothing
could be measured) and its raw numbers (hosts: host, installed, fake_marlin and bare, each
with cmd_per_s, complete, acknowledged, job, runs).

Exit 0 whenever the bench ran, goals met or not (it measures, it does not test); 2 for bad
arguments; 130 if interrupted. Every process it starts is stopped, its files removed.
"""

import argparse
import contextlib
import json
import os
import shutil
import signal
import sys
import tempfile
import time
from pathlib import Path

from fake_marlin import __version__
from fake_marlin.emulator.cli.parsing import Commands, whole_number

PROG = "fake-marlin bench"
# The keys of measure.SECTIONS, in their order (tests/test_cli.py checks): written out here so
# that building the parser, which every `fake-marlin` does, imports none of the measurements.
SECTIONS = ("hosts", "cpu", "baud", "latency", "simhour", "farm", "lab")
DEFAULT_MOVES, QUICK_MOVES = 2000, 300
DEFAULT_ROUNDS, QUICK_ROUNDS = 3, 1


def _sections(text: str) -> tuple[str, ...]:
    names = tuple(name.strip() for name in text.split(",") if name.strip())
    unknown = [name for name in names if name not in SECTIONS]
    if not names or unknown:
        raise argparse.ArgumentTypeError(
            f"unknown section {', '.join(map(repr, unknown)) or repr(text)}; choose from "
            f"{', '.join(SECTIONS)}")
    return tuple(name for name in SECTIONS if name in names)  # the documented order


def configure(commands: Commands) -> None:
    """Add `bench` to fake-marlin's commands (main.py); its errors are one line, no usage block:
    `fake-marlin bench: error: ... (see fake-marlin bench --help)`."""
    parser = commands.add_parser(
        "bench", help="measure fake-marlin and the hosts against references",
        one_line_errors=True, formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Measure fake-marlin and the hosts; each figure is a ratio to a reference "
        "measured side by side in the same run.",
        epilog="sections: " + ", ".join(SECTIONS),
    )
    parser.add_argument("--quick", action="store_true",
                        help="small jobs, one round, smaller farms (about half a minute)")
    parser.add_argument("--only", type=_sections, metavar="SECTION[,SECTION]",
                        help="run these sections only")
    parser.add_argument("--moves", type=whole_number(1, 1_000_000), metavar="N",
                        help=f"moves in the throughput job (default {DEFAULT_MOVES:,}; "
                        f"{QUICK_MOVES} with --quick)")
    parser.add_argument("--rounds", type=whole_number(1, 100), metavar="N",
                        help=f"side-by-side rounds per throughput pair (default {DEFAULT_ROUNDS}; "
                        f"{QUICK_ROUNDS} with --quick)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead")
    parser.set_defaults(run=run)


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def main(argv: list[str]) -> int:
    """`fake-marlin bench ARGV...`."""
    from fake_marlin.emulator.cli.main import main

    return main(["bench", *argv])


def run(args: argparse.Namespace) -> int:
    from fake_marlin.emulator.bench.measure import Bench, Options, run_section
    from fake_marlin.emulator.bench.procs import Processes
    from fake_marlin.emulator.bench.report import as_json, markdown

    options = Options(
        quick=args.quick,
        moves=args.moves or (QUICK_MOVES if args.quick else DEFAULT_MOVES),
        rounds=args.rounds or (QUICK_ROUNDS if args.quick else DEFAULT_ROUNDS),
        only=args.only or tuple(SECTIONS),
    )
    # SIGTERM and SIGHUP unwind like Ctrl-C, through the `finally` that stops the processes.
    previous = {signum: signal.signal(signum, _interrupt) for signum in (signal.SIGTERM,
                                                                       signal.SIGHUP)}
    workdir = Path(tempfile.mkdtemp(prefix="fake-marlin-bench-"))
    procs = Processes(workdir)
    progress = sys.stderr.isatty()
    try:
        load_before = os.getloadavg()[0]
        bench = Bench(options, procs, workdir)
        sections = []
        for key in options.only:
            if progress:
                print(f"{PROG}: {key} ...", file=sys.stderr, flush=True)
            sections.append(run_section(bench, key))
        load_after = os.getloadavg()[0]
        meta = {"version": __version__, "quick": options.quick, "moves": options.moves,
                "rounds": options.rounds, "cpus": os.cpu_count(),
                "load_average": [round(load_before, 2), round(load_after, 2)]}
        if args.json:
            print(json.dumps(as_json(sections, meta), indent=2, ensure_ascii=False))
        else:
            when = time.strftime("%Y-%m-%d %H:%M")
            preamble = [f"fake-marlin {__version__} bench, {when}: {os.cpu_count()} CPUs, load "
                        f"average {load_before:.2f} before, {load_after:.2f} after"
                        + (" (--quick: small jobs, not for comparison)" if options.quick else "")]
            print(markdown(sections, preamble))
        sys.stdout.flush()
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted; stopped every process it had started", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `| head` has read enough
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    finally:
        # Another Ctrl-C or SIGTERM while cleaning up must not leave printers behind: finish.
        stopping = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
        restore = {signum: signal.signal(signum, signal.SIG_IGN) for signum in stopping}
        procs.stop_all()
        shutil.rmtree(workdir, ignore_errors=True)
        restore.update(previous)
        for signum, handler in restore.items():
            signal.signal(signum, handler)
    return 0
