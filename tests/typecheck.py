"""Type checks: `mypy --strict` on the sans-IO layers, plain mypy on the whole package.

mypy finds packages by their folders, and ours are installed from folders of other names
(emulator/ as fake_marlin.emulator, see setup.py), so it checks them through a tree of symlinks
laid out as the installed package is. `python -m tests.typecheck` runs both checks.
"""

import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PARTS = ("emulator", "host", "wire")
STRICT = ("fake_marlin.wire", "fake_marlin.emulator.protocols", "fake_marlin.host.codecs")
CHECKS = {
    "strict": ["--strict", *(arg for package in STRICT for arg in ("-p", package))],
    "plain": ["-p", "fake_marlin"],
}


def lay_out(where: Path) -> Path:
    """`where`/fake_marlin, whose parts are symlinks to the source folders."""
    package = where / "fake_marlin"
    package.mkdir()
    for name in ("__init__.py", "py.typed"):
        (package / name).symlink_to(ROOT / "fake_marlin" / name)
    for part in PARTS:
        (package / part).symlink_to(ROOT / part, target_is_directory=True)
    return where


def run(check: str, where: Path) -> subprocess.CompletedProcess[str]:
    environment = {**os.environ, "MYPYPATH": str(where)}
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "mypy",
            "--config-file",
            str(ROOT / "pyproject.toml"),
            "--cache-dir",
            str(where / ".mypy_cache"),
            *CHECKS[check],
        ],
        capture_output=True,
        text=True,
        env=environment,
        cwd=where,
    )


def main() -> int:
    failed = 0
    with tempfile.TemporaryDirectory() as scratch:
        where = lay_out(Path(scratch))
        for check in CHECKS:
            result = run(check, where)
            print(
                f"== mypy {check}: {' '.join(CHECKS[check])}\n{result.stdout}{result.stderr}",
                end="",
            )
            failed |= result.returncode != 0
    return failed


if __name__ == "__main__":
    sys.exit(main())
