"""fake-marlin's host client: stream G-code to any printer on a serial port."""

from host.client import PrintSummary, open_printer
from host.errors import CommandError, ConnectionLost, HostError, PortError, PrinterNotResponding

__all__ = [
    "CommandError",
    "ConnectionLost",
    "HostError",
    "PortError",
    "PrintSummary",
    "PrinterNotResponding",
    "open_printer",
]
