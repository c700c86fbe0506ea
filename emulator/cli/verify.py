"""`fake-marlin verify JOB JOURNAL`: did the printer run the job exactly once, in order?

Exit codes: 0 it did, 1 it did not (missing, duplicated or reordered commands; with --strict
also extra ones), 2 a usage problem or a file that cannot be read as UTF-8 text.
"""

import argparse
import json
import os
import sys
from collections import Counter
from typing import TYPE_CHECKING

from fake_marlin.emulator.cli.parsing import Commands

# The checking code is imported where it runs: building the parser, which every `fake-marlin`
# does, imports none of it.
if TYPE_CHECKING:
    from fake_marlin.emulator.journal.verify import Problem, Verification

PROG = "fake-marlin verify"


class InputError(Exception):
    pass


def configure(commands: Commands) -> None:
    """Add `verify` to fake-marlin's commands (main.py)."""
    parser = commands.add_parser(
        "verify", help="check that a --journal ran its G-code job exactly once",
        description="Check a --journal against the G-code job it should have run: report job "
        "commands that are missing, duplicated or reordered, and extra commands the host sent "
        "on its own (polls, line numbering: not failures unless --strict).",
    )
    parser.add_argument("job", metavar="JOB.gcode", help="the G-code file the host streamed")
    parser.add_argument("journal", metavar="JOURNAL", help="the file fake-marlin --journal wrote")
    parser.add_argument("--strict", action="store_true", help="extra commands fail the check too")
    parser.add_argument("--json", action="store_true", help="print every problem as JSON instead")
    parser.add_argument(
        "--allow-undetectable", action="store_true",
        help="commands that ran damaged past the protocol's checksum are no failure",
    )
    parser.add_argument(
        "--limit", type=_count, default=20, metavar="N",
        help="problems to list (default 20; 0 lists all)",
    )
    parser.set_defaults(run=run)


def _count(text: str) -> int:
    if not text.isdigit():
        raise argparse.ArgumentTypeError(f"must be a whole number, got {text!r}")
    return int(text)


def read_text(path: str) -> str:
    """The file as text, or InputError saying in one line why it cannot be."""
    try:
        with open(path, "rb") as file:
            raw = file.read()
    except OSError as error:
        raise InputError(f"cannot read {path}: {error.strerror or error}") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        line = raw.count(b"\n", 0, error.start) + 1
        raise InputError(f"{path}:{line}: not UTF-8 text (byte 0x{raw[error.start]:02x})") from None


def main(argv: list[str] | None = None) -> int:
    """`fake-marlin verify ARGV...`."""
    from fake_marlin.emulator.cli.main import main

    return main(["verify", *(sys.argv[1:] if argv is None else argv)])


def run(args: argparse.Namespace) -> int:
    from fake_marlin.emulator.journal.verify import job_commands, verify

    try:
        job = job_commands(read_text(args.job))
        journal = read_text(args.journal).split("\n")
    except InputError as error:
        print(f"{PROG}: {error}", file=sys.stderr)
        return 2
    result = verify(job, journal)
    try:
        if args.json:
            print(json.dumps(_as_json(result, args), indent=2))
        else:
            print(report(result, args.strict, args.limit, args.allow_undetectable))
        sys.stdout.flush()
    except BrokenPipeError:  # `| head` has read enough; the verdict is still the exit code
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0 if result.passed(args.strict, args.allow_undetectable) else 1


def report(
    result: "Verification", strict: bool = False, limit: int = 20, allow_undetectable: bool = False
) -> str:
    """A few lines a person reads: the verdict, then the first `limit` failures."""
    from fake_marlin.emulator.journal.verify import FAILURES, Kind

    failures = result.failures(strict, allow_undetectable)
    kinds: tuple[Kind, ...] = FAILURES + (Kind.EXTRA,) if strict else FAILURES
    # Damage past the checksum is rare and its own story: counted only where it happened.
    kinds = tuple(kind for kind in kinds if kind is not Kind.DAMAGED or result.count(kind))
    if failures:
        lines = ["FAILED: " + ", ".join(f"{result.count(kind)} {kind.value}" for kind in kinds)]
    else:
        lines = [f"OK: each of the {result.job_commands} job commands ran once, in order"]
        if result.count(Kind.DAMAGED):
            lines[0] += f" ({result.count(Kind.DAMAGED)} damaged past the checksum, allowed)"
    shown = failures if limit == 0 else failures[:limit]
    lines += ["  " + _describe(problem) for problem in shown]
    if len(shown) < len(failures):
        lines.append(f"  ... and {len(failures) - len(shown)} more (--limit 0 lists all)")
    extras = Counter(p.command for p in result.problems if p.kind is Kind.EXTRA)
    if extras and not strict:
        common = ", ".join(f"{count} x {command}" for command, count in extras.most_common(5))
        more = f", {len(extras) - 5} other kinds" if len(extras) > 5 else ""
        lines.append(
            f"{sum(extras.values())} extra (sent by the host, not failures without --strict): "
            f"{common}{more}"
        )
    if result.approximate:
        lines.append(
            "note: part of the journal differs from the job in too many places to align (is it "
            "this job's journal?); the problems listed there are a rough guess"
        )
    return "\n".join(lines)


def _describe(problem: "Problem") -> str:
    from fake_marlin.emulator.journal.verify import Kind, describe_damage

    command = problem.command
    match problem.kind:
        case Kind.MISSING:
            return f"missing     job line {problem.job_line} never ran: {command}"
        case Kind.DUPLICATED:
            return (f"duplicated  job line {problem.job_line} ran again at journal line "
                    f"{problem.journal_line}: {command}")
        case Kind.REORDERED:
            return (f"reordered   job line {problem.job_line} ran out of order at journal line "
                    f"{problem.journal_line}: {command}")
        case Kind.EXTRA:
            return f"extra       journal line {problem.journal_line}, not the job's: {command}"
        case Kind.DAMAGED:
            return describe_damage(problem)


def _as_json(result: "Verification", args: argparse.Namespace) -> dict:
    from fake_marlin.emulator.journal.verify import Kind

    return {
        "ok": result.passed(args.strict, args.allow_undetectable),
        "strict": args.strict,
        "job": args.job,
        "journal": args.journal,
        "job_commands": result.job_commands,
        "journal_commands": result.journal_commands,
        "counts": {kind.value: result.count(kind) for kind in Kind},
        "approximate": result.approximate,
        "problems": [
            {"kind": p.kind.value, "job_line": p.job_line, "journal_line": p.journal_line,
             "command": p.command, **({"ran_as": p.ran_as} if p.kind is Kind.DAMAGED else {})}
            for p in result.problems
        ],
    }


if __name__ == "__main__":
    sys.exit(main())
