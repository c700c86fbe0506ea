"""Many printers in one process: what each one is, from the command line or a farm file.

A farm file is TOML: one `[[printer]]` table per kind of printer, with the keys of a
scenario's `[printer]` table plus these:

    processes = 4                 # (top level) spread the printers over 4 processes (--processes)
    first_number = 21             # (top level) its first printer is number 21 (--first-number)

    count = 10                    # this many printers alike (default 1)
    scenario = "noisy.toml"       # printer settings and faults from a scenario (its job unused)
    seed = 3                      # for its random faults; printer k of a count gets seed + k
    link = "/tmp/printer-{n}"     # a symlink to its pty; {n} is the printer's number, from 1
    journal = "logs/{n}.log"      # append each executed command here
    sd_dir = "sd/{n}"             # the directory behind its SD card (default: a temporary one)
    eeprom_file = "eeprom/{n}.json"  # where M500 keeps its settings (default: in memory)
    tcp = "127.0.0.1:9000"        # serve on TCP instead of a pty; a count takes consecutive ports
    rfc2217 = 9100                # or on RFC 2217
    serial = "CZPX0001X{number:03d}X{letter}{d:05d}"   # its identity (docs/firmwares.md): a
    machine_name = "Shelf A {number}"                   # template, as the firmware's profile's;
    uuid = "..."                                        # default: the firmware's, per printer
    [[printer.fault]]             # as a scenario's [[fault]] tables
    kind = "bit-errors"
    ...

Every mistake is reported with the file, the printer table and the key, as scenario errors are.
"""

import argparse
import dataclasses
from dataclasses import dataclass
from pathlib import Path

from fake_marlin.emulator.cli.links import Address, tcp_address
from fake_marlin.emulator.faults.layer import FaultConfig
from fake_marlin.emulator.firmware.identity import make_identity
from fake_marlin.emulator.scenario.definition import (
    PrinterSetup,
    ScenarioError,
    TableReader,
    add_fault_table,
    load,
    read_printer_table,
    read_toml,
)

MAX_PRINTERS = 10_000  # more than one machine should serve; a typo, not a farm
MAX_PROCESSES = 64
MAX_FIRST_NUMBER = 1_000_000
_FARM_KEYS = ("count", "scenario", "seed", "link", "journal", "sd_dir", "tcp", "rfc2217", "fault",
              "uuid", "serial", "machine_name", "eeprom_file")
_IDENTITY_KEYS = ("uuid", "serial", "machine_name")


class FarmError(ScenarioError):
    """A farm file or --printers setting that cannot be used; the message says where and why."""


@dataclass(frozen=True)
class PrinterPlan:
    """One printer to serve: its settings, faults, and where its outputs go."""

    number: int  # from 1, in the order the paths are printed
    setup: PrinterSetup
    faults: FaultConfig
    link: str | None = None
    journal: str | None = None
    sd_dir: str | None = None
    tcp: Address | None = None
    rfc2217: Address | None = None
    # Its identity (firmware/identity.py): templates, None for the firmware's own.
    uuid: str | None = None
    serial: str | None = None
    machine_name: str | None = None
    eeprom_file: str | None = None  # where M500 keeps its settings (default: in memory)


def numbered(pattern: str | None, number: int) -> str | None:
    return None if pattern is None else pattern.replace("{n}", str(number))


def parse_address(text: str | int) -> Address:
    """`[HOST:]PORT` (an int is a port), as --tcp takes it; ValueError with the reason."""
    if isinstance(text, bool) or not isinstance(text, (str, int)):
        raise ValueError(f"expected [HOST:]PORT, got {text!r}")
    try:
        return tcp_address(str(text))
    except argparse.ArgumentTypeError as error:
        raise ValueError(str(error)) from None


def copies(plan: PrinterPlan, count: int, first: int = 1, seed_from: int = 0) -> list[PrinterPlan]:
    """`count` printers like `plan`, numbered from `first`: each its own {n} paths, the next
    port, and the next seed (so that their random faults differ), from `plan`'s + `seed_from`."""
    out = []
    for k in range(count):
        number = first + k
        faults = dataclasses.replace(plan.faults, seed=plan.faults.seed + seed_from + k)
        out.append(dataclasses.replace(
            plan, number=number, faults=faults,
            link=numbered(plan.link, number), journal=numbered(plan.journal, number),
            sd_dir=numbered(plan.sd_dir, number), eeprom_file=numbered(plan.eeprom_file, number),
            tcp=plan.tcp.plus(k) if plan.tcp else None,
            rfc2217=plan.rfc2217.plus(k) if plan.rfc2217 else None,
        ))
    return out


