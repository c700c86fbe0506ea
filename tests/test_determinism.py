"""A scenario run is a pure function of its file: the same digest of the wire transcript under
any hash seed, in a fresh process each time."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.e2e  # every test starts processes
SCENARIOS = Path(__file__).parent.parent / "scenarios"
ONE_PER_PROTOCOL = [SCENARIOS / name for name in (
    "um3-noisy-serial.toml", "marlin-noisy-serial.toml", "repetier-noisy-serial.toml",
    "commstack-noisy-link.toml",
)]


def digests(paths: list[Path], hash_seed: str) -> dict[str, str]:
    result = subprocess.run(
        [sys.executable, "-m", "fake_marlin.emulator.cli", "scenario", "run", "--json", *map(str, paths)],
        capture_output=True, text=True, timeout=300,
        env={**os.environ, "PYTHONHASHSEED": hash_seed},
    )
    assert result.returncode == 0, result.stdout + result.stderr
    return {row["scenario"]: row["digest"] for row in map(json.loads, result.stdout.splitlines())}


def test_the_same_file_gives_the_same_digest_under_every_hash_seed():
    runs = [digests(ONE_PER_PROTOCOL, seed) for seed in ("0", "1", "4242")]
    assert len(runs[0]) == len(ONE_PER_PROTOCOL) and all(len(d) == 64 for d in runs[0].values())
    assert runs[0] == runs[1] == runs[2]


def test_another_seed_gives_another_run(tmp_path):
    text = (SCENARIOS / "marlin-noisy-serial.toml").read_text()
    assert "\nseed = " in text
    reseeded = tmp_path / "reseeded.toml"
    reseeded.write_text(text.replace("\nseed = ", "\nseed = 1000", 1))
    original = digests([SCENARIOS / "marlin-noisy-serial.toml"], "0")
    other = digests([reseeded], "0")
    assert list(original.values()) != list(other.values())
