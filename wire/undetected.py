"""Units toward a printer whose protocol is not known yet (`--protocol auto` before its first
decisive bytes, or after the bootloader hands over): Ultimaker packets and text lines, which
wait for their end, and any other bytes, which wait for nothing.

Binary bytes may be a Repetier command, a CommStack frame or an STK500 message: which one is
what auto-detection is about to find out from them, so they cannot wait for a framer of their
own; they go on as a unit as they come. Once the protocol is known its own framer takes over.
"""

import re

from fake_marlin.wire import ultimaker
from fake_marlin.wire.framing import Framer
from fake_marlin.wire.lines import MAX_LINE

_NOT_TEXT = re.compile(rb"[^\t\n\r\x20-\x7e]")


def unit_end(buffer: bytes, start: int) -> int | None:
    if buffer[start] == ultimaker.HEADER_BYTE:
        return ultimaker.packet_end(buffer, start)
    stop = min(len(buffer), start + MAX_LINE)
    binary = _NOT_TEXT.search(buffer, start, stop)
    if binary is not None and binary.start() == start:
        # Up to the end of a line, if one came: text after it may be a host that just started.
        newline = buffer.find(b"\n", start, stop)
        return newline + 1 if newline >= 0 else stop
    end = ultimaker.text_end(buffer, start)
    if binary is not None and (end is None or binary.start() < end):
        return binary.start()  # a text line that turns binary is none
    return end


TO_PRINTER_UNITS = Framer(unit_end, MAX_LINE, filler=b"\r\n")
