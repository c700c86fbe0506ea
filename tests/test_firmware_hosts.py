"""Real hosts against each shipped firmware: OctoPrint's comm layer connects to every one, reads
its name as it reads the real one's, and prints a job exactly once, with each quirk on in turn
on Marlin; printcore prints to each ASCII firmware (every profile that speaks `marlin`).

The cells are tests/hosts/matrix.py's (`python -m tests.hosts.matrix` runs all of them, every
firmware with every quirk, and prints the table docs/firmwares.md carries): a `fake-marlin`
process each, the printer's journal verified against the job. All of OctoPrint's cells of a
group go through one driver process (its start-up costs seconds), each a fresh MachineCom.
A quirk a host does not survive is a finding, not a failure of ours: the tables below say what
each host does, as found, and the test checks that it still does exactly that, so that a change
either way (a host that now survives, or fails differently) fails here and gets looked at.
The hosts' venvs come from `python -m tests.hosts.install`; without them the tests skip.
"""

import json
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from fake_marlin.emulator.firmware import load_profile, shipped
from fake_marlin.emulator.firmware.profile import SAMPLE_CONTEXT
from fake_marlin.emulator.printer.statements import CATALOG
from tests.hosts import matrix
from tests.hosts.install import not_installed

pytestmark = pytest.mark.e2e

FIRMWARES = shipped()  # at collection time: the profiles in the tree now
ASCII_FIRMWARES = [name for name in FIRMWARES if "marlin" in load_profile(name).protocols]
ROWS = {variant.name: variant for variant in matrix.variants()}
NONE = ROWS["none"]
# OctoPrint 1.11's firmware detection (util/comm.py, _monitor: "firmware name & version"): the
# words it looks for in FIRMWARE_NAME to switch on what that firmware needs.
OCTOPRINT_DETECTS = ("repetier", "anet_a8", "reprapfirmware", "malyan", "teacup", "klipper",
                     "ultimaker2", "prusa-firmware")
# OctoPrint's regex_firmware_splitter (util/comm.py), which parse_firmware_line() splits M115 by.
FIRMWARE_SPLITTER = re.compile(r"(^|\s+)([A-Z][A-Z0-9_]*):")


@dataclass(frozen=True)
class Finding:
    """What a host does in a cell it does not survive, as found: why, and how to recognise it."""

    reason: str
    matches: Callable[[matrix.Result], bool]


def nothing_ran(result: matrix.Result) -> bool:
    jobs = result.verification.job_commands if result.verification else -1
    return result.counts() == {"missing": jobs}


# OctoPrint 1.11 on Marlin 2.1, the quirk's row -> what it does, where it does not print the job
# exactly once (docs/firmwares.md, the matrix's findings).
OCTOPRINT_ON_MARLIN: dict[str, Finding] = {
    "password=1234+locked=true": Finding(
        "OctoPrint knows nothing of PASSWORD_FEATURE: every line, M110 and M115 too, is answered "
        "`echo:Printer locked! (Unlock with M511 or LCD)` and `ok`, and the `ok` is all it looks "
        "at. It never reads the firmware's name (no FIRMWARE_NAME line comes), streams the job "
        "and calls it done; the printer ran none of it.",
        lambda r: (r.host_done and not r.hang and not r.host_errors and nothing_ran(r)
                   and r.report.get("firmware_name") is None)),
}
# printcore on each ASCII firmware, with no quirk: the firmware -> what it does, where it does
# not print the job exactly once. None so far: printcore's findings are quirks' (a dropped `ok`
# hangs it for good, a locked printer takes the job and runs none of it), which only the matrix
# runs: a hang costs the whole 80 s.
PRINTCORE_ON: dict[str, Finding] = {}


def describe(result: matrix.Result) -> str:
    """The cell and what the host and the printer said, for an assertion message."""
    report = {key: value for key, value in result.report.items()
              if key not in ("sent", "received", "wire", "log", "temperatures", "states")}
    return "\n".join([f"{result.cell}: {result.text()}", *result.details(),
                      json.dumps(report, indent=1)[:3000]])


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> matrix.Workspace:
    return matrix.make_workspace(tmp_path_factory.mktemp("matrix"), matrix.HOSTS.values())


def python_of(workspace: matrix.Workspace, host: matrix.Host) -> Path:
    if host.name not in workspace.pythons:
        pytest.skip(not_installed(host.venv.label))
    return workspace.pythons[host.name]


@pytest.fixture(scope="module")
def octoprint(workspace) -> Callable[[list[matrix.Cell]], dict[matrix.Cell, matrix.Result]]:
    """Runs a group of cells through one OctoPrint driver process."""
    python = python_of(workspace, matrix.OCTOPRINT)
    drivers: list[matrix.OctoPrint] = []

    def run(cells: list[matrix.Cell]) -> dict[matrix.Cell, matrix.Result]:
        driver = matrix.OctoPrint(python, workspace.directory / f"octoprint-{len(drivers)}.stderr")
        drivers.append(driver)
        try:
            return {cell: matrix.run_cell(cell, workspace, driver) for cell in cells}
        finally:
            driver.close()

    return run


