"""The fault layer: damages bytes between the link and the protocol, per direction.

It sits below every protocol state machine, so the printer model never sees a fault, only the
commands that survive it. Damage is drawn from a seeded generator: a run can be repeated.

Unit faults (drop, duplicate, ...) act on what the protocol in use frames, each wire format's
framer finding its units (wire/framing.py). The server says which protocol that is
(set_protocol); until it knows, toward the printer, text lines and Ultimaker packets are units
and any other bytes pass as they come.
"""

import dataclasses
import random
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum

from fake_marlin.emulator.faults.rules import FaultKind, FaultPlan, FaultRule, stream_random
from fake_marlin.wire import (
    commstack, marlin_binary, repetier, stk500, ultimaker, ultimaker_variants, undetected,
)
from fake_marlin.wire.ultimaker_variants import PLAIN, Variants
from fake_marlin.wire.framing import Framer, split_units
from fake_marlin.wire.lines import LINES


class Direction(Enum):
    TO_PRINTER = "to-printer"
    TO_HOST = "to-host"


@dataclass(frozen=True)
class LineFaults:
    """What happens to bytes travelling one way."""

    bit_error_rate: float = 0.0  # chance that any one bit is flipped
    drop_rate: float = 0.0  # chance that any one byte is lost
    # Chance that a line gets one damaged character, never its end: mostly what a checksum
    # catches. (A damaged leading `N` makes a bare line, which Marlin runs unchecked. A damaged
    # line end leaves the printer waiting for the rest of the line, which hangs hosts with no
    # `ok` timeout, such as printcore; bit-errors includes that case.)
    line_corruption_rate: float = 0.0

    @property
    def active(self) -> bool:
        return self.bit_error_rate > 0 or self.drop_rate > 0 or self.line_corruption_rate > 0


@dataclass(frozen=True)
class FaultConfig:
    to_printer: LineFaults = field(default_factory=LineFaults)
    to_host: LineFaults = field(default_factory=LineFaults)
    seed: int = 0
    rules: tuple[FaultRule, ...] = ()


@dataclass(frozen=True)
class Segment:
    """Bytes for the other side, after a pause (a stall); then perhaps the line hangs up."""

    data: bytes = b""
    pause: float = 0.0
    hang_up: float | None = None  # seconds until the line comes back


RATE_KINDS = {  # the kinds of damage given as a rate, and the LineFaults field each sets
    "bit-errors": "bit_error_rate",
    "drop-bytes": "drop_rate",
    "corrupt-lines": "line_corruption_rate",
}
_LINE_ENDS = b"\r\n"

# Each protocol's units: (toward the printer, toward the host). None: not known yet.
FRAMERS: dict[str | None, tuple[Framer, Framer]] = {
    None: (undetected.TO_PRINTER_UNITS, LINES),
    "marlin": (marlin_binary.TO_PRINTER_UNITS, LINES),  # lines, and M28 B1's packets
    "ultimaker": (ultimaker.TO_PRINTER_UNITS, ultimaker.TO_HOST_UNITS),
    "repetier": (repetier.TO_PRINTER_UNITS, repetier.TO_HOST_UNITS),
    "commstack": (commstack.TO_PRINTER_UNITS, commstack.TO_HOST_UNITS),
    "stk500": (stk500.TO_PRINTER_UNITS, stk500.TO_HOST_UNITS),
    "g2core": (LINES, LINES),  # JSON and G-code lines both ways (a single character rides with its line)
}


def parse_fault(spec: str, config: FaultConfig) -> FaultConfig:
    """Add `DIRECTION:KIND=RATE` (e.g. `to-printer:bit-errors=1e-4`) to a configuration."""
    direction_name, _, rest = spec.partition(":")
    kind, _, value = rest.partition("=")
    try:
        direction = Direction(direction_name)
    except ValueError:
        raise ValueError(
            f"{spec!r}: the direction must be {' or '.join(d.value for d in Direction)}"
        ) from None
    if kind not in RATE_KINDS:
        raise ValueError(f"{spec!r}: the kind must be one of {', '.join(RATE_KINDS)}")
    try:
        rate = float(value)
    except ValueError:
        raise ValueError(f"{spec!r}: {value!r} is not a number") from None
    if not 0.0 <= rate <= 1.0:
        raise ValueError(f"{spec!r}: a rate is between 0 and 1")
    return with_rate(config, direction.value, RATE_KINDS[kind], rate)


