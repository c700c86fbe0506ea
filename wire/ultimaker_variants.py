"""The protocol lab's variants of Ultimaker's protocol (docs/protocols.md section 1.1), shared
by both ends: seed 000's "possible improvements", each opt-in on both sides.

- `ack` (seed 1): the printer answers `a` SS PP CC the moment a packet enters its command
  queue; `o` then means only "executed".
- `compact-oob` (seed 4): out-of-band lines start `p:`, `e:`, `w:`, `l:` instead of
  `\\nProtoError:`, `\\nError:`, `WARNING:`, `LOG:`.
- `crc8` (seed 5): one start byte instead of two, and CRC-8/SMBUS instead of CRC-16.
- `sync-byte` (seed 7): the start byte is SYN (0x16), and it never occurs inside a packet:
  every other byte is a character 0x20..0x7F (sequence number, length and check carried as
  characters).
- `7bit` (seed 8): 7 data bits per character on the line (7N1: 9 bit times, not 10); needs
  every byte below 0x80, so its packets are sync-byte's.

Plain v3 (no variant) is byte for byte what wire/ultimaker.py says.
"""

from collections.abc import Sequence
from dataclasses import dataclass, field

from fake_marlin.wire import ultimaker as v3
from fake_marlin.wire.checksums import crc8_smbus, crc16_ccitt_false
from fake_marlin.wire.framing import Framer
from fake_marlin.wire.lines import MAX_LINE, line_end

NAMES = ("ack", "compact-oob", "crc8", "sync-byte", "7bit")
SYN = 0x16  # ASCII "synchronous idle": the start byte of sync-byte and 7bit
CHAR_MIN, CHAR_MAX = 0x20, 0x7F  # what every byte of a sync-byte packet but its start is
ARMORED_SEQUENCE_MODULUS = 96  # 0x20 + seq stays a character: 0..95
CHECK_DIGIT_BASE = 0x40  # a check is sent 6 bits per character, 0x40 + bits: 0x40..0x7F
CHECK_DIGIT_BITS = 6
BOOT_LINE = "Marlin started"  # the printer's first LOG line (UltimakerMarlin's)
# A printer with variants names them in that line: "Marlin started; protocol variants: ack".
ANNOUNCEMENT = BOOT_LINE + "; protocol variants: "


class VariantError(ValueError):
    """A variant list the caller gave that names no variant (the message says which)."""


@dataclass(frozen=True, order=True)
class Variants:
    ack: bool = False
    compact_oob: bool = False
    crc8: bool = False
    sync_byte: bool = False
    seven_bit: bool = False

    @property
    def names(self) -> tuple[str, ...]:
        flags = (self.ack, self.compact_oob, self.crc8, self.sync_byte, self.seven_bit)
        return tuple(name for name, on in zip(NAMES, flags) if on)

    @property
    def plain(self) -> bool:
        return not self.names

    def __str__(self) -> str:
        return ",".join(self.names) or "v3"

    @property
    def packet(self) -> "PacketFormat":
        armored = self.sync_byte or self.seven_bit
        return PacketFormat(
            start=SYN if armored else v3.HEADER_BYTE,
            starts=1 if self.crc8 else 2,
            armored=armored,
            check_bits=8 if self.crc8 else 16,
        )

    @property
    def data_bits(self) -> int:
        return 7 if self.seven_bit else 8


PLAIN = Variants()
# Every set of variants, 32: bit k of the index is NAMES[k] (1 ack, 2 compact-oob, 4 crc8,
# 8 sync-byte, 16 7bit). For the tests and the fuzz targets, which try them all.
EVERY_SET = tuple(Variants(*(bool(index >> bit & 1) for bit in range(len(NAMES))))
                  for index in range(1 << len(NAMES)))


def parse_variants(text: str | None) -> Variants:
    """`ack,compact-oob` -> Variants; '' or None or `v3` -> plain; VariantError for the rest."""
    names = [name.strip() for name in (text or "").split(",") if name.strip()]
    if names == ["v3"]:
        return PLAIN
    unknown = [name for name in names if name not in NAMES]
    if unknown:
        raise VariantError(f"unknown protocol variant {', '.join(map(repr, unknown))}; "
                           f"choose from {', '.join(NAMES)} (comma-separated)")
    return Variants(*(name in names for name in NAMES))


def variants_of(value: "str | Variants | Sequence[str] | None") -> Variants:
    """What a library caller may pass as `variants=`: a Variants, names, or `ack,crc8`."""
    if isinstance(value, Variants):
        return value
    if value is None or isinstance(value, str):
        return parse_variants(value)
    return parse_variants(",".join(value))