def check_patterns(plans: list[PrinterPlan]) -> None:
    """Two printers may not share a link, journal, SD directory or port."""
    for key in ("link", "journal", "sd_dir", "eeprom_file"):
        seen: dict[str, int] = {}
        for plan in plans:
            value = getattr(plan, key)
            if value is None:
                continue
            if value in seen:
                raise FarmError(
                    f"printers {seen[value]} and {plan.number} would share the {key} {value}; "
                    "put {n} in it"
                )
            seen[value] = plan.number
    ports: dict[tuple[str, int], int] = {}
    for plan in plans:
        for address in (plan.tcp, plan.rfc2217):
            if address is None or address.port == 0:
                continue
            where = (address.host, address.port)
            if where in ports:
                raise FarmError(
                    f"printers {ports[where]} and {plan.number} would share port {address.port}"
                )
            ports[where] = plan.number


@dataclass(frozen=True)
class Farm:
    """A farm file: its printers, and how many processes serve them (None: not said)."""

    plans: list[PrinterPlan]
    processes: int | None = None


def load_farm(path: str | Path, first_number: int | None = None) -> list[PrinterPlan]:
    return read_farm(path, first_number).plans


def read_farm(path: str | Path, first_number: int | None = None) -> Farm:
    """The farm file at `path`; `first_number` (--first-number) over its own `first_number`."""
    path = Path(path)
    top = TableReader(path, "", read_toml(path))
    entries = top.get("printer", list, [])
    processes = top.get("processes", int, None, minimum=1, maximum=MAX_PROCESSES)
    own_first = top.get("first_number", int, 1, minimum=1, maximum=MAX_FIRST_NUMBER)
    top.finish()
    first = own_first if first_number is None else first_number
    if not entries:
        raise FarmError(f"{path}: no [[printer]] tables: a farm needs at least one printer")
    plans: list[PrinterPlan] = []
    for index, entry in enumerate(entries, start=1):
        where = f"[[printer]] #{index} "
        if not isinstance(entry, dict):
            raise FarmError(f"{path}: {where}must be a table")
        plans += _entry(path, where, entry, first=first + len(plans))
        if len(plans) > MAX_PRINTERS:
            raise FarmError(f"{path}: more than {MAX_PRINTERS} printers")
    try:
        check_patterns(plans)
    except FarmError as error:
        raise FarmError(f"{path}: {error}") from None
    if processes is not None and processes > len(plans):
        raise FarmError(f"{path}: processes = {processes}, but the farm has {len(plans)} "
                        "printer(s): at most one process each")
    return Farm(plans, processes)


def _entry(path: Path, where: str, entry: dict, first: int) -> list[PrinterPlan]:
    own = TableReader(path, where, {key: entry[key] for key in _FARM_KEYS if key in entry})
    count = own.get("count", int, 1, minimum=1, maximum=MAX_PRINTERS)
    scenario_file = own.get("scenario", str, None)
    printer_keys = {key: value for key, value in entry.items() if key not in _FARM_KEYS}
    if scenario_file is not None:
        if printer_keys:
            own.fail(sorted(printer_keys)[0], "comes from the scenario; give one or the other")
        try:
            scenario = load(path.parent / scenario_file)
        except ScenarioError as error:
            own.fail("scenario", str(error))
        setup, faults = scenario.printer, scenario.faults
    else:
        setup = read_printer_table(path, where, printer_keys)
        faults = FaultConfig()
    seed = own.get("seed", int, None)
    if seed is not None:
        faults = dataclasses.replace(faults, seed=seed)
    for number, table in enumerate(own.get("fault", list, []), start=1):
        faults = add_fault_table(faults, table, f"{path}: {where}[[printer.fault]] #{number}")
    addresses: dict[str, Address] = {}
    for key in ("tcp", "rfc2217"):
        value = own.get(key, (str, int), None)
        if value is not None:
            try:
                addresses[key] = parse_address(value)
            except ValueError as error:
                own.fail(key, str(error))
    if len(addresses) > 1:
        own.fail("rfc2217", "a printer is served on TCP or on RFC 2217, not both")
    identity = {key: own.get(key, str, None) for key in _IDENTITY_KEYS}
    for key, template in identity.items():
        if template is None:
            continue
        try:
            # This template alone, so that an error names its own key.
            make_identity(0, 1, *(template if name == key else "" for name in _IDENTITY_KEYS))
        except (KeyError, ValueError, IndexError) as error:
            own.fail(key, f"{template!r} is not a template it can fill in: {error!r}")
        if count > 1 and "{" not in template:
            own.fail(key, f"{count} printers would share it: make it a template, e.g. with "
                          "{number}")
    plan = PrinterPlan(
        number=first, setup=setup, faults=faults,
        link=_beside(path, own.get("link", str, None)),
        journal=_beside(path, own.get("journal", str, None)),
        sd_dir=_beside(path, own.get("sd_dir", str, None)), **addresses,
        eeprom_file=_beside(path, own.get("eeprom_file", str, None)),
        uuid=identity["uuid"], serial=identity["serial"], machine_name=identity["machine_name"],
    )
    own.finish()
    if plan.link is not None and (plan.tcp or plan.rfc2217):
        own.fail("link", "is the pty's symlink; a printer on TCP has no pty")
    return copies(plan, count, first)


def _beside(farm: Path, value: str | None) -> str | None:
    """A relative path in a farm file is relative to the file, as a scenario's job file is."""
    return None if value is None else str(farm.parent / value)
