"""fake-marlin's pytest plugin (registered with the `pytest11` entry point, so a project that
installs fake-marlin has these fixtures at once):

- `fake_printer`: a virtual printer with default settings on a real pty, for one test.
- `fake_printer_factory(**options)`: more printers, each on its own pty, with options that mirror
  the command line (see fake_marlin.testing.PrinterOptions); all are stopped at teardown.

A printer that crashed fails the test at teardown with its stderr.
"""

from collections.abc import Iterator
from typing import Protocol, Unpack

import pytest

from fake_marlin.testing import FakePrinter, PrinterCrashed, PrinterOptions, start_printer


class PrinterFactory(Protocol):
    def __call__(self, **options: Unpack[PrinterOptions]) -> FakePrinter: ...


@pytest.fixture
def fake_printer_factory() -> Iterator[PrinterFactory]:
    started: list[FakePrinter] = []

    def start(**options: Unpack[PrinterOptions]) -> FakePrinter:
        started.append(start_printer(**options))
        return started[-1]

    yield start
    crashes = []
    for printer in started:
        try:
            printer.stop()
        except PrinterCrashed as crash:
            crashes.append(f"fake_printer on {printer.port}: {crash}")
    if crashes:
        pytest.fail("\n\n".join(crashes), pytrace=False)


@pytest.fixture
def fake_printer(fake_printer_factory: PrinterFactory) -> FakePrinter:
    return fake_printer_factory()
