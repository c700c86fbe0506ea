"""Verify direct waits on trio releases: `python -m tests.verify_trio 0.35.0 [0.36.0 ...]`.

For each release: a venv of its own (under ~/.cache/fake-marlin/trio-verify), this checkout
installed into it with its test extras, that trio release over them, and the tests that show
direct waits keep trio's promises (emulator/link/direct_wait.py) run there. A release passes
only if they all pass with direct waits in use; add it to VERIFIED_TRIO first (a release not
in the list runs trio's own waits, and its direct-wait tests skip). Exit 0 when every release
passed.
"""

import argparse
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
VENVS = Path.home() / ".cache" / "fake-marlin" / "trio-verify"
TESTS = (
    "tests/test_direct_wait.py",
    "tests/test_end_to_end.py",
    "tests/test_host_marlin_e2e.py",
    "tests/test_tcp_link.py",
)


def verify(version: str) -> bool:
    venv = VENVS / f"trio-{version}"
    python = venv / "bin" / "python"
    steps = [
        [sys.executable, "-m", "venv", str(venv)],
        [str(python), "-m", "pip", "install", "-q", "-e", f"{ROOT}[test]"],
        [str(python), "-m", "pip", "install", "-q", f"trio=={version}"],
    ]
    for step in steps:
        if subprocess.run(step, cwd=ROOT).returncode != 0:
            print(f"trio {version}: could not run {' '.join(step)}", file=sys.stderr)
            return False
    waits = subprocess.run(
        [str(python), "-c", "from fake_marlin.emulator.link.direct_wait import waits_in_use;"
         "print(waits_in_use()[1])"], cwd=ROOT, capture_output=True, text=True,
    ).stdout.strip()
    print(f"== {waits}", flush=True)
    tests = subprocess.run(
        [str(python), "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rs", *TESTS], cwd=ROOT
    )
    return tests.returncode == 0 and "direct waits" in waits.split(":", 1)[1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.verify_trio", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("versions", nargs="+", metavar="VERSION", help="trio releases, e.g. 0.35.0")
    args = parser.parse_args(argv)
    failed = [version for version in args.versions if not verify(version)]
    print(f"verified: {', '.join(v for v in args.versions if v not in failed) or 'none'}; "
          f"failed: {', '.join(failed) or 'none'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
