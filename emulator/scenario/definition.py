"""Scenarios: a printer, the faults it suffers, a job, and what must hold afterwards.

Read from TOML (see scenarios/README.md for the format). Every mistake in a file is reported
with the file, the key and the problem, never as a traceback.
"""

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path

from fake_marlin.emulator.faults.layer import RATE_KINDS, FaultConfig, with_rate
from fake_marlin.emulator.faults.rules import LINK_KINDS, FaultKind, FaultRule, Trigger
from fake_marlin.emulator.firmware import Firmware, Profile, ProfileError, Quirks, load_profile
from fake_marlin.emulator.firmware.quirks import read_quirks
from fake_marlin.emulator.link.conditions import LinkConditions
from fake_marlin.emulator.server.lifecycle import ServerConfig
from fake_marlin.emulator import tables
from fake_marlin.wire.ultimaker_variants import PLAIN, VariantError, Variants, variants_of

DIRECTIONS = ("to-printer", "to-host")
PROTOCOLS = ("auto", "marlin", "ultimaker", "repetier", "commstack", "g2core")
HOST_PROTOCOLS = ("marlin", "ultimaker", "repetier", "commstack", "g2core")
OUTCOMES = ("completed", "failed")
TRIGGER_KEYS = ("nth", "every", "at", "pattern", "probability")


class ScenarioError(tables.TableError):
    """A scenario file that cannot be used; the message names the file, key and problem."""


class _Reader(tables.TableReader):
    error = ScenarioError


def read_toml(path: Path) -> dict:
    """A TOML file's tables, or ScenarioError saying why it cannot be read."""
    return tables.read_toml(path, ScenarioError)


@dataclass(frozen=True)
class PrinterSetup:
    protocol: str = "auto"
    extruders: int = 1
    baud: int | None = None
    baud_from_host: bool = False
    latency: float = 0.0
    jitter: float = 0.0
    boot_delay: float = 0.0
    advanced_ok: bool = False
    firmware: str = "marlin"  # a shipped profile's name, or a profile file's path
    quirks: Quirks | None = None  # None: the profile's own
    variants: Variants = PLAIN  # the protocol lab's (protocol ultimaker only)

    @property
    def conditions(self) -> LinkConditions:
        return LinkConditions(self.baud, self.latency, self.jitter)

    def make_firmware(self, number: int = 1, seed: int = 0, uuid: str | None = None,
                      serial: str | None = None, machine_name: str | None = None,
                      capabilities: dict[str, bool] | None = None,
                      profile: Profile | None = None) -> Firmware:
        """Printer `number`'s firmware, as this setup says (its identity from seed and number
        unless given); `profile`, its firmware's profile already loaded (a farm loads each once)."""
        return Firmware.make(profile or self.firmware, seed, number, self.quirks, uuid, serial,
                             machine_name, capabilities)

    def server_config(self, faults: FaultConfig) -> ServerConfig:
        """The printer server's settings: these, with these faults."""
        return ServerConfig(
            protocol=self.protocol, boot_delay=self.boot_delay, advanced_ok=self.advanced_ok,
            faults=faults, conditions=self.conditions, baud_from_host=self.baud_from_host,
            variants=self.variants,
        )


@dataclass(frozen=True)
class HostSetup:
    protocol: str | None = None  # default: the printer's (required when the printer is auto)
    window: int = 3
    timeout: float = 2.0
    retries: int = 8
    disconnect_after: int | None = None  # drop the port after this many commands, then reopen
    reconnect_after: float | None = None  # when the line hangs up: reopen after this long
    variants: Variants | None = None  # default: the printer's


@dataclass(frozen=True)
class Expectations:
    exactly_once: bool | None = None
    outcome: str | None = None
    error: str | None = None
    resends: tuple[int, int] | None = None
    printer_halted: bool | None = None
    lines_include: tuple[str, ...] = ()
    lines_exclude: tuple[str, ...] = ()
    missing: int | None = None  # job commands that never ran
    duplicated_at_most: int | None = None
    # exactly_once holds though commands ran damaged past the protocol's own check (Marlin's
    # XOR misses some double flips): what the firmware does, and no host can prevent.
    allow_undetectable: bool = False


@dataclass(frozen=True)
class Scenario:
    path: Path
    name: str
    description: str = ""
    printer: PrinterSetup = field(default_factory=PrinterSetup)
    faults: FaultConfig = field(default_factory=FaultConfig)
    job: tuple[str, ...] = ()
    job_file: Path | None = None
    host: HostSetup = field(default_factory=HostSetup)
    expect: Expectations = field(default_factory=Expectations)

    @property
    def host_protocol(self) -> str:
        return self.host.protocol or self.printer.protocol

    @property
    def host_variants(self) -> Variants:
        return self.printer.variants if self.host.variants is None else self.host.variants


