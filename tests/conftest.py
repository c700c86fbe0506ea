import io
from contextlib import asynccontextmanager

import trio
import trio.testing

from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.link.memory import MemoryLink
from fake_marlin.emulator.printer.model import Printer
from fake_marlin.emulator.server.lifecycle import PrinterServer, ServerConfig


class RunningPrinter:
    def __init__(self, link: MemoryLink, server: PrinterServer, journal_text: io.StringIO) -> None:
        self.link = link
        self.server = server
        self._journal_text = journal_text

    @property
    def journal(self) -> list[str]:
        return self._journal_text.getvalue().splitlines()


@asynccontextmanager
async def running_printer(config: ServerConfig = ServerConfig(protocol="ultimaker"), printer=None):
    """A printer on an in-memory link, for the length of the block."""
    link = MemoryLink()
    journal_text = io.StringIO()
    server = PrinterServer(link, printer or Printer(), Journal(journal_text), config)
    async with trio.open_nursery() as nursery:
        nursery.start_soon(server.run)
        # Power-on completes before any host opens the port, as on a real desk.
        await trio.testing.wait_all_tasks_blocked()
        yield RunningPrinter(link, server, journal_text)
        nursery.cancel_scope.cancel()
