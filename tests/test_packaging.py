"""What `pip install fake-marlin` puts on a machine: one import root, typed, with its plugin."""

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(ROOT)],
        check=True,
        capture_output=True,
    )
    (found,) = out.glob("fake_marlin-*.whl")
    return found


def test_the_wheel_installs_one_top_level_package_and_marks_it_typed(wheel: Path) -> None:
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        (top_level,) = [name for name in names if name.endswith(".dist-info/top_level.txt")]
        assert archive.read(top_level).decode().split() == ["fake_marlin"]
        (entry_points,) = [name for name in names if name.endswith(".dist-info/entry_points.txt")]
        points = archive.read(entry_points).decode()
    assert {name.split("/")[0] for name in names if ".dist-info/" not in name} == {"fake_marlin"}
    assert "fake_marlin/py.typed" in names
    for module in ("emulator/cli/main.py", "host/connect.py", "wire/gcode.py", "testing.py"):
        assert f"fake_marlin/{module}" in names
    assert "fake_marlin = fake_marlin.pytest_plugin" in points
    assert "fake-marlin = fake_marlin.emulator.cli.main:main" in points


def test_from_the_wheel_fake_marlin_imports_and_emulator_host_wire_do_not(
    wheel: Path, tmp_path: Path
) -> None:
    unpacked = tmp_path / "site"
    with zipfile.ZipFile(wheel) as archive:
        archive.extractall(unpacked)
    check = f"""
import sys
sys.path.insert(0, {str(unpacked)!r})
sys.meta_path[:] = [f for f in sys.meta_path if "editable" not in str(getattr(f, "__module__", ""))]
import fake_marlin, fake_marlin.host, fake_marlin.emulator.cli.main, fake_marlin.wire.gcode
assert fake_marlin.__file__.startswith({str(unpacked)!r}), fake_marlin.__file__
from fake_marlin.host import Client, PrintSummary, connect, open_printer
for name in ("emulator", "host", "wire"):
    try:
        __import__(name)
    except ModuleNotFoundError:
        pass
    else:
        raise SystemExit(f"import {{name}} worked")
print(fake_marlin.__version__)
"""
    result = subprocess.run(
        [sys.executable, "-c", check], cwd=tmp_path, capture_output=True, text=True
    )
    assert result.returncode == 0, result.stderr
    import fake_marlin

    assert result.stdout.strip() == fake_marlin.__version__


def test_both_programs_say_their_version() -> None:
    import fake_marlin

    for program in ("fake_marlin.emulator.cli", "fake_marlin.host.cli"):
        result = subprocess.run(
            [sys.executable, "-m", program, "--version"], capture_output=True, text=True
        )
        assert result.returncode == 0
        assert result.stdout.strip().endswith(f" {fake_marlin.__version__}")