@pytest.fixture(scope="module")
def every_firmware(octoprint) -> dict[str, matrix.Result]:
    """(a) OctoPrint prints the job to every shipped firmware, no quirk on."""
    cells = [matrix.Cell(firmware, NONE, "octoprint") for firmware in FIRMWARES]
    return {cell.firmware: result for cell, result in octoprint(cells).items()}


@pytest.fixture(scope="module")
def every_quirk_on_marlin(octoprint) -> dict[str, matrix.Result]:
    """(b) OctoPrint prints the job to Marlin with each quirk on in turn."""
    cells = [matrix.Cell("marlin", variant, "octoprint") for variant in ROWS.values()]
    return {cell.variant.name: result for cell, result in octoprint(cells).items()}


def m115_name(firmware: str) -> str | None:
    """FIRMWARE_NAME as OctoPrint parses it from the profile's own M115 lines."""
    profile = load_profile(firmware)
    values = {**SAMPLE_CONTEXT, **CATALOG["firmware_info"], "version": profile.version,
              "date": profile.date, "machine_type": profile.machine_type, "firmware": profile.name}
    for template in profile.templates["firmware_info"]["lines"]:
        line = template.format(**values)
        if "FIRMWARE_NAME:" in line:
            parts = FIRMWARE_SPLITTER.split(line.strip())[1:]
            fields = {parts[i + 1]: parts[i + 2].strip() for i in range(0, len(parts) - 2, 3)}
            return fields.get("FIRMWARE_NAME")
    return None


def test_the_matrix_covers_every_quirk():
    """A quirk added to quirks.py gets a row of its own (the matrix and the tests below)."""
    from fake_marlin.emulator.firmware.quirks import NAMES

    covered = {name for variant in ROWS.values() for name in variant.quirks}
    assert covered == set(NAMES)


@pytest.mark.parametrize("firmware", FIRMWARES)
def test_octoprint_names_and_prints_to_every_firmware(every_firmware, firmware):
    result = every_firmware[firmware]
    if result.na:
        pytest.skip(result.na)
    assert result.ok, describe(result)
    # The name OctoPrint read is the one the real firmware's M115 gives it...
    expected = m115_name(firmware)
    assert expected, f"{firmware}'s M115 says no FIRMWARE_NAME"
    name = result.report["firmware_name"]
    assert name == expected, describe(result)
    # ... so its detection does for this firmware what it does for the real one.
    detected = [note for note in result.report["notes"] if note.startswith("Detected ")]
    if any(word in expected.lower() for word in OCTOPRINT_DETECTS):
        assert detected, f"OctoPrint did not recognise {name!r}: {result.report['notes']}"
    else:
        assert not detected, detected
    # M115's capabilities are the profile's own.
    profile = load_profile(firmware)
    if profile.templates["firmware_info"]["capability"] != ("",):
        assert result.report["capabilities"] == dict(profile.capabilities), describe(result)


def test_octoprint_reads_the_firmware_names_hosts_look_for(every_firmware):
    """The names as a person knows them, for the firmwares that are in the tree now."""
    families = {"marlin": "Marlin", "marlin-1.1": "Marlin 1.1", "prusa": "Prusa-Firmware",
                "klipper": "Klipper", "reprapfirmware": "RepRapFirmware",
                "smoothieware": "Smoothieware", "repetier": "Repetier",
                "ultimaker2": "Ultimaker2"}
    for firmware, result in every_firmware.items():
        word = families.get(firmware)
        if word is not None and not result.na:
            assert word in (result.report.get("firmware_name") or ""), describe(result)


@pytest.mark.parametrize("row", list(ROWS))
def test_octoprint_with_each_quirk_on_marlin(every_quirk_on_marlin, row):
    result = every_quirk_on_marlin[row]
    if result.na:
        pytest.skip(result.na)
    assert not result.trouble, describe(result)
    finding = OCTOPRINT_ON_MARLIN.get(row)
    if finding is None:
        assert result.ok, describe(result)
    else:
        assert not result.ok, f"OctoPrint now survives {row}: {result.text()} (the finding was: " \
                              f"{finding.reason})"
        assert finding.matches(result), f"not the documented finding ({finding.reason}):\n" \
                                        f"{describe(result)}"


@pytest.mark.parametrize("firmware", ASCII_FIRMWARES)
def test_printcore_prints_to_each_ascii_firmware(workspace, firmware):
    python_of(workspace, matrix.PRINTCORE)
    result = matrix.run_cell(matrix.Cell(firmware, NONE, "printcore"), workspace)
    assert not result.trouble, describe(result)
    finding = PRINTCORE_ON.get(firmware)
    if finding is None:
        assert result.ok, describe(result)
    else:
        assert not result.ok, f"printcore now prints to {firmware}: {result.text()}"
        assert finding.matches(result), f"not the documented finding ({finding.reason}):\n" \
                                        f"{describe(result)}"