def with_rate(config: FaultConfig, direction: str, field_name: str, rate: float) -> FaultConfig:
    """`config` with one rate of damage (a LineFaults field) set for one direction."""
    side = "to_printer" if direction == Direction.TO_PRINTER.value else "to_host"
    faults = dataclasses.replace(getattr(config, side), **{field_name: rate})
    return dataclasses.replace(config, **{side: faults})


@dataclass
class FaultStats:
    lines_corrupted: int = 0


class _Streams(dict[Direction, random.Random]):
    """Each direction's generator, made when it first draws: a printer without damage never
    draws, and a farm of thousands then keeps no Mersenne Twister's 2.5 KB state per stream."""

    def __init__(self, seed: int, unit: str) -> None:
        super().__init__()
        self._seed, self._unit = seed, unit

    def __missing__(self, direction: Direction) -> random.Random:
        made = self[direction] = stream_random(self._seed, f"{direction.value} {self._unit}")
        return made


class FaultLayer:
    def __init__(self, config: FaultConfig = FaultConfig()) -> None:
        self.config = config
        self.plan = FaultPlan(config.rules, config.seed)
        # Each direction's damage draws from generators of its own, byte by byte (bits, drops)
        # and line by line (corrupt lines): the same bytes get the same damage however they are
        # cut into reads, and whatever the other direction does meanwhile.
        self._byte_random = _Streams(config.seed, "bytes")
        self._line_random = _Streams(config.seed, "lines")
        self.stats = {direction: FaultStats() for direction in Direction}
        self._at_line_start = {direction: True for direction in Direction}
        self._partial = {direction: b"" for direction in Direction}
        self._link_rules = {d: self.plan.link_rules(d.value) for d in Direction}
        self._framers = self._framers_for(None)
        self.data_bits = 8  # bits per character on the line, of which bit errors flip one
        self._update_quiet()
        # Told of every fault as it fires (the trace): kind, direction, count, unit.
        self.on_fault: Callable[[str, str, int | None, bytes | None], None] | None = None

    def _update_quiet(self) -> None:
        # With no rule and no rate in a direction its bytes pass untouched: the server then
        # skips the layer altogether, so that a printer without faults pays nothing for it.
        self.quiet_to_printer = not self._link_rules[Direction.TO_PRINTER] and not (
            self.config.to_printer.active
        )
        self.quiet_to_host = not self._link_rules[Direction.TO_HOST] and not (
            self.config.to_host.active
        )

    def set_protocol(self, protocol: str | None, variants: Variants = PLAIN) -> None:
        """The protocol the connection speaks from now on (None or "auto": not known yet),
        with the protocol lab's variants (Ultimaker only): their packets are the units, and
        a 7-bit line flips one of 7 bits.

        Bytes of a unit not yet complete are framed anew by the new protocol's framer."""
        self._framers = self._framers_for(None if protocol == "auto" else protocol)
        if protocol == "ultimaker" and not variants.plain:
            self._framers[Direction.TO_PRINTER] = ultimaker_variants.to_printer_units(
                variants.packet)
        self.data_bits = variants.data_bits

    @staticmethod
    def _framers_for(protocol: str | None) -> dict[Direction, Framer]:
        if protocol not in FRAMERS:
            raise ValueError(f"no framer for protocol {protocol!r}")
        to_printer, to_host = FRAMERS[protocol]
        return {Direction.TO_PRINTER: to_printer, Direction.TO_HOST: to_host}

    def add_rule(self, rule: FaultRule) -> None:
        self.plan.add(rule)
        self._link_rules = {d: self.plan.link_rules(d.value) for d in Direction}
        self._update_quiet()

    def set_rate(self, direction: str, field_name: str, rate: float) -> None:
        self.config = with_rate(self.config, direction, field_name, rate)
        self._update_quiet()

    def new_connection(self) -> None:
        """A host (re)opened the port: half-received units belong to nobody."""
        for direction in Direction:
            self._partial[direction] = b""
            self._at_line_start[direction] = True

    def to_printer(self, data: bytes) -> list[Segment]:
        return self._carry(data, Direction.TO_PRINTER, self.config.to_printer)

    def to_host(self, data: bytes) -> list[Segment]:
        return self._carry(data, Direction.TO_HOST, self.config.to_host)

    def _carry(self, data: bytes, direction: Direction, faults: LineFaults) -> list[Segment]:
        rules = self._link_rules[direction]
        if rules:
            segments = self._apply_rules(data, direction, rules)
        else:
            segments = [Segment(data)]
        return [
            Segment(self._damage(segment.data, direction, faults), segment.pause, segment.hang_up)
            for segment in segments
        ]

    def _apply_rules(
        self, data: bytes, direction: Direction, rules: list[tuple[int, FaultRule]]
    ) -> list[Segment]:
        segments = [Segment()]
        framer = self._framers[direction]
        for unit in self._units(data, direction, framer):
            text = unit.decode("latin-1")
            out, pause, hang_up = unit, 0.0, None
            for index, rule in rules:
                if framer.is_filler(unit) or not self.plan.fires(index, text):
                    continue
                kind = rule.kind
                if self.on_fault is not None:
                    self.on_fault(kind.value, direction.value, None, unit)
                if kind is FaultKind.DROP:
                    out = b""
                elif kind is FaultKind.DUPLICATE:
                    out = out + out
                elif kind is FaultKind.TRUNCATE:
                    out = out[: rule.length or len(out) // 2]
                elif kind is FaultKind.GARBAGE:
                    out = self.plan.garbage(index) + out
                elif kind is FaultKind.STALL:
                    pause += rule.seconds
                elif kind is FaultKind.DISCONNECT:
                    hang_up = rule.seconds
            if pause:
                segments.append(Segment(pause=pause))
            last = segments[-1]
            segments[-1] = Segment(last.data + out, last.pause, hang_up)
            if hang_up is not None:
                break  # nothing more gets through a line that hangs up
        return [s for s in segments if s.data or s.pause or s.hang_up is not None]

    def _units(self, data: bytes, direction: Direction, framer: Framer) -> list[bytes]:
        """Complete units in arrival order; a unit not yet complete waits for its rest (never
        more than the framer's max_unit bytes)."""
        units, self._partial[direction] = split_units(self._partial[direction] + data, framer)
        return units

    def _damage(self, data: bytes, direction: Direction, faults: LineFaults) -> bytes:
        if not faults.active or not data:
            return data
        stats = self.stats[direction]
        if faults.line_corruption_rate:
            corrupted = stats.lines_corrupted
            data = self._corrupt_lines(data, direction, faults.line_corruption_rate, stats)
            if self.on_fault is not None and stats.lines_corrupted > corrupted:
                self.on_fault("corrupt-lines", direction.value, stats.lines_corrupted - corrupted,
                              None)
        bits = self.data_bits
        byte_error_rate = 1.0 - (1.0 - faults.bit_error_rate) ** bits
        draw = self._byte_random[direction]
        out = bytearray()
        flipped = 0
        for byte in data:
            if faults.drop_rate and draw.random() < faults.drop_rate:
                continue
            if byte_error_rate and draw.random() < byte_error_rate:
                byte ^= 1 << draw.randrange(bits)
                flipped += 1
            out.append(byte)
        if self.on_fault is not None:
            if flipped:
                self.on_fault("bit-errors", direction.value, flipped, None)
            if len(data) - len(out):
                self.on_fault("drop-bytes", direction.value, len(data) - len(out), None)
        return bytes(out)

    def _corrupt_lines(self, data: bytes, direction: Direction, rate: float, stats: FaultStats) -> bytes:
        """Each line that starts in `data` is damaged with chance `rate`, in one character."""
        out = bytearray(data)
        draw = self._line_random[direction]
        start = 0
        while start < len(out):
            end = start
            while end < len(out) and out[end] not in _LINE_ENDS:
                end += 1
            if self._at_line_start[direction] and end > start and draw.random() < rate:
                position = draw.randrange(start, end)
                while True:  # a flip that made a line end would cut the line, not damage it
                    damaged = out[position] ^ (1 << draw.randrange(8))
                    if damaged not in _LINE_ENDS:
                        break
                out[position] = damaged
                stats.lines_corrupted += 1
            self._at_line_start[direction] = end < len(out)
            start = end + 1
        return bytes(out)

