"""`fake-marlin`'s command line: one parser, the printer by default, its commands."""

import subprocess
import sys

from fake_marlin.emulator.bench import cli as bench_cli
from fake_marlin.emulator.cli import scenario as scenario_cli


def _imported_by_the_parser() -> set[str]:
    """The modules a fresh interpreter has loaded once the command line's modules are imported."""
    code = ("import sys; import fake_marlin.emulator.bench.cli, fake_marlin.emulator.cli.scenario, "
            "fake_marlin.emulator.cli.verify, fake_marlin.emulator.cli.report; "
            "print('\\n'.join(sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return set(done.stdout.split())


def test_the_names_written_out_for_the_parser_are_those_the_code_runs():
    from fake_marlin.emulator.bench.measure import SECTIONS
    from fake_marlin.emulator.scenario.fuzz import PROTOCOLS

    assert bench_cli.SECTIONS == tuple(SECTIONS)
    assert scenario_cli.FUZZ_PROTOCOLS == PROTOCOLS


def test_the_commands_import_what_they_run_only_when_they_run_it():
    loaded = _imported_by_the_parser()
    for heavy in ("fake_marlin.emulator.bench.measure", "fake_marlin.emulator.scenario.run",
                  "fake_marlin.emulator.scenario.campaign", "fake_marlin.emulator.journal.verify",
                  "fake_marlin.emulator.report.build", "matplotlib", "trio"):
        assert heavy not in loaded
