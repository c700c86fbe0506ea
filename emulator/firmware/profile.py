"""Firmware profiles: what a firmware says and does on the wire, as data.

A profile is a TOML file: the shipped ones are in profiles/ (`fake-marlin --firmware list`
lists them), and a user's own file may extend one (`extends = "marlin"`) for a firmware
fake-marlin does not ship. Extending merges tables key by key (a table in the new file changes
only the keys it names), but for the tables it names in `replace`, which are its own; any other
value replaces the one before. Every template is checked
against the statement it says (printer/statements.py) when the profile is loaded, so that a
mistake is an error naming the file and key, not a surprise on the wire.
"""

import dataclasses
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from fake_marlin.emulator.firmware.identity import SAMPLE_VALUES
from fake_marlin.emulator.firmware.quirks import Quirks, read_quirks
from fake_marlin.emulator.firmware.templates import fill
from fake_marlin.emulator.printer.heating import HeatWait
from fake_marlin.emulator.printer.planner import MAX_MOVES
from fake_marlin.emulator.printer.model import SET_STATEMENTS
from fake_marlin.emulator.printer.statements import CATALOG, SPECIAL
from fake_marlin.emulator.protocols.marlin import LineRules
from fake_marlin.emulator.tables import TableError, TableReader

PROTOCOL_NAMES = ("marlin", "ultimaker", "repetier", "commstack", "g2core")
COMMAND_SETS = ("marlin", "prusa", "klipper", "reprapfirmware", "smoothieware")
_SHIPPED = resources.files("fake_marlin.emulator.firmware") / "profiles"
_MAX_DEPTH = 8  # profiles extending profiles


class ProfileError(TableError):
    """A firmware profile that cannot be used; the message names the file, key and problem."""


class _Reader(TableReader):
    error = ProfileError


@dataclass(frozen=True)
class Busy:
    interval: float = 2.0  # seconds between `busy:` lines while a command holds the queue
    adjustable: bool = True  # M113 S<seconds> sets it (Marlin's HOST_KEEPALIVE_FEATURE)
    # M109/M190 say `busy:` too, between their temperature lines (BUSY_WHILE_HEATING as Marlin
    # 1.1 has it); False: only the temperature lines.
    while_heating: bool = False


@dataclass(frozen=True)
class Halt:
    """What a halted printer (after M112, a thermal error) does until it is reset."""

    # False: it reads nothing at all (Marlin's kill()); True: it answers each command with the
    # halted_refusal statement and `ok`, but for these:
    reads: bool = False
    still_runs: frozenset[str] = frozenset()  # commands it runs all the same (M105, STATUS)
    revive: frozenset[str] = frozenset()  # commands that reset it (FIRMWARE_RESTART)
    clear: frozenset[str] = frozenset()  # commands that end the halt without a reset (M999)
    reboot_after: float = 0.0  # seconds after which it resets itself (a watchdog); 0: never
    refusal_ok: bool = True  # halted_refusal is followed by `ok` (Smoothieware's `!!` is not)
    # True: every line it read gets its answer and `ok` through the halt, as a firmware that
    # reads on does (Klipper): the command the halt cut short, the lines queued behind it and
    # the rest of what came with M112. False: those are dropped.
    answers_all: bool = False


@dataclass(frozen=True)
class Profile:
    name: str
    title: str
    source: str  # where its facts come from (docs/firmwares.md has the details)
    path: str  # the file it was read from (the last of a chain of extends)
    protocols: tuple[str, ...]
    bootloader: bool  # the STK500v2 bootloader listens first after a reset (AVR boards)
    # A host opening the port resets the board (DTR, on boards with a USB-serial chip); False:
    # the firmware runs on, and says `connected` (native USB, Klipper's pty).
    reset_on_open: bool
    command_sets: tuple[str, ...]
    unsupported: frozenset[str]
    protocol_words: dict[str, str]  # protocol -> the profile whose words a host of it hears
    version: str
    date: str
    machine_type: str
    uuid: str  # "" : drawn per printer from the seed and number
    serial: str  # a template of identity.py's values
    machine_name: str  # likewise
    capabilities: tuple[tuple[str, bool], ...]
    lines: LineRules
    busy: Busy
    halt: Halt
    templates: dict[str, Any] = field(repr=False)  # statement key -> its table or template
    quirks: Quirks = Quirks()
    # An unknown G, M or T code gets its `ok` and nothing more: only a line without one is an
    # unknown command (Marlin 1.0's process_command(), the Ultimaker 2's).
    silent_unknown_codes: bool = False
    heat_wait: HeatWait = HeatWait()  # how M109/M190 wait ([heating])
    planner_moves: int = MAX_MOVES  # the moves its planner holds (Marlin 15, g2core 48)

    def capability(self, name: str) -> bool:
        return dict(self.capabilities).get(name, False)