@dataclass(frozen=True)
class PacketFormat:
    """How a host->printer packet is laid out: start bytes, seq, len, payload, check."""

    start: int
    starts: int  # 1 or 2 start bytes
    armored: bool  # seq, len and check carried as characters 0x20..0x7F (sync-byte, 7bit)
    check_bits: int  # 16: CRC-16/CCITT-FALSE, 8: CRC-8/SMBUS; over seq, len, payload
    # Plain v3's layout (wire/ultimaker.py's own code then encodes it): set once, since the
    # host asks for every packet it sends.
    is_v3: bool = field(init=False, compare=False, repr=False)

    def __post_init__(self) -> None:
        plain = (self.start, self.starts, self.armored, self.check_bits) == (
            v3.HEADER_BYTE, 2, False, 16)
        object.__setattr__(self, "is_v3", plain)

    @property
    def sequence_modulus(self) -> int:
        return ARMORED_SEQUENCE_MODULUS if self.armored else v3.SEQUENCE_MODULUS

    @property
    def check_chars(self) -> int:
        if self.armored:
            return -(-self.check_bits // CHECK_DIGIT_BITS)
        return self.check_bits // 8

    def check(self, seq: int, payload: bytes) -> int:
        data = bytes((seq, len(payload))) + payload
        return crc8_smbus(data) if self.check_bits == 8 else crc16_ccitt_false(data)

    def seq_byte(self, seq: int) -> int:
        return CHAR_MIN + seq if self.armored else seq

    def len_byte(self, length: int) -> int:
        return CHAR_MIN - 1 + length if self.armored else length

    def read_seq(self, byte: int) -> int | None:
        """The sequence number a seq byte carries, or None if no packet has that byte there."""
        if self.armored:
            value = byte - CHAR_MIN
            return value if 0 <= value < ARMORED_SEQUENCE_MODULUS else None
        return byte if byte < v3.SEQUENCE_MODULUS else None

    def read_len(self, byte: int) -> int:
        """The length a len byte carries (0 or above MAX_PAYLOAD: none a packet has)."""
        return byte - (CHAR_MIN - 1) if self.armored else byte

    def check_bytes(self, value: int) -> bytes:
        if not self.armored:
            return value.to_bytes(self.check_chars, "big")
        return bytes(CHECK_DIGIT_BASE + (value >> (CHECK_DIGIT_BITS * place) & 0x3F)
                     for place in reversed(range(self.check_chars)))

    def read_check(self, data: bytes) -> int | None:
        """The check value in its bytes, or None if they are no check's bytes."""
        if not self.armored:
            return int.from_bytes(data, "big")
        value = 0
        for byte in data:
            digit = byte - CHECK_DIGIT_BASE
            if not 0 <= digit < 1 << CHECK_DIGIT_BITS:
                return None
            value = value << CHECK_DIGIT_BITS | digit
        return value if value < 1 << self.check_bits else None

    def encode(self, seq: int, payload: bytes) -> bytes:
        """One packet; the caller has checked payload_error(payload) and the sequence number."""
        if self.is_v3:
            return v3.encode_packet(seq, payload)
        return (bytes((self.start,) * self.starts)
                + bytes((self.seq_byte(seq), self.len_byte(len(payload)))) + payload
                + self.check_bytes(self.check(seq, payload)))

    def next_seq(self, seq: int, step: int = 1) -> int:
        return (seq + step) % self.sequence_modulus

    def seq_distance(self, from_seq: int, to_seq: int) -> int:
        return (to_seq - from_seq) % self.sequence_modulus

    def packet_end(self, buffer: bytes, start: int) -> int | None:
        """For the fault layer: where the packet at `start` (at a start byte) ends; None if
        it is not all here. Anything that cannot be a packet ends at once, a unit of noise.
        (Plain v3's framer is wire/ultimaker.py's: to_printer_units.)"""
        header = start + self.starts
        if len(buffer) < header + 2:
            whole = buffer[start:header]
            return None if whole == bytes((self.start,)) * len(whole) else start + 1
        if any(byte != self.start for byte in buffer[start:header]):
            return start + 1
        length = self.read_len(buffer[header + 1])
        if not 1 <= length <= v3.MAX_PAYLOAD:
            return header + 2
        end = header + 2 + length + self.check_chars
        return end if end <= len(buffer) else None


V3_PACKET = PacketFormat(start=v3.HEADER_BYTE, starts=2, armored=False, check_bits=16)


def boot_line(variants: Variants) -> str:
    """The text of the printer's boot line: plain v3's, or naming its variants."""
    return BOOT_LINE if variants.plain else ANNOUNCEMENT + ",".join(variants.names)


def announced(text: str) -> Variants | None:
    """The variants a boot line's text (without its prefix) names; None if it is no boot line
    (one damaged on the way, say)."""
    if text == BOOT_LINE:
        return PLAIN
    if not text.startswith(ANNOUNCEMENT):
        return None
    try:
        return parse_variants(text[len(ANNOUNCEMENT):])
    except VariantError:
        return None


# -- printer->host lines -------------------------------------------------------------------
COMPACT_PREFIXES = {"ProtoError": "p:", "Error": "e:", "WARNING": "w:", "LOG": "l:"}
DATA_ESCAPE = "d:"  # before a response line that would look like a compact out-of-band line
ESCAPED = tuple(COMPACT_PREFIXES.values()) + (DATA_ESCAPE,)
ACK_KIND = "a"


def response_line(text: str, variants: Variants) -> str:
    """A response data line as compact-oob sends it (escaped if it looks out of band)."""
    if variants.compact_oob and text.startswith(ESCAPED):
        return DATA_ESCAPE + text
    return text


# -- units, for the fault layer (wire/framing.py) -------------------------------------------
def to_printer_units(packet: PacketFormat) -> Framer:
    """Packets, and lines between them, in this format (plain v3's own framer for v3)."""
    if packet.is_v3:
        return v3.TO_PRINTER_UNITS
    start_byte = bytes((packet.start,))

    def unit_end(buffer: bytes, start: int) -> int | None:
        if buffer[start] == packet.start:
            return packet.packet_end(buffer, start)
        end = line_end(buffer, start)
        header = buffer.find(start_byte, start, end if end is not None else len(buffer))
        return header if header > start else end

    return Framer(unit_end, MAX_LINE, filler=b"\r\n")
