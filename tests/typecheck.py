"""Type checks: `mypy --strict` on the sans-IO layers, plain mypy on the whole package.

The import root, fake_marlin/, is a plain folder of the checkout (its emulator, host and wire
are symlinks to the top-level folders), so mypy reads it as it is. `python -m tests.typecheck`
runs both checks.
"""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
STRICT = (
    "fake_marlin.wire",
    "fake_marlin.emulator.protocols",
    "fake_marlin.host.codecs",
    "fake_marlin.host.cores",
)
CHECKS = {
    "strict": ["--strict", *(arg for package in STRICT for arg in ("-p", package))],
    "plain": ["-p", "fake_marlin"],
}


def run(check: str, cache: Path | None = None) -> subprocess.CompletedProcess[str]:
    """mypy's verdict on one check, from the checkout root. `cache`: mypy's cache directory
    (default: .mypy_cache/<check> in the checkout, one for each check: the strict and the plain
    check read the same modules with other options, so in one cache each would find the other's
    results stale and check everything again; warm, each takes half a second)."""
    cache = cache if cache is not None else ROOT / ".mypy_cache" / check
    return subprocess.run(
        [sys.executable, "-m", "mypy", "--cache-dir", str(cache), *CHECKS[check]],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )


def main() -> int:
    failed = 0
    for check in CHECKS:
        result = run(check)
        print(f"== mypy {check}: {' '.join(CHECKS[check])}\n{result.stdout}{result.stderr}", end="")
        failed |= result.returncode != 0
    return failed


if __name__ == "__main__":
    sys.exit(main())
