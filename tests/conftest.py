from contextlib import AbstractAsyncContextManager
from pathlib import Path

import pytest

from fake_marlin.emulator.printer.model import Printer
from fake_marlin.emulator.scenario.definition import load
from fake_marlin.emulator.scenario.run import ScenarioResult, run_scenario
from fake_marlin.emulator.server.lifecycle import ServerConfig
from fake_marlin.testing import MemoryPrinter, serve_in_memory
from tests.hosts import apt, npm
from tests.hosts.install import not_installed


def running_printer(
    config: ServerConfig = ServerConfig(protocol="ultimaker"), printer: Printer | None = None
) -> AbstractAsyncContextManager[MemoryPrinter]:
    """A printer on an in-memory link, for the length of the block (our own tests' spelling of
    fake_marlin.testing.serve_in_memory, with an Ultimaker printer by default)."""
    return serve_in_memory(config, printer or Printer())


class ScenarioRuns:
    """Shipped scenarios run once a session, plain and traced: a run is a pure function of its
    file (test_determinism), so the tests that look at the same run share it. Results are
    shared objects: read them, never change them."""

    def __init__(self, traces: Path) -> None:
        self._traces = traces
        self._plain: dict[Path, ScenarioResult] = {}
        self._traced: dict[Path, tuple[ScenarioResult, Path]] = {}

    def plain(self, path: Path) -> ScenarioResult:
        path = path.resolve()
        if path not in self._plain:
            self._plain[path] = run_scenario(load(path))
        return self._plain[path]

    def traced(self, path: Path) -> tuple[ScenarioResult, Path]:
        """The run with its wire trace (gzip-compressed, as a field report would come)."""
        path = path.resolve()
        if path not in self._traced:
            trace = self._traces / f"{path.stem}.trace.jsonl.gz"
            self._traced[path] = run_scenario(load(path), str(trace)), trace
        return self._traced[path]


@pytest.fixture(scope="session")
def scenario_runs(tmp_path_factory: pytest.TempPathFactory) -> ScenarioRuns:
    return ScenarioRuns(tmp_path_factory.mktemp("traces"))


@pytest.fixture(scope="session")
def browser() -> tuple[npm.Install, str]:
    """Headless Chromium and playwright-core to drive it (the browser tests), or a skip saying
    which is not installed."""
    chromium = apt.find(apt.CHROMIUM)
    if chromium is None:
        pytest.skip(not_installed(apt.CHROMIUM.label))
    install = npm.find(npm.PLAYWRIGHT)
    if install is None:
        pytest.skip(not_installed(npm.PLAYWRIGHT.label))
    return install, chromium

