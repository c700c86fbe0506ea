"""The install step (tests/hosts/install.py): the tests find what it made, and only that.

Every cache is moved to an empty folder here (FAKE_MARLIN_VENVS, FAKE_MARLIN_NPM), so nothing
is installed or touched; `--check` installs nothing by design.
"""

import json
import os
from pathlib import Path

import pytest

from fake_marlin.emulator.bench import runs
from tests.hosts import install, npm, venvs


@pytest.fixture
def caches(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("FAKE_MARLIN_VENVS", str(tmp_path / "venvs"))
    monkeypatch.setenv("FAKE_MARLIN_NPM", str(tmp_path / "npm"))
    return tmp_path


def fake_venv(caches: Path, host: venvs.Host, marker: bool = True) -> Path:
    """A venv as the install step leaves it: bin/python, and the marker written last."""
    path = caches / "venvs" / f"{host.name}-{host.version}"
    (path / "bin").mkdir(parents=True)
    os.symlink(os.path.realpath("/proc/self/exe"), path / "bin" / "python")
    if marker:
        (path / venvs.MARKER).write_text(json.dumps({"install_seconds": 1.5}))
    return path


def test_the_skip_reason_names_the_command() -> None:
    assert install.not_installed("OctoPrint 1.11") == (
        "OctoPrint 1.11 is not installed: run `python -m tests.hosts.install`")


def test_nothing_is_found_in_empty_caches(caches: Path) -> None:
    assert all(venvs.find(host) is None for host in venvs.HOSTS)
    assert all(npm.find(package) is None for package in npm.PACKAGES)
    assert not (caches / "venvs").exists() and not (caches / "npm").exists()


def test_a_venv_is_found_only_once_its_marker_is_written(caches: Path) -> None:
    fake_venv(caches, venvs.PRINTRUN, marker=False)  # an install cut short
    assert venvs.find(venvs.PRINTRUN) is None
    path = fake_venv(caches, venvs.OCTOPRINT)
    found = venvs.find(venvs.OCTOPRINT)
    assert found is not None and found.path == path and found.python == path / "bin" / "python"
    assert found.install_seconds == 1.5 and not found.built_now


def test_the_bench_finds_the_venvs_where_the_install_step_puts_them(caches: Path) -> None:
    assert runs.octoprint().command is None and runs.printcore().command is None
    assert "python -m tests.hosts.install" in runs.octoprint().missing
    for host in (venvs.OCTOPRINT, venvs.PRINTRUN):
        fake_venv(caches, host)
    assert runs.octoprint().command is not None and runs.printcore().command is not None


def test_an_npm_package_is_found_only_whole(caches: Path) -> None:
    path = caches / "npm" / f"{npm.CNCJS.name}-{npm.CNCJS.version}"
    (path / "node_modules" / "cncjs").mkdir(parents=True)
    (path / "node_modules" / "cncjs" / "package.json").write_text("{}")
    assert npm.find(npm.CNCJS) is None  # no marker
    (path / npm.MARKER).write_text(json.dumps({"install_seconds": 2.0}))
    found = npm.find(npm.CNCJS)
    if found is None:
        pytest.skip("no node on PATH")
    assert found.path == path and found.module("cncjs") == path / "node_modules" / "cncjs"


def test_check_installs_nothing_and_says_what_is_missing(caches: Path, capsys) -> None:
    fake_venv(caches, venvs.BINPROTO)
    assert install.main(["--check", "--only", "binproto", "--only", "printrun"]) == 1
    out, err = capsys.readouterr()
    lines = out.splitlines()  # in install order
    assert lines[0].split() == ["printrun", "missing"]
    assert lines[1].startswith("binproto ") and "cached (built in 1.5 s)" in lines[1]
    assert "not installed: printrun (run `python -m tests.hosts.install`)" in err
    assert not (caches / "venvs" / f"printrun-{venvs.PRINTRUN.version}").exists()


def test_only_takes_what_an_item_needs_and_keeps_the_install_order() -> None:
    assert [item.name for item in install.chosen(["pyright", "avrdude"])] == [
        "node", "npm", "avrdude", "pyright"]
    assert len(install.BY_NAME) == len(install.ITEMS)
    assert {"octoprint", "printrun", "binproto", "cncjs", "playwright-core", "pyright",
            "avrdude", "chromium", "node", "npm", "prusalink", "libcap-dev", "libturbojpeg0",
            "libmagic1", "dockerd", "docker-compose", "debootstrap", "docker-daemon",
            "docker-base-image", "docker-wheels"} == set(install.BY_NAME)


def test_help_names_every_item(capsys) -> None:
    with pytest.raises(SystemExit) as done:
        install.main(["--help"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    assert "python -m tests.hosts.install" in out
    assert all(f"  {name} " in out for name in install.BY_NAME)