def load(path: str | os.PathLike[str]) -> Scenario:
    path = Path(path)
    top = _Reader(path, "", read_toml(path))
    name = top.get("name", str, path.stem)
    description = top.get("description", str, "")
    printer = _printer(top.table_at("printer"))
    seed = top.get("seed", int, 0)
    faults = _faults(path, top.get("fault", list, []), seed)
    job, job_file = _job(path, top.table_at("job"))
    host = _host(top.table_at("host"), printer)
    expect = _expect(top.table_at("expect"))
    top.finish()
    return Scenario(path, name, description, printer, faults, job, job_file, host, expect)


TableReader = _Reader  # for other files built of the same tables (the farm file)


def read_printer_table(path: Path | str, where: str, table: dict) -> PrinterSetup:
    """A `[printer]` table's settings, from wherever such a table is given."""
    return _printer(_Reader(path, where, table))


def _printer(table: _Reader) -> PrinterSetup:
    baud = table.get("baud", (int, str), None)
    if isinstance(baud, str) and baud != "host":
        table.fail("baud", f"must be a rate such as 250000, or \"host\", not {baud!r}")
    if isinstance(baud, int) and baud <= 0:
        table.fail("baud", "must be positive")
    firmware = table.get("firmware", str, "marlin")
    if firmware.endswith(".toml") and not Path(firmware).is_absolute():
        firmware = str(Path(table.path).parent / firmware)  # beside the file that names it
    try:
        profile = load_profile(firmware)
    except ProfileError as error:
        table.fail("firmware", str(error))
    quirks = None
    if "quirks" in table.table:
        quirks = read_quirks(table.table_at("quirks"), profile.quirks)
    protocol = table.get("protocol", str, "auto", PROTOCOLS)
    if protocol != "auto" and protocol not in profile.protocols:
        table.fail("protocol", f"firmware {profile.name} speaks {', '.join(profile.protocols)}, "
                               f"not {protocol}")
    setup = PrinterSetup(
        protocol=protocol,
        extruders=table.get("extruders", int, 1, minimum=1, maximum=8),
        baud=baud if isinstance(baud, int) else None,
        baud_from_host=baud == "host",
        latency=table.get("latency_ms", (int, float), 0, minimum=0) / 1000,
        jitter=table.get("jitter_ms", (int, float), 0, minimum=0) / 1000,
        boot_delay=table.get("boot_delay", (int, float), 0.0, minimum=0),
        advanced_ok=table.get("advanced_ok", bool, False),
        firmware=firmware,
        quirks=quirks,
        variants=_variants(table, "variants") or PLAIN,
    )
    if not setup.variants.plain and protocol != "ultimaker":
        table.fail("variants", f"are Ultimaker's: give protocol = \"ultimaker\" (auto never "
                               "guesses a variant)")
    table.finish()
    return setup


def _variants(table: _Reader, key: str) -> Variants | None:
    """`variants = ["ack", "crc8"]` or `"ack,crc8"`; None if not given."""
    value = table.get(key, (str, list), None)
    if value is None:
        return None
    if isinstance(value, list) and not all(isinstance(name, str) for name in value):
        table.fail(key, "must be a list of variant names, or one string of them")
    try:
        return variants_of(value)
    except VariantError as error:
        raise ScenarioError(f"{table.path}: {table.where}{key}: {error}") from None


def _faults(path: Path, entries: list, seed: int) -> FaultConfig:
    config = FaultConfig(seed=seed)
    for number, entry in enumerate(entries, start=1):
        config = add_fault_table(config, entry, f"{path}: [[fault]] #{number}")
    return config


def add_fault_table(config: FaultConfig, entry: object, where: str) -> FaultConfig:
    """`config` with one more fault, given as a `[[fault]]` table (a dict); `where` names it
    in errors."""
    fault = parse_fault_table(entry, where)
    if isinstance(fault, FaultRule):
        return dataclasses.replace(config, rules=(*config.rules, fault))
    return with_rate(config, *fault)


def parse_fault_table(entry, where: str) -> FaultRule | tuple[str, str, float]:
    """One `[[fault]]` table: a triggered rule, or (direction, LineFaults field, rate)."""
    if not isinstance(entry, dict):
        raise ScenarioError(f"{where}: must be a table")
    table = _Reader(where, "", entry)  # errors name the place as given
    kinds = [k.value for k in FaultKind] + list(RATE_KINDS)
    kind = table.get("kind", str, None, kinds)
    if kind is None:
        table.fail("kind", f"is missing; one of {', '.join(kinds)}")
    direction = table.get("direction", str, None, DIRECTIONS)
    if kind in RATE_KINDS:
        if direction is None:
            table.fail("direction", "is missing: to-printer or to-host")
        rate = table.get("rate", (int, float), 0.0, minimum=0, maximum=1)
        table.finish()
        return direction, RATE_KINDS[kind], float(rate)
    fault_kind = FaultKind(kind)
    if fault_kind in LINK_KINDS and direction is None:
        table.fail("direction", f"is missing: a {kind} fault happens to-printer or to-host")
    trigger_values = {key: table.get(key, (int, float, str), None) for key in TRIGGER_KEYS}
    times = table.get("times", int, None, minimum=1)
    try:
        trigger = Trigger(**trigger_values, times=times)
    except (TypeError, ValueError) as error:
        table.fail("trigger", str(error))
    if trigger.at is not None and fault_kind in (FaultKind.DROP, FaultKind.DUPLICATE, FaultKind.TRUNCATE):
        table.fail("at", f"a {kind} fault acts on a unit: trigger it with nth, every, pattern or probability")
    rule = FaultRule(
        kind=fault_kind,
        trigger=trigger,
        direction=direction,
        seconds=float(table.get("seconds", (int, float), 0.0, minimum=0)),
        text=table.get("text", str, ""),
        length=table.get("length", int, 0, minimum=0),
        heater=table.get("heater", str, "T0"),
    )
    table.finish()
    return rule


