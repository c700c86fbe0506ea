"""Each printer's identity: its UUID, serial number and machine name.

A farm manager tells printers apart by these, so no two printers share them: each follows from
the seed and the printer's number (the same on every run), unless a profile, a farm file or the
library sets it. The profile says how a serial number and a machine name are written
(`[identity] serial`, `machine_name`: templates of the values below).
"""

import hashlib
import string
import uuid
from dataclasses import dataclass


@dataclass(frozen=True)
class Identity:
    uuid: str
    serial: str
    machine_name: str


def _values(seed: int, number: int) -> dict[str, object]:
    """What a serial number or machine name template may use: the printer's number, and
    digits, letters and hex drawn from a hash of the seed and number."""
    digest = hashlib.sha256(f"fake-marlin identity {seed} {number}".encode()).digest()
    pick = int.from_bytes(digest[16:], "big")
    values: dict[str, object] = {"number": number, "hex": digest.hex().upper()}
    for name in "abcd":
        pick, values[name] = divmod(pick, 100_000)
    values["letter"] = string.ascii_uppercase[pick % 26]
    return values


def make_identity(seed: int, number: int, uuid_text: str, serial: str,
                  machine_name: str) -> Identity:
    """The identity of printer `number`: each of `uuid_text`, `serial` and `machine_name` is
    a template ("" for the UUID: drawn from the seed and number)."""
    digest = hashlib.sha256(f"fake-marlin uuid {seed} {number}".encode()).digest()
    values = _values(seed, number)
    return Identity(
        uuid=uuid_text.format(**values) if uuid_text else str(uuid.UUID(bytes=digest[:16], version=4)),
        serial=serial.format(**values),
        machine_name=machine_name.format(**values),
    )


SAMPLE_VALUES = _values(0, 1)  # for checking a profile's templates when it is loaded
