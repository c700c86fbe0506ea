"""fake-marlin's host client: stream G-code to any printer on a serial port.

    async with open_printer("/dev/ttyACM0", protocol="marlin") as printer:
        print(await printer.send("M105"))
        summary = await printer.print_file("part.gcode")
"""

from fake_marlin.host.connect import DEFAULT_BAUDRATE, PROTOCOLS, connect, load_job, open_printer
from fake_marlin.host.cores.base import PrinterLine, Stats
from fake_marlin.host.cores.queue import Ticket
from fake_marlin.host.errors import (
    CommandError,
    CommandFailed,
    ConnectionLost,
    HostError,
    PortError,
    PrinterHalted,
    PrinterLocked,
    PrinterNotResponding,
    PrinterReset,
    RemoteError,
    UploadFailed,
    UsageError,
    VariantMismatch,
)
from fake_marlin.wire.ultimaker_variants import Variants
from fake_marlin.host.shell import (
    ByteStream,
    Client,
    ClientOptions,
    LineCallback,
    PrintSummary,
    ProgressCallback,
    StreamingClient,
)

__all__ = [
    "DEFAULT_BAUDRATE",
    "PROTOCOLS",
    "ByteStream",
    "Client",
    "ClientOptions",
    "CommandError",
    "CommandFailed",
    "ConnectionLost",
    "HostError",
    "LineCallback",
    "PortError",
    "PrintSummary",
    "PrinterHalted",
    "PrinterLine",
    "PrinterLocked",
    "PrinterNotResponding",
    "PrinterReset",
    "ProgressCallback",
    "RemoteError",
    "Stats",
    "StreamingClient",
    "Ticket",
    "UploadFailed",
    "UsageError",
    "VariantMismatch",
    "Variants",
    "connect",
    "load_job",
    "open_printer",
]
