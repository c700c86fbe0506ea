"""The type checks are part of the suite: a type error fails it (see tests/typecheck.py)."""

from pathlib import Path

import pytest

from tests import typecheck


@pytest.mark.parametrize("check", list(typecheck.CHECKS))
def test_mypy_finds_no_error(check: str, tmp_path: Path) -> None:
    result = typecheck.run(check, cache=tmp_path / "mypy-cache")
    assert result.returncode == 0, f"mypy {check}:\n{result.stdout}{result.stderr}"
