"""fake-marlin's host client: stream G-code to any printer on a serial port."""

from host.client import PROTOCOLS, PrintSummary, open_printer
from host.errors import (
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
