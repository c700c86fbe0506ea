"""fake-marlin's host client: stream G-code to any printer on a serial port."""

from fake_marlin.host.connect import PROTOCOLS, open_printer
from fake_marlin.host.shell import PrintSummary
from fake_marlin.host.errors import (
    CommandError,
    ConnectionLost,
    HostError,
    PortError,
    PrinterHalted,
    PrinterNotResponding,
    PrinterReset,
)

__all__ = [
    "CommandError",
    "ConnectionLost",
    "HostError",
    "PROTOCOLS",
    "PortError",
    "PrintSummary",
    "PrinterHalted",
    "PrinterNotResponding",
    "PrinterReset",
    "open_printer",
]
