"""Text lines, the unit of Marlin's ASCII protocol both ways (docs/protocols.md section 6), of
every printer's replies but CommStack's and STK500's, and of Repetier's ASCII commands."""

from fake_marlin.wire.framing import Framer

# Longer than any line a printer keeps (Marlin keeps 95 characters, Repetier 96) or says (M115's
# first line is about 250): a "line" this long without its end is noise, cut here as a unit.
MAX_LINE = 512


def line_end(buffer: bytes, start: int, ends: bytes = b"\n", limit: int = MAX_LINE) -> int | None:
    """Just past the first byte of `ends` from `start`, or `limit` bytes on if none comes in
    them; None while neither has come."""
    stop = min(len(buffer), start + limit)
    found = [at for at in (buffer.find(end, start, stop) for end in ends) if at >= 0]
    if found:
        return min(found) + 1
    return start + limit if len(buffer) - start >= limit else None


LINES = Framer(line_end, MAX_LINE, filler=b"\r\n")