def shipped() -> list[str]:
    """The names of the profiles fake-marlin ships, sorted."""
    return sorted(entry.name[:-5] for entry in _SHIPPED.iterdir() if entry.name.endswith(".toml"))


def load_profile(name_or_path: str) -> Profile:
    """A shipped profile by name (`prusa`), or a profile file by path (`./my-printer.toml`)."""
    tables, path = _read_chain(name_or_path, 0)
    return _build(tables, path)


def _locate(name_or_path: str) -> tuple[str, str]:
    """(TOML text, where it is) for a name or a path."""
    if name_or_path.endswith(".toml") or "/" in name_or_path:
        path = Path(name_or_path)
        try:
            return path.read_text(encoding="utf-8"), str(path)
        except OSError as error:
            raise ProfileError(f"{path}: cannot read: {error.strerror}") from None
        except UnicodeDecodeError:
            raise ProfileError(f"{path}: not UTF-8 text") from None
    if name_or_path not in shipped():
        raise ProfileError(f"no firmware {name_or_path!r}: one of {', '.join(shipped())}, or a "
                           "profile file (a path ending in .toml)")
    entry = _SHIPPED / f"{name_or_path}.toml"
    return entry.read_text(encoding="utf-8"), f"{name_or_path} (shipped)"


def _read_chain(name_or_path: str, depth: int) -> tuple[dict[str, Any], str]:
    if depth > _MAX_DEPTH:
        raise ProfileError(f"{name_or_path}: extends goes more than {_MAX_DEPTH} profiles deep "
                           "(a profile that extends itself?)")
    text, where = _locate(name_or_path)
    try:
        tables = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ProfileError(f"{where}: not valid TOML: {error}") from None
    base_name = tables.pop("extends", None)
    if base_name is None:
        return tables, where
    if not isinstance(base_name, str) or not base_name:
        raise ProfileError(f"{where}: extends: must be a profile's name or path, not {base_name!r}")
    if base_name.endswith(".toml") and not Path(base_name).is_absolute() and "/" in where:
        base_name = str(Path(where).parent / base_name)  # relative to the file that names it
    replace = tables.pop("replace", [])
    if not isinstance(replace, list) or not all(isinstance(name, str) for name in replace):
        raise ProfileError(f"{where}: replace: must be a list of table names, not {replace!r}")
    try:
        base, _ = _read_chain(base_name, depth + 1)
    except ProfileError as error:
        if depth == 0 and where not in str(error):
            raise ProfileError(f"{where}: extends: {error}") from None
        raise
    for name in replace:  # these tables are the new file's own, not the base's with changes
        base.pop(name, None)
    return _merged(base, tables), where


