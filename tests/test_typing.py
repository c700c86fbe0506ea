"""The type checks are part of the suite: a type error fails it (see tests/typecheck.py), and so
does an import that pyright, the checker editors use, cannot resolve."""

import json
import subprocess

import pytest

from tests import typecheck
from tests.hosts import npm
from tests.hosts.install import not_installed

ROOT = typecheck.ROOT
PYRIGHT_TIMEOUT = 600
# What an unresolved import looks like to pyright: a module it cannot find, a stub without its
# module, or a name a module it found does not have (`x.y`, `from x import y`).
UNRESOLVED_RULES = {"reportMissingImports", "reportMissingModuleSource"}
NOT_IN_MODULE = ("is not a known attribute of module", "is unknown import symbol")


@pytest.mark.parametrize("check", list(typecheck.CHECKS))
def test_mypy_finds_no_error(check: str) -> None:
    # mypy's cache in the checkout (.mypy_cache/<check>): half a second a check once warm.
    result = typecheck.run(check)
    assert result.returncode == 0, f"mypy {check}:\n{result.stdout}{result.stderr}"


def unresolved(diagnostic: dict) -> bool:
    rule = diagnostic.get("rule")
    return rule in UNRESOLVED_RULES or (
        rule == "reportAttributeAccessIssue"
        and any(words in diagnostic["message"] for words in NOT_IN_MODULE))


# End-to-end for its time alone: pyright keeps no cache between runs, so each reads the whole
# checkout and what it imports again (16 s on this idle 2-core machine, 40 s loaded).
@pytest.mark.e2e
def test_pyright_resolves_every_import() -> None:
    """pyright (npm's, basic mode, as [tool.pyright] in pyproject.toml sets it up: the checkout
    with each module once, and the venv .venv) resolves every import. Its other diagnostics are
    type errors, not this test's business. The host drivers (tests/hosts/*_driver.py) import
    packages that only their hosts' venvs have, and say so to pyright in a comment."""
    install = npm.find(npm.PYRIGHT)
    if install is None:
        pytest.skip(not_installed(npm.PYRIGHT.label))
    if not (ROOT / ".venv").is_dir():
        pytest.skip("pyright reads the packages of the checkout's .venv ([tool.pyright] in "
                    "pyproject.toml), and there is none: make it as the README says")
    done = subprocess.run(
        [install.node, str(install.module("pyright") / "index.js"), "--outputjson"],
        cwd=ROOT, capture_output=True, text=True, timeout=PYRIGHT_TIMEOUT,
    )
    # 0: no error, 1: errors (type errors count); anything else is pyright failing to run.
    assert done.returncode in (0, 1), f"pyright exited {done.returncode}:\n{done.stderr[-3000:]}"
    report = json.loads(done.stdout)
    # The whole checkout was read, not a corner of it.
    ours = [path for folder in ("emulator", "host", "wire", "tests")
            for path in (ROOT / folder).rglob("*.py")]
    assert report["summary"]["filesAnalyzed"] >= len(ours)
    found = [
        f"{d['file']}:{d['range']['start']['line'] + 1}: {d['message']} ({d['rule']})"
        for d in report["generalDiagnostics"] if unresolved(d)
    ]
    assert not found, "pyright cannot resolve:\n" + "\n".join(found)
