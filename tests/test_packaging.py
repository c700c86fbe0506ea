"""What `pip install fake-marlin` puts on a machine: one import root, typed, with its plugin;
and the checkout it is built from, whose import root is a plain folder (docs/layout.md)."""

import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.e2e  # every test starts processes
ROOT = Path(__file__).resolve().parent.parent
PARTS = ("emulator", "host", "wire")


def package_files() -> set[str]:
    """Every file of the package as it should be installed: fake_marlin's own, and those of
    the top-level folders its symlinks stand for (their modules and the firmware profiles),
    each under fake_marlin/ once."""
    files = {f"fake_marlin/{p.name}" for p in (ROOT / "fake_marlin").iterdir() if p.is_file()}
    for part in PARTS:
        files |= {f"fake_marlin/{p.relative_to(ROOT)}" for p in (ROOT / part).rglob("*.py")}
    profiles = ROOT / "emulator" / "firmware" / "profiles"
    return files | {f"fake_marlin/{p.relative_to(ROOT)}" for p in profiles.glob("*.toml")}


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
    installed = [name for name in names if ".dist-info/" not in name]
    assert sorted(installed) == sorted(package_files())  # each once, none missing
    assert "fake_marlin/py.typed" in names
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
        assert result.stdout.splitlines()[0].endswith(f" {fake_marlin.__version__}")


def test_the_sdist_holds_each_file_once_under_the_import_root(tmp_path: Path) -> None:
    subprocess.run(
        [sys.executable, "-m", "build", "--sdist", "-o", str(tmp_path), str(ROOT)],
        check=True,
        capture_output=True,
    )
    (sdist,) = tmp_path.glob("fake_marlin-*.tar.gz")
    with tarfile.open(sdist) as archive:
        members = archive.getmembers()
    assert not [m.name for m in members if m.issym() or m.islnk()]  # files, not links
    names = [m.name.split("/", 1)[1] for m in members if m.isfile()]
    package = sorted(name for name in names if name.startswith("fake_marlin/")
                     and not name.startswith("fake_marlin.egg-info/"))
    assert package == sorted(package_files())
    assert {"pyproject.toml", "README.md", "LICENSE", "CHANGELOG.md"} <= set(names)


def test_from_the_checkout_without_an_install_the_parts_import_under_fake_marlin() -> None:
    # -S: no site-packages, so no editable install's finder; the checkout root is the cwd.
    check = (
        "import fake_marlin.emulator.protocols.marlin, fake_marlin.wire.gcode\n"
        "print(fake_marlin.emulator.__file__)"
    )
    result = subprocess.run(
        [sys.executable, "-S", "-c", check], cwd=ROOT, capture_output=True, text=True
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == str(ROOT / "fake_marlin" / "emulator" / "__init__.py")
