"""Quirks: the ways real firmware departs from what a host expects, each a switch.

A profile sets them (its `[quirks]` table), a scenario or a farm file's printer overrides them
(`[printer.quirks]`), and the control channel turns them on and off while a host is connected
(`{"op": "quirks", "set": {...}}`). docs/firmwares.md says what each does to the hosts.
"""

import dataclasses
from dataclasses import dataclass

from fake_marlin.emulator.tables import TableReader


@dataclass(frozen=True)
class Quirks:
    # Marlin before 1.1 and some forks: `ok` first, then what the command printed.
    ok_before_output: bool = False
    # A resend request answered with two `ok`s (the error's and the resend's): a host that
    # counts them as two free slots sends a line too many.
    extra_ok_after_resend: bool = False
    # `Resend: N` with no `ok` after it (OctoPrint's "brokenResend").
    resend_without_ok: bool = False
    # Every Nth `ok` is never sent (0: none is dropped); the host must time out and poll.
    drop_ok_every: int = 0
    # Seconds between `busy:` lines while a command holds the queue; None: the firmware's own
    # ([busy] interval of the profile); 0: none.
    busy_interval: float | None = None
    # M112 is not known: no emergency parser, and the queued M112 is an unknown command.
    no_m112: bool = False
    # M29 ends the file with `Done saving file.` and no `ok` (most Marlin 1.x in the wild).
    broken_m29: bool = False
    # Line numbers and checksums are not checked: every line is taken as it comes.
    unchecked_line_numbers: bool = False
    # Marlin's PASSWORD_FEATURE: "" is none (M510-M512 unknown); a password makes M510 lock,
    # M511 P<password> unlock, M512 change it.
    password: str = ""
    # Locked at power-up (PASSWORD_ON_STARTUP): nothing but M511 runs until it is unlocked.
    locked: bool = False
    # EEPROM_SETTINGS: M500 stores, M501 loads, M502 resets, M503 reports; stored settings
    # outlive resets (and the process, with an EEPROM file).
    eeprom: bool = True


NAMES = tuple(field.name for field in dataclasses.fields(Quirks))
# What a quirk that is more than a switch takes (the others are true or false).
KINDS: dict[str, type | tuple[type, ...]] = {
    "drop_ok_every": int, "busy_interval": (int, float), "password": str,
}


def read_quirks(table: TableReader, base: Quirks) -> Quirks:
    """`base` with what a `[quirks]` table sets; each key checked, unknown keys refused."""
    changes: dict[str, object] = {}
    for name in NAMES:
        kind = KINDS.get(name, bool)
        minimum = 0 if name in ("drop_ok_every", "busy_interval") else None
        value = table.get(name, kind, None, minimum=minimum)
        if value is not None:
            changes[name] = float(value) if name == "busy_interval" else value
    table.finish()
    quirks = dataclasses.replace(base, **changes)  # type: ignore[arg-type]
    if quirks.locked and not quirks.password:
        table.fail("locked", "needs a password to unlock it with (password = \"1234\")")
    return quirks


def describe(quirks: Quirks) -> dict[str, object]:
    return {name: getattr(quirks, name) for name in NAMES}