def _merged(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    result = dict(base)
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(result.get(key), dict):
            result[key] = _merged(result[key], value)
        else:
            result[key] = value
    return result


def _strings(table: _Reader, key: str, default: tuple[str, ...] = ()) -> tuple[str, ...]:
    value = table.get(key, list, None)
    if value is None:
        return default
    if not all(isinstance(item, str) for item in value):
        table.fail(key, "must be a list of strings")
    return tuple(value)


def _build(tables: dict[str, Any], path: str) -> Profile:
    top = _Reader(path, "", tables)
    name = top.get("name", str, None)
    if not name:
        top.fail("name", "is missing")
    protocols = _strings(top, "protocols", ("marlin",))
    for protocol in protocols:
        if protocol not in PROTOCOL_NAMES:
            top.fail("protocols", f"{protocol!r} is not one of {', '.join(PROTOCOL_NAMES)}")
    command_sets = _strings(top, "command_sets", ("marlin",))
    for command_set in command_sets:
        if command_set not in COMMAND_SETS:
            top.fail("command_sets", f"{command_set!r} is not one of {', '.join(COMMAND_SETS)}")
    identity = top.table_at("identity")
    capabilities = top.table_at("capabilities")
    for key, value in capabilities.table.items():
        if not isinstance(value, bool):
            capabilities.fail(key, f"must be true or false, not {value!r}")
    profile = Profile(
        name=name,
        title=top.get("title", str, name),
        source=top.get("source", str, ""),
        path=path,
        protocols=protocols,
        bootloader=top.get("bootloader", bool, False),
        reset_on_open=top.get("reset_on_open", bool, True),
        command_sets=command_sets,
        unsupported=frozenset(code.upper() for code in _strings(top, "unsupported")),
        protocol_words=_protocol_words(top.table_at("protocol_words")),
        version=identity.get("version", str, ""),
        date=identity.get("date", str, ""),
        machine_type=identity.get("machine_type", str, "3D Printer"),
        uuid=identity.get("uuid", str, ""),
        serial=identity.get("serial", str, "FM{number:05d}{hex:.8}"),
        machine_name=identity.get("machine_name", str, "3D Printer {number}"),
        capabilities=tuple(capabilities.table.items()),
        lines=_line_rules(top.table_at("lines")),
        busy=_busy(top.table_at("busy")),
        halt=_halt(top.table_at("halt")),
        templates=_templates(top, command_sets),
        quirks=read_quirks(top.table_at("quirks"), Quirks()),
        silent_unknown_codes=top.get("silent_unknown_codes", bool, False),
        heat_wait=_heat_wait(top.table_at("heating")),
        planner_moves=top.get("planner_moves", int, MAX_MOVES, minimum=4, maximum=1000),
    )
    identity.finish()
    top.finish()
    for template, where in ((profile.serial, "serial"), (profile.machine_name, "machine_name"),
                            (profile.uuid, "uuid")):
        _check(identity, where, template, SAMPLE_VALUES)
    return profile


def _line_rules(table: _Reader) -> LineRules:
    default = LineRules()
    values: dict[str, object] = {}
    for rule in dataclasses.fields(LineRules):
        current = getattr(default, rule.name)
        kind: type | tuple[type, ...] = type(current)
        if isinstance(current, tuple):
            values[rule.name] = _strings(table, rule.name, current)
            continue
        minimum = (0 if rule.name == "first_line" else 1) if kind is int else None
        value = table.get(rule.name, kind, None, minimum=minimum)
        if value is not None:
            values[rule.name] = value
    table.finish()
    rules = dataclasses.replace(default, **values)  # type: ignore[arg-type]
    for key, choices in (("checksum", ("required", "optional", "ignored")),
                         ("bad_line", ("resend", "drop"))):
        if getattr(rules, key) not in choices:
            table.fail(key, f"must be one of {', '.join(map(repr, choices))}, "
                            f"not {getattr(rules, key)!r}")
    if rules.encoding not in ("ascii", "utf-8"):
        table.fail("encoding", "must be \"ascii\" or \"utf-8\"")
    if rules.line_end not in ("\n", "\r\n"):
        table.fail("line_end", "must be \"\\n\" or \"\\r\\n\"")
    sample = {"last": 4, "line": 5, "expected": 5, "got": 7}
    for rule in dataclasses.fields(LineRules):
        value = getattr(rules, rule.name)
        if isinstance(value, str) and rule.name.startswith(("error_", "resend")):
            _check(table, rule.name, value, sample)
    return rules


def _protocol_words(table: _Reader) -> dict[str, str]:
    words = {}
    for protocol in PROTOCOL_NAMES:
        name = table.get(protocol, str, None)
        if name is not None:
            words[protocol] = name
    table.finish()
    return words


def _busy(table: _Reader) -> Busy:
    busy = Busy(
        interval=float(table.get("interval", (int, float), Busy.interval, minimum=0)),
        adjustable=table.get("adjustable", bool, Busy.adjustable),
        while_heating=table.get("while_heating", bool, Busy.while_heating),
    )
    table.finish()
    return busy


def _heat_wait(table: _Reader) -> HeatWait:
    default = HeatWait()
    wait = HeatWait(**{
        name: table.get(name, (int, float), getattr(default, name), minimum=0) * 1.0
        for name in ("residency", "window", "bed_residency", "bed_window")},
        cools=table.get("cools", bool, default.cools))
    table.finish()
    return wait


def _halt(table: _Reader) -> Halt:
    def codes(key: str) -> frozenset[str]:
        return frozenset(code.upper() for code in _strings(table, key))

    halt = Halt(
        reads=table.get("reads", bool, False),
        still_runs=codes("still_runs"),
        revive=codes("revive"),
        clear=codes("clear"),
        reboot_after=float(table.get("reboot_after", (int, float), 0.0, minimum=0)),
        refusal_ok=table.get("refusal_ok", bool, True),
        answers_all=table.get("answers_all", bool, False),
    )
    table.finish()
    return halt


# Tables of their own for the statements that take more than one template (SPECIAL), each
# with the templates it must or may have.
_SPECIAL_TABLES: dict[str, tuple[str, ...]] = {
    "greeting": ("lines", "sd", "after?"),
    "firmware_info": ("lines", "capability", "after?"),  # ?: may be left out (none)
    # heating_bed: M190's lines, where they are not M109's (heating): by default they are.
    "temperatures": ("one", "several", "each", "each_power", "auto", "heating", "heating_bed?"),
    "position": ("report", "auto"),
}


def _special_samples() -> dict[tuple[str, str], dict[str, object]]:
    """(table, template) -> the values that template is filled in with (firmware/words.py)."""
    heat = CATALOG["temperatures"]["active"]._asdict()  # type: ignore[attr-defined]
    report = {"report": "T:21.00 /0.00"}
    whole = {"each": "T0:21.00 /0.00", "each_power": "@0:0"}
    return {
        ("greeting", "lines"): CATALOG["greeting"], ("greeting", "sd"): CATALOG["greeting"],
        ("greeting", "after"): CATALOG["greeting"],
        ("firmware_info", "lines"): CATALOG["firmware_info"],
        ("firmware_info", "capability"): {"name": "EEPROM", "value": 1},
        ("firmware_info", "after"): CATALOG["firmware_info"],
        ("temperatures", "one"): {**CATALOG["temperatures"], **whole},
        ("temperatures", "several"): {**CATALOG["temperatures"], **whole},
        ("temperatures", "each"): heat, ("temperatures", "each_power"): heat,
        ("temperatures", "auto"): {**CATALOG["auto_temperatures"], **report},
        ("temperatures", "heating"): {**CATALOG["heating"], **report},
        ("temperatures", "heating_bed"): {**CATALOG["heating"], **report},
        ("position", "report"): CATALOG["position"], ("position", "auto"): CATALOG["auto_position"],
    }


def _templates(top: _Reader, command_sets: tuple[str, ...]) -> dict[str, Any]:
    """Every statement's template(s), each checked with its statement's sample values: those
    of printer/statements.py, and those of the profile's command sets."""
    templates: dict[str, Any] = {}
    messages = top.table_at("messages")
    catalog = dict(CATALOG)
    for command_set in command_sets:
        catalog.update(SET_STATEMENTS[command_set])
    for key in catalog:
        if key in SPECIAL:
            continue
        value = messages.get(key, (str, list), None)
        if value is None:
            messages.fail(key, "is missing: every statement needs its words (\"\" for none)")
        lines = (value,) if isinstance(value, str) else _strings(messages, key)
        for line in lines:
            _check(messages, key, line, {**SAMPLE_CONTEXT, **catalog[key]})
        templates[key] = lines
    messages.finish()
    for table_name, keys in _SPECIAL_TABLES.items():
        table = top.table_at(table_name)
        found: dict[str, tuple[str, ...]] = {}
        for key in keys:
            optional, key = key.endswith("?"), key.rstrip("?")
            value = table.get(key, (str, list), "" if optional else None)
            if value is None:
                table.fail(key, "is missing")
            found[key] = (value,) if isinstance(value, str) else _strings(table, key)
        if table_name == "temperatures" and "heating_bed" not in table.table:
            found["heating_bed"] = found["heating"]
        table.finish()
        templates[table_name] = found
    for (table_name, key), sample in _special_samples().items():
        reader = _Reader(top.path, f"[{table_name}] ", {})
        for line in templates[table_name][key]:
            _check(reader, key, line, {**SAMPLE_CONTEXT, **sample})
    return templates


SAMPLE_CONTEXT: dict[str, object] = {
    "version": "1.0", "date": "2024-01-01", "machine_type": "3D Printer", "uuid": "uuid",
    "serial": "FM1", "machine_name": "3D Printer 1", "firmware": "marlin",
}


def _check(table: TableReader, key: str, template: str, values: Mapping[str, object]) -> None:
    try:
        fill(template, values)
    except KeyError as error:
        table.fail(key, f"{template!r} names {{{error.args[0]}}}, which is not one of its "
                        f"values: {', '.join(sorted(values))}")
    except (ValueError, IndexError, AttributeError, TypeError) as error:
        table.fail(key, f"{template!r} is not a template it can fill in: {error}")
