"""Run fuzz targets under atheris (libFuzzer), with coverage of the fake_marlin package.

    python -m fuzz.run TARGET [libFuzzer options] [CORPUS_DIR ...]
    python -m fuzz.run --all --runs N [libFuzzer options]
    python -m fuzz.run --list

Without a corpus directory, TARGET reads fuzz/corpus/TARGET/ (the committed seeds, never
written) and keeps what it learns in fuzz/work/TARGET/corpus/; a crash, hang or leak is written
to fuzz/work/TARGET/ (crash-*, timeout-*, oom-*) unless -artifact_prefix says otherwise.
FUZZ_SKIP_KNOWN=1 steps around the bugs already reported (fuzz/README.md, "Known bugs").
"""

import os
import subprocess
import sys
from pathlib import Path

FUZZ = Path(__file__).resolve().parent


def fuzz_one(name: str, args: list[str]) -> int:
    import atheris
    # atheris.instrument_imports itself (typeshed's partial atheris stub leaves it out of
    # atheris/__init__.pyi, so type checkers cannot see it there).
    from atheris.import_hook import instrument_imports

    # Instrument what the receivers run: the package, and tomllib for the scenario loader
    # (coverage inside the TOML parser is what leads the fuzzer to well-formed files). Nothing
    # of theirs may be imported before this, or it runs uninstrumented.
    with instrument_imports(include=["fake_marlin", "tomllib"]):
        from fuzz.targets import TARGETS
    if name not in TARGETS:
        print(f"no target {name!r}; the targets are: {', '.join(TARGETS)}", file=sys.stderr)
        return 2
    target = TARGETS[name]
    if not any(not arg.startswith("-") for arg in args):
        work = FUZZ / "work" / name / "corpus"
        work.mkdir(parents=True, exist_ok=True)
        args += [str(work), str(FUZZ / "corpus" / name)]
    if not any(arg.startswith("-artifact_prefix=") for arg in args):
        (FUZZ / "work" / name).mkdir(parents=True, exist_ok=True)
        args.append(f"-artifact_prefix={FUZZ / 'work' / name}{os.sep}")
    atheris.Setup([sys.argv[0], *args], target)
    atheris.Fuzz()  # exits the process: 0 when done, non-zero on a crash, hang or leak
    return 0


def fuzz_all(runs: str, args: list[str]) -> int:
    """Each target for `runs` inputs, one subprocess each; the first failure's code."""
    from fuzz.targets import TARGETS

    failed = 0
    for name in TARGETS:
        print(f"== {name}", flush=True)
        code = subprocess.call([sys.executable, "-m", "fuzz.run", name, f"-runs={runs}", *args],
                               cwd=FUZZ.parent)
        print(f"== {name}: exit {code}", flush=True)
        failed = failed or code
    return failed


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__)
        return 0 if argv else 2
    if argv[0] == "--list":
        from fuzz.targets import TARGETS

        print("\n".join(TARGETS))
        return 0
    if argv[0] == "--all":
        rest = argv[1:]
        runs = "100000"
        if "--runs" in rest:
            at = rest.index("--runs")
            runs = rest[at + 1]
            del rest[at:at + 2]
        return fuzz_all(runs, rest)
    return fuzz_one(argv[0], argv[1:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
