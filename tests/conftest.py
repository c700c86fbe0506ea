from contextlib import AbstractAsyncContextManager

from fake_marlin.emulator.printer.model import Printer
from fake_marlin.emulator.server.lifecycle import ServerConfig
from fake_marlin.testing import MemoryPrinter, serve_in_memory


def running_printer(
    config: ServerConfig = ServerConfig(protocol="ultimaker"), printer: Printer | None = None
) -> AbstractAsyncContextManager[MemoryPrinter]:
    """A printer on an in-memory link, for the length of the block (our own tests' spelling of
    fake_marlin.testing.serve_in_memory, with an Ultimaker printer by default)."""
    return serve_in_memory(config, printer or Printer())