def _job(path: Path, table: _Reader) -> tuple[tuple[str, ...], Path | None]:
    from fake_marlin.wire.gcode import strip_comment

    file = table.get("file", str, None)
    moves = table.get("moves", int, None, minimum=1, maximum=MAX_MOVES)
    table.finish()
    if file is not None and moves is not None:
        table.fail("file", "give a file or a number of moves, not both")
    if file is not None:
        job_path = (path.parent / file)
        try:
            text = job_path.read_text(encoding="utf-8", errors="replace")
        except OSError as error:
            table.fail("file", f"cannot read {job_path}: {error.strerror}")
        except ValueError as error:  # a NUL in the name
            table.fail("file", f"cannot read {job_path!r}: {error}")
        return tuple(c for line in text.splitlines() if (c := strip_comment(line))), job_path
    if moves is not None:
        return generated_job(moves), None
    return (), None


MAX_MOVES = 1_000_000  # a generated job of more is no test anyone waits for


def generated_job(moves: int) -> tuple[str, ...]:
    """A plausible small print: home, heat without waiting, extrude along a square spiral."""
    job = ["G28", "M104 S200", "M140 S60", "G92 E0", "G1 Z0.3 F600", "M106 S255"]
    e = 0.0
    for n in range(moves):
        side = n % 4
        x = 50 + (n // 4 % 40) + (20 if side in (1, 2) else 0)
        y = 50 + (n // 4 % 40) + (20 if side in (2, 3) else 0)
        e += 0.8
        job.append(f"G1 X{x} Y{y} E{e:.2f} F3000")
    job += ["M107", "M104 S0", "M140 S0", "M400"]
    return tuple(job)


def _host(table: _Reader, printer: PrinterSetup) -> HostSetup:
    host = HostSetup(
        protocol=table.get("protocol", str, None, HOST_PROTOCOLS),
        window=table.get("window", int, 3, minimum=1, maximum=32),
        timeout=float(table.get("timeout", (int, float), 2.0, minimum=0.01)),
        retries=table.get("retries", int, 8, minimum=1),
        disconnect_after=table.get("disconnect_after", int, None, minimum=1),
        reconnect_after=table.get("reconnect_after", (int, float), None, minimum=0),
        variants=_variants(table, "variants"),
    )
    if host.variants is not None and not host.variants.plain and (
            host.protocol or printer.protocol) != "ultimaker":
        table.fail("variants", "are Ultimaker's: the host must speak ultimaker")
    if host.protocol is None and printer.protocol == "auto":
        table.fail("protocol", "is needed when the printer detects its protocol (printer.protocol = auto)")
    if host.disconnect_after is not None and (host.protocol or printer.protocol) == "commstack":
        table.fail("disconnect_after", "is for streaming hosts; a CommStack host uploads its job whole")
    table.finish()
    return host


def _expect(table: _Reader) -> Expectations:
    resends = table.get("resends", list, None)
    if resends is not None and (len(resends) != 2 or not all(isinstance(n, int) for n in resends)
                                or resends[0] > resends[1]):
        table.fail("resends", f"must be [least, most], two whole numbers, not {resends!r}")
    include = table.get("lines_include", list, [])
    exclude = table.get("lines_exclude", list, [])
    for key, lines in (("lines_include", include), ("lines_exclude", exclude)):
        if not all(isinstance(line, str) for line in lines):
            table.fail(key, "must be a list of strings")
    expect = Expectations(
        exactly_once=table.get("exactly_once", bool, None),
        outcome=table.get("outcome", str, None, OUTCOMES),
        error=table.get("error", str, None),
        resends=tuple(resends) if resends else None,
        printer_halted=table.get("printer_halted", bool, None),
        lines_include=tuple(include),
        lines_exclude=tuple(exclude),
        missing=table.get("missing", int, None, minimum=0),
        duplicated_at_most=table.get("duplicated_at_most", int, None, minimum=0),
        allow_undetectable=table.get("allow_undetectable", bool, False),
    )
    table.finish()
    return expect
