"""Firmwares: each a profile of data (profiles/*.toml) that says the printer model's statements
in that firmware's words and sets the rules of its line protocol, with the printer's identity
and the quirks switched on (docs/firmwares.md)."""

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from fake_marlin.emulator.firmware.identity import Identity, make_identity
from fake_marlin.emulator.firmware.profile import Profile, ProfileError, load_profile, shipped
from fake_marlin.emulator.firmware.quirks import Quirks
from fake_marlin.emulator.firmware.words import Words
from fake_marlin.emulator.printer.model import PrinterConfig
from fake_marlin.emulator.protocols.marlin import LineRules

__all__ = ["Firmware", "Identity", "Profile", "ProfileError", "Quirks", "Words", "load_profile",
           "shipped"]


@dataclass
class Firmware:
    """One printer's firmware: its profile, its identity, and the quirks on now (the control
    channel may change them while it runs)."""

    profile: Profile
    identity: Identity
    quirks: Quirks
    # M115's capabilities: the profile's, as --capability changed them.
    capabilities: tuple[tuple[str, bool], ...] = ()

    def __post_init__(self) -> None:
        if not self.capabilities:
            self.capabilities = self.profile.capabilities
        self.words = Words(self.profile, self.identity, self.said_capabilities())

    @classmethod
    def make(cls, profile: Profile | str = "marlin", seed: int = 0, number: int = 1,
             quirks: Quirks | None = None, uuid: str | None = None, serial: str | None = None,
             machine_name: str | None = None,
             capabilities: dict[str, bool] | None = None) -> "Firmware":
        """Printer `number`'s firmware; what is not given comes from the profile."""
        if isinstance(profile, str):
            profile = load_profile(profile)
        identity = make_identity(
            seed, number,
            profile.uuid if uuid is None else uuid,
            profile.serial if serial is None else serial,
            profile.machine_name if machine_name is None else machine_name,
        )
        merged = dict(profile.capabilities)
        merged.update(capabilities or {})
        return cls(profile, identity, profile.quirks if quirks is None else quirks,
                   _shared(tuple(merged.items())))

    def switch(self, quirks: Quirks) -> None:
        """These quirks from now on (the control channel): its words follow them."""
        self.quirks = quirks
        self.words = Words(self.profile, self.identity, self.said_capabilities())

    def with_uuid(self, uuid: str) -> "Firmware":
        """This firmware saying another UUID (g2core's Marlin side says the board's id)."""
        return Firmware(self.profile, dataclasses.replace(self.identity, uuid=uuid), self.quirks,
                        self.capabilities)

    def speaking(self, protocol: str) -> "Firmware":
        """This printer's firmware as a host that speaks `protocol` hears it: a board that
        tells protocols apart (--protocol auto) answers a Repetier host in Repetier-Firmware's
        words, as the profile's [protocol_words] says; itself for any other."""
        name = self.profile.protocol_words.get(protocol)
        if name is None or name == self.profile.name:
            return self
        other = load_profile(name)
        return Firmware(other, self.identity, self.quirks, other.capabilities)

    def printer_config(self, extruders: int = 1, sd_dir: Path | None = None,
                       eeprom_file: Path | None = None) -> PrinterConfig:
        """The printer model's settings for this firmware: its capabilities and commands, as
        its quirks change them."""
        return self.configure(PrinterConfig(extruders=extruders, sd_dir=sd_dir,
                                            eeprom_file=eeprom_file))

    def configure(self, config: PrinterConfig) -> PrinterConfig:
        """`config` with what this firmware and its quirks say (again, when they change)."""
        quirks = self.quirks
        unsupported = set(self.profile.unsupported)
        if quirks.no_m112:
            unsupported.add("M112")
        return dataclasses.replace(
            config, capabilities=self.said_capabilities(), command_sets=self.profile.command_sets,
            unsupported=frozenset(unsupported),
            # (No M511 to unlock it with: a firmware without PASSWORD_FEATURE ignores the quirk.)
            password_feature=bool(quirks.password) and "M511" not in unsupported,
            password=quirks.password, locked_at_boot=quirks.locked,
            machine_name=self.identity.machine_name,
            silent_unknown_codes=self.profile.silent_unknown_codes,
            heat_wait=self.profile.heat_wait, planner_moves=self.profile.planner_moves)

    def said_capabilities(self) -> tuple[tuple[str, bool], ...]:
        """M115's capabilities: the profile's (as --capability changed them), EEPROM as the
        eeprom quirk says where the firmware has the line."""
        return _shared(tuple((name, self.quirks.eeprom if name == "EEPROM" else enabled)
                             for name, enabled in self.capabilities))

    def line_rules(self) -> LineRules:
        """The profile's line rules, as the quirks on now change them."""
        quirks, rules = self.quirks, self.profile.lines
        changes: dict[str, object] = {}
        if quirks.unchecked_line_numbers:
            changes.update(sequence=False, checksum="ignored")
        if quirks.resend_without_ok:
            changes["ok_after_resend"] = False
        if quirks.extra_ok_after_resend:
            changes["extra_ok_after_resend"] = True
        if quirks.no_m112:
            changes["emergency"] = tuple(code for code in rules.emergency if code != "M112")
        return dataclasses.replace(rules, **changes) if changes else rules  # type: ignore[arg-type]


_SHARED: dict[tuple[tuple[str, bool], ...], tuple[tuple[str, bool], ...]] = {}


def _shared(capabilities: tuple[tuple[str, bool], ...]) -> tuple[tuple[str, bool], ...]:
    """One tuple for every printer whose capabilities are alike: a farm's thousands of printers
    would otherwise each keep some 50 pairs of their own, twice."""
    return _SHARED.setdefault(capabilities, capabilities)
