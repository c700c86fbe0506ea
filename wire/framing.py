"""How a byte stream falls into units: what a wire format calls one line, packet or frame.

Each wire format owns its framer (wire/lines.py, wire/ultimaker.py, wire/repetier.py,
wire/commstack.py, wire/stk500.py); the fault layer uses them to find the units its rules act
on. A framer is pure, with no clock: given the bytes so far and where a unit starts, it says
where that unit ends, or that it cannot tell yet. It always can once `max_unit` bytes have
come, so whoever waits on it never holds more than that: noise, or a stream that is not of the
format, costs units cut in odd places, never a stall.
"""

from collections.abc import Callable
from dataclasses import dataclass

UnitEnd = Callable[[bytes, int], int | None]


@dataclass(frozen=True)
class Framer:
    # unit_end(buffer, start): the end (exclusive, > start) of the unit that starts at `start`,
    # or None if more bytes must come to say. For the format's own units a longer buffer gets
    # the same answer, so they do not depend on how the stream was cut into reads; bytes that
    # are no unit of it may go on as far as they have come, rather than wait.
    unit_end: UnitEnd
    max_unit: int  # unit_end decides once this many bytes from `start` have come
    # Bytes that alone make no unit worth a fault (line ends between lines, NULs between
    # Repetier commands): they pass, uncounted, as a blank line always has.
    filler: bytes = b""

    def is_filler(self, unit: bytes) -> bool:
        return bool(self.filler) and not unit.strip(self.filler)


def split_units(buffer: bytes, framer: Framer) -> tuple[list[bytes], bytes]:
    """The whole units at the start of `buffer`, in order, and the rest, which waits for more.

    The rest is always shorter than `framer.max_unit`: a framer that would wait longer (none of
    ours does) has its unit cut there.
    """
    units = []
    position = 0
    while position < len(buffer):
        end = framer.unit_end(buffer, position)
        if end is None:
            if len(buffer) - position < framer.max_unit:
                break
            end = position + framer.max_unit
        elif end <= position:
            raise ValueError(f"a framer ended a unit at {end}, not after its start {position}")
        units.append(buffer[position:end])
        position = end
    return units, buffer[position:]
