"""The commands of reprapfirmware that Marlin does not have (its profile's command set "reprapfirmware").

Each handler is `handler(printer, command, now) -> Reply | Step`, as in the other modules: it
states what happened (printer/statements.py); the profile says it in the firmware's words.

As RepRapFirmware 3.5.3 does it on a Duet 3 MB6HC over its native USB, in the USB channel's
default Marlin output mode (Duet3D/RepRapFirmware e7085e43: GCodes/GCodes2.cpp, GCodes.cpp,
GCodes7.cpp, Platform/RepRap.cpp, ObjectModel/ObjectModel.cpp, Heating/Heat.cpp): its waits
(M109/M190/M116 within 1.5 C, no residency), the temperature lines it sends while a USB command
is still executing once the host has asked with M105, M112's halt that still answers (and M999's
reset), its JSON replies (M20 S2/S3, M36, M408, M409, each real JSON), its file commands on
0:/gcodes/, M291's messages, heater faults that pause rather than halt. The config.g it stands
for: one tool T0 (heater 1, selected at the end of config.g), a heated bed (heater 0), moves
allowed before homing (M564 H0) and cold extrusion allowed (M302 P1), as docs/firmwares.md says.
"""

import hashlib
import json
import re
import time
from collections.abc import Generator
from dataclasses import dataclass, field
from pathlib import Path

from fake_marlin.emulator.printer import failures, heating, motion
from fake_marlin.emulator.printer.gcode import Command
from fake_marlin.emulator.printer.sdcard import OpenFile
from fake_marlin.emulator.printer.statements import Statement, state
from fake_marlin.emulator.printer.steps import Reply, Report, Sleep, reply

# What these handlers state that the other sets do not, with sample values: the profiles with
# this set say each in their [messages] (printer/statements.py has the rest).
STATEMENTS: dict[str, dict[str, object]] = {
    "bad_command": {"text": "X10"},  # a line that is no G, M or T code
    "json_reply": {"json": '{"err":0}\n'},  # an OutputBuffer as RRF builds it (its own `\n`s)
    "text_reply": {"text": "hello"},  # a text the command prints as it is (M118, echo, M503)
    "missing_parameter": {"code": "M26", "letter": "S"},
    "expected_string": {"code": "M118", "column": 7},
    "machine_name": {"name": "My Duet"},  # M550
    "output_mode": {"mode": "Marlin"},  # M555
    "network_state": {"state": "enabled", "configured": "0.0.0.0", "actual": "192.168.1.50"},
    "diagnostics": {"firmware": "RepRapFirmware for Duet 3 MB6HC", "version": "3.5.3",
                    "electronics": "Duet 3 MB6HC v1.02b or later", "board_id": "08DJM-9P63L",
                    "hours": 0, "minutes": 0, "seconds": 5, "cause": "power up",
                    "last_software_reset": "Last software reset details not available"},
    "message_title": {"title": "Attention"},  # M291
    "message_text": {"text": "Check the bed"},
    "message_continue": {},
    "message_continue_or_cancel": {},
    "message_not_dismissable": {"code": "M291"},
    "tool_selected": {"tool": 0},  # T with no number
    "no_tool_selected": {},
    "card_mounted": {"type": "SDHC", "slot": 0, "capacity": 31.91, "unit": "Gb"},  # M21
    "no_card": {"code": "M21"},
    "card_removable": {"slot": 0},  # M22
    "file_not_found": {"code": "M23", "name": "x.gcode"},
    "already_printing": {"code": "M23"},
    "no_file_selected": {"code": "M24"},
    "already_paused": {"code": "M25"},
    "not_printing": {"code": "M25"},
    "paused_at": {"x": 10.0, "y": 20.0, "z": 0.3},
    "delete_failed": {"code": "M30"},
    "cannot_write_file": {"name": "x.gcode"},  # M28 (its `ok` is inside the words)
    "end_of_file": {},  # M29 with nothing being written
    "cancel_needs_pause": {"code": "M0"},
    "only_in_file": {"code": "M600"},
    "bed_temperature": {"temperature": 21.0},  # M140 with no parameter
    # A heater fault (heater: RRF's number, the bed 0, T0's 1): the alert's title, then what
    # went wrong, as each kind of fault says it.
    "heater_fault_excursion": {"title": "Event notification", "heater": 1, "target": 200.0,
                               "actual": 230.0},
    "heater_fault_sensor": {"title": "Event notification", "heater": 1,
                            "error": "sensor open circuit"},
    "heater_fault_monitor": {"title": "Event notification", "heater": 1, "monitor": 0},
    "heater_fault_rising": {"title": "Event notification", "heater": 1, "expected": 2.43,
                            "measured": 0.52},
}

FIRMWARE_NAME = "RepRapFirmware for Duet 3 MB6HC"  # Config/Pins_Duet3_MB6HC.h:9
VERSION = "3.5.3"
DATE = "2024-09-18"  # the build's IsoDate (build-dependent; the profile's identity says it too)
TIME = "12:00:00"  # __TIME__ of the build (build-dependent)
ELECTRONICS = "Duet 3 MB6HC v1.02b or later"  # Platform.cpp:3991-3995
BOARD_NAME = "MB6HC"
GCODE_DIR = "0:/gcodes/"  # Configuration.h:280
DEFAULT_MACHINE_NAME = "My Duet"  # Configuration.h:270, for a printer with no identity
REPORT_INTERVAL = 2.0  # UnsolicitedStatusReportInterval, Configuration.h:80
CLOSE_ENOUGH = 1.5  # TemperatureCloseEnough (CANlib RRF3Common.h)
SO_LOW_DONT_CARE = 40.0  # TemperatureSoLowDontCare
HEATING_FAULT_TIME = 5.0  # s a heater may fall short of its expected rise (M570's default)
M999_DWELL = 1.0  # GCodes2.cpp:4711: DoDwellTime(1000), then the reset
COMPATIBILITY = ("Default", "RepRapFirmware", "Marlin", "Teacup", "Sprinter", "Repetier",
                 "NanoDLP")  # GCodeMachineState.h:150
HEATER_STATES = ("off", "standby", "active", "fault", "tuning", "offline")  # HeaterStatus
MAX_FANS = 20  # MaxFans on the MB6HC (M408 S0's fanPercent has one entry per fan and more)
STATUS_CHARACTERS = {"idle": "I", "printing": "P", "paused": "S", "halted": "H", "busy": "B"}


@dataclass
class RrfState:
    """What RRF keeps beside the model's state, for one boot (M999 resets the board)."""

    boot: int
    started: float  # when this boot's first command came (the model does not say when it booted)
    report_type: str = "none"  # GCodeBuffer::lastStatusReportType of the USB channel
    last_report: float = 0.0  # whenReportDueTimerStarted
    name: str | None = None  # M550 P: the name; None: config.g's (the printer's identity)
    mode: int = 2  # M555: Marlin, the USB channel's default (GCodes.cpp:123)
    faults: set[int] = field(default_factory=set)  # heaters in a fault state (RRF's numbers)
    paused: bool = False  # a print paused by M25 (or a heater fault)
    print_started: float | None = None
    print_name: str = ""  # the file as M23 named it


# The boot that powered the board up: the first in which the firmware did anything. (The model
# resets once when it is made and again as the server powers it up: the boot count does not
# say which boot is the power-up one, the first line the host sends does.) Every line the host
# sends is read by read_line() first, M999 included: a software reset always comes after it.
_FIRST_BOOT = "reprapfirmware.first_boot"


def rrf_state(printer, now: float = 0.0) -> RrfState:
    current = printer.extensions.get("reprapfirmware")
    if not isinstance(current, RrfState) or current.boot != printer.boots:
        current = RrfState(boot=printer.boots, started=now)
        printer.extensions["reprapfirmware"] = current
        printer.extensions.setdefault(_FIRST_BOOT, printer.boots)
    return current


def powered_up(printer) -> bool:
    """Whether this boot is the power-up one (else M999, a watchdog: a software reset)."""
    rrf_state(printer)
    return printer.extensions[_FIRST_BOOT] == printer.boots


def machine_name(printer) -> str:
    name = rrf_state(printer).name
    return name if name is not None else (printer.config.machine_name or DEFAULT_MACHINE_NAME)


# -- JSON, as RRF prints numbers: a float with the decimals its field has -----------------
class Fixed(float):
    """A number RRF prints with a fixed number of decimals (`%.1f`)."""

    decimals: int

    def __new__(cls, value: float, decimals: int = 1) -> "Fixed":
        number = super().__new__(cls, value)
        number.decimals = decimals
        return number


def to_json(value: object) -> str:
    """Compact JSON (json's strings, ints and literals), with each Fixed as RRF formats it."""
    if isinstance(value, Fixed):
        return f"{float(value):.{value.decimals}f}"
    if isinstance(value, dict):
        return "{" + ",".join(f"{json.dumps(key)}:{to_json(item)}"
                              for key, item in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(to_json(item) for item in value) + "]"
    if isinstance(value, float):
        return json.dumps(round(value, 6))
    return json.dumps(value, ensure_ascii=False)


def _json_reply(text: str) -> Reply:
    return reply(state("json_reply", json=text))


# -- parameters, as RRF's StringParser reads them -----------------------------------------
@dataclass(frozen=True)
class Param:
    value: str
    quoted: bool
    column: int  # where its value starts, 1-based, as `at column` counts


def params(command: Command) -> dict[str, Param]:
    """The parameters after the command word: a letter, then a "quoted string" ("" inside is
    one quote) or the text up to the next space. Letters are upper case outside quotes."""
    text = command.text
    found: dict[str, Param] = {}
    position = len(command.code) if text[:len(command.code)].upper() == command.code else 0
    while position < len(text):
        if text[position].isspace():
            position += 1
            continue
        letter = text[position].upper()
        position += 1
        if position < len(text) and text[position] == '"':
            start, position, value = position + 1, position + 1, []
            while position < len(text):
                if text[position] == '"':
                    if text[position + 1:position + 2] == '"':
                        value.append('"')
                        position += 2
                        continue
                    position += 1
                    break
                value.append(text[position])
                position += 1
            found.setdefault(letter, Param("".join(value), True, start))
        else:
            start = position
            while position < len(text) and not text[position].isspace():
                position += 1
            found.setdefault(letter, Param(text[start:position], False, start + 1))
    return found


class _BadParameter(Exception):
    """A parameter's value that StringParser refuses: the command's reply is the error."""

    def __init__(self, statement: Statement) -> None:
        super().__init__(statement.key)
        self.statement = statement


def _refusing(handler):
    """`handler`, with a _BadParameter as its reply (`Error: ...`, then `ok`)."""

    def run(printer, command: Command, now: float):
        try:
            return handler(printer, command, now)
        except _BadParameter as bad:
            return reply(bad.statement)

    run.__doc__ = handler.__doc__
    return run


_INT32_MIN, _INT32_MAX, _UINT32_MAX = -(2 ** 31), 2 ** 31 - 1, 2 ** 32 - 1
# NumericConverter::Accumulate (RRFLibraries): spaces and tabs, a sign, digits; a float's
# fraction and exponent (an E needs digits after it, or there is no number at all).
_DIGITS = re.compile(r"[ \t]*([+-]?)(\d+)")
_FLOAT = re.compile(r"[ \t]*[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE](?:[+-]?\d+|(?P<bad>)))?")


def _value_text(command: Command, found: Param) -> str:
    """What follows the parameter's letter, as StringParser reads the number from there."""
    return command.text[found.column - 1:]


def _expected_number(command: Command, letter: str, found: Param) -> _BadParameter:
    # GCodeException::GetMessage: ` at column <n>: M20: expected number after 'S'` (the
    # column is where the value should start, 1-based), after the reply's `Error: `.
    text = f" at column {found.column}: {command.code}: expected number after '{letter}'"
    return _BadParameter(state("firmware_error", text=text))


def _integer(command: Command, given: dict[str, Param], letter: str, default: int,
             unsigned: bool = False) -> int:
    """GetIValue() (GetUIValue() if `unsigned`) of the parameter, `default` without it (or
    with no value, as this model has always read it): StrToI32/StrToU32, digits up to the
    first that is not one (`S2.5` and `S1e9` are 2 and 1), a value too large for 32 bits the
    type's limit; no digits (`Sabc`, `Snan`, a sign for an unsigned one) the parse error."""
    found = given.get(letter)
    if found is None or not found.value:
        return default
    match = _DIGITS.match(_value_text(command, found))
    if match is None or (unsigned and match[1] == "-"):
        raise _expected_number(command, letter, found)
    value = int(match[2]) * (-1 if match[1] == "-" else 1)
    if unsigned:
        return min(value, _UINT32_MAX)
    return max(_INT32_MIN, min(_INT32_MAX, value))


def _float(command: Command, given: dict[str, Param], letter: str, default: float) -> float:
    """GetFValue() of the parameter, `default` without it (or with no value): a number as
    SafeStrtof reads it (a float too large is infinite); none (`Tabc`, `Tnan`, `T1e`) is the
    parse error."""
    found = given.get(letter)
    if found is None or not found.value:
        return default
    match = _FLOAT.match(_value_text(command, found))
    if match is None or match["bad"] is not None:
        raise _expected_number(command, letter, found)
    return float(match[0].strip(" \t"))


def _unprecedented(command: Command) -> str:
    """GetUnprecedentedString(): the rest of the line, quotes taken off (M23, M30, M36)."""
    text = command.string_argument.strip()
    if len(text) >= 2 and text[0] == '"' and text[-1] == '"':
        text = text[1:-1].replace('""', '"')
    return text


# -- the report while a USB command executes (GCodes::CheckReportDue) ---------------------
def reporting(handler):
    """`handler`, with the temperature line RRF sends while it is still executing: every
    REPORT_INTERVAL from the last M105 (or report), once the host has sent M105
    (GCodes.cpp:4916-4961, GCodeBuffer.cpp:194-216). Marlin's own M109 lines are dropped."""

    def reported(printer, command: Command, now: float):
        outcome = handler(printer, command, now)
        if not isinstance(outcome, Generator):
            return outcome
        return (yield from _reports_while(printer, outcome, now))

    return reported


def _reports_while(printer, steps, now: float):
    rrf = rrf_state(printer, now)
    try:
        step = next(steps)
        while True:
            if isinstance(step, Sleep):
                while rrf.report_type == "m105" and not printer.halted:
                    due = rrf.last_report + REPORT_INTERVAL
                    if due >= step.until:
                        break
                    if due > now:
                        now = yield Sleep(due)
                    rrf.last_report = now
                    now = yield Report(heating.temperature_report(printer, now))
                now = yield step
            elif isinstance(step, Report) and step.statement.key != "heating":
                now = yield step
            step = steps.send(now)
    except StopIteration as finished:
        return finished.value


# -- temperatures --------------------------------------------------------------------------
def heater_number(printer, heater) -> int:
    return 0 if heater is printer.bed else printer.hotends.index(heater) + 1


def heater_status(printer, number: int) -> int:
    """HeaterStatus as RRF numbers it: 0 off, 2 active (T0 is selected, so its heater is
    active even at 0), 3 fault."""
    if number in rrf_state(printer).faults:
        return 3
    heater = printer.bed if number == 0 else printer.hotends[number - 1]
    return 2 if number != 0 or heater.target > 0 else 0


def report_temperatures(printer, command: Command, now: float):
    """M105: `ok T:.. /.. T0:.. /.. B:.. /..`; it turns on the reports of CheckReportDue."""
    rrf = rrf_state(printer, now)
    rrf.report_type, rrf.last_report = "m105", now
    return Reply(answer=heating.temperature_report(printer, now))


def _set_target(printer, heater, target: float, now: float) -> None:
    if heater_number(printer, heater) not in rrf_state(printer, now).faults:
        heater.set_target(now, target)


def _target_tool(printer, command: Command) -> int | Reply:
    """The tool a T word names (TryGetIValue), the selected one without it; or the refusal
    (`Invalid tool number`, or T's number that cannot be read)."""
    try:
        tool = _integer(command, params(command), "T", printer.active_tool)
    except _BadParameter as bad:
        return reply(bad.statement)
    if 0 <= tool < len(printer.hotends):
        return tool
    return reply(state("invalid_extruder", code=command.code, tool=tool))


def set_hotend(printer, command: Command, now: float):
    """M104 S/R [T]: the tool's active and standby temperature; no reply."""
    tool = _target_tool(printer, command)
    if isinstance(tool, Reply):
        return tool
    if command.has("S") or command.has("R"):
        _set_target(printer, printer.hotends[tool],
                    command.value("S", command.value("R", 0.0)), now)
    return reply()


def set_bed(printer, command: Command, now: float):
    """M140 S: the bed's active temperature; with no parameter its temperature."""
    if command.has("S") or command.has("R"):
        _set_target(printer, printer.bed, command.value("S", command.value("R", 0.0)), now)
        return reply()
    return reply(state("bed_temperature", temperature=printer.bed.temperature(now)))


def _at_temperature(printer, heater, now: float, wait_cooling: bool) -> bool:
    """Heat::HeaterAtSetTemperature for a USB wait (waitOnFault false): a heater off or in
    fault is not waited for, nor a target under 40 C, nor (without R) one below it."""
    number = heater_number(printer, heater)
    if number in rrf_state(printer).faults or heater.target == 0.0:
        return True
    current = heater.temperature(now)
    return (heater.target < SO_LOW_DONT_CARE or abs(current - heater.target) <= CLOSE_ENOUGH
            or (heater.target < current and not wait_cooling))


def _wait_for(printer, heaters: list, now: float, wait_cooling: bool):
    """Until every heater is at its temperature; a heater that does not rise (broken) faults
    after HEATING_FAULT_TIME, which ends the wait (LocalHeater.cpp:323)."""
    rising_since = {id(heater): (now, heater.temperature(now)) for heater in heaters}
    while not printer.halted:
        waiting = [heater for heater in heaters
                   if not _at_temperature(printer, heater, now, wait_cooling)]
        if not waiting:
            return now
        for heater in waiting:
            since, was = rising_since[id(heater)]
            if heater.broken and heater.target > heater.temperature(now):
                if now - since >= HEATING_FAULT_TIME:
                    measured = (heater.temperature(now) - was) / (now - since)
                    for line in raise_fault(printer, heater, now, "heater_fault_rising",
                                            expected=_expected_rise(heater, was),
                                            measured=measured):
                        yield Report(line)
        wake = min(min(heater.reached_at(now), now + 1.0) for heater in waiting)
        now = yield Sleep(max(wake, now + 0.01))
    return now


def _expected_rise(heater, temperature: float) -> float:
    """The model's rate at full power (C/s), as RRF's heater model expects it."""
    spec = heater.spec
    return (spec.saturation - temperature) / spec.heat_tau


def wait_hotend(printer, command: Command, now: float):
    """M109 S|R [T]: set the tool's temperature, wait for its moves, then for the heater."""
    tool = _target_tool(printer, command)
    if isinstance(tool, Reply):
        return tool
    if not (command.has("S") or command.has("R")):
        return reply()
    now = yield from motion.synchronize(printer, now)
    heater = printer.hotends[tool]
    _set_target(printer, heater, command.value("S", command.value("R", 0.0)), now)
    yield from _wait_for(printer, [heater], now, wait_cooling=command.has("R"))
    return reply()


def wait_bed(printer, command: Command, now: float):
    """M190 S|R: set the bed's temperature and wait for it."""
    if not (command.has("S") or command.has("R")):
        return reply()
    _set_target(printer, printer.bed, command.value("S", command.value("R", 0.0)), now)
    yield from _wait_for(printer, [printer.bed], now, wait_cooling=command.has("R"))
    return reply()


def wait_all(printer, command: Command, now: float):
    """M116: wait for every heater (of the tools, and the bed) to be at its temperature."""
    yield from _wait_for(printer, [*printer.hotends, printer.bed], now, wait_cooling=False)
    return reply()


def raise_fault(printer, heater, now: float, key: str, **values: object) -> tuple[Statement, ...]:
    """LocalHeater::RaiseHeaterFault, and GCodes::ProcessEvent's default with no
    heater-fault.g (GCodes3.cpp:1520-1572): the heater off, a pause if printing, the alert."""
    rrf = rrf_state(printer, now)
    number = heater_number(printer, heater)
    if number in rrf.faults:
        return ()
    rrf.faults.add(number)
    heater.set_target(now, 0.0)
    printing = printer.sd.printing
    if printing:
        printer.sd.printing = False
        rrf.paused = True
    title = "Printing paused" if printing else "Event notification"
    return (state(key, title=title, heater=number, **values),)


def heater_fault(printer, reason: str, heater_name: str, now: float) -> tuple[Statement, ...]:
    """A thermal error (failures.thermal_error): a heater fault, not a halt."""
    heater = failures.heater(printer, heater_name)
    if reason == "thermal_runaway":
        return raise_fault(printer, heater, now, "heater_fault_excursion", target=heater.target,
                           actual=heater.temperature(now))
    if reason == "mintemp":
        return raise_fault(printer, heater, now, "heater_fault_sensor",
                           error="sensor open circuit")
    if reason == "maxtemp":
        return raise_fault(printer, heater, now, "heater_fault_monitor", monitor=0)
    temperature = heater.temperature(now)
    return raise_fault(printer, heater, now, "heater_fault_rising",
                       expected=_expected_rise(heater, temperature), measured=0.0)


@_refusing
def clear_fault(printer, command: Command, now: float):
    """M562 [P<heater>]: the fault cleared; the heater stays off until it is set again."""
    rrf = rrf_state(printer, now)
    given = params(command)
    if "P" in given:
        rrf.faults.discard(_integer(command, given, "P", 0, unsigned=True))
    else:
        rrf.faults.clear()
    return reply()


# -- halts and resets ----------------------------------------------------------------------
def emergency_stop(printer, command: Command, now: float):
    """M112, in its turn (USB has no emergency parser): everything stops, the message, and
    `ok`; the printer is halted from then on (GCodes2.cpp:1930, GCodes.cpp:853-858)."""
    if printer.halted:
        return reply(state("m112_shutdown"))
    return Reply(printer.kill(state("m112_shutdown"), now), effect="halted")


def reset(printer, command: Command, now: float):
    """M999: a second's dwell for the output to drain, then the board resets: no reply, no
    `ok` (GCodes2.cpp:4711-4768)."""
    yield Sleep(now + M999_DWELL)
    return Reply(effect="reset")


# -- lines and meta commands ---------------------------------------------------------------
_COMMAND = re.compile(r"[GMT]\d*$|[GM]\d+\.\d+$")


def read_line(printer, command: Command, now: float):
    """A line that is no G, M or T code (GCodes2.cpp:149-152): `Error: Bad command: X10`; an
    `echo` meta command says its expression; None for the code's handler."""
    printer.extensions.setdefault(_FIRST_BOOT, printer.boots)  # this boot runs: see _FIRST_BOOT
    if _COMMAND.match(command.code) and command.code not in ("G", "M"):
        return None
    if command.code == "ECHO":
        return _echo(printer, command, now)
    return reply(state("bad_command", text=command.text))


def _echo(printer, command: Command, now: float):
    """`echo "text"` or `echo <object model path>`, several separated by commas."""
    parts = []
    for expression in re.findall(r'"(?:[^"]|"")*"|[^,]+', command.string_argument):
        expression = expression.strip()
        if expression.startswith('"'):
            parts.append(expression[1:-1].replace('""', '"'))
        else:
            found, value = lookup(object_model(printer, now), expression)
            parts.append("null" if not found else
                         value if isinstance(value, str) else to_json(value))
    return reply(state("text_reply", text=" ".join(parts)))


def report_tool(printer, command: Command, now: float):
    """T with no number: which tool is selected (T0, from config.g)."""
    return reply(state("tool_selected", tool=printer.active_tool))


def serial_print(printer, command: Command, now: float):
    """M118 S"text" [P]: the text must be quoted (GetQuotedString)."""
    found = params(command).get("S")
    if found is None:
        return reply(state("missing_parameter", code=command.code, letter="S"))
    if not found.quoted:
        return reply(state("expected_string", code=command.code, column=found.column))
    return reply(state("text_reply", text=found.value))


@_refusing
def message_box(printer, command: Command, now: float):
    """M291 P"msg" [R"title"] [S<mode>] [T<timeout>], from USB: printed, never blocking
    (RepRap.cpp:2745-2780, GCodes7.cpp:14-113); M292 then finds no box and answers `ok`."""
    given = params(command)
    if "P" not in given:
        return reply(state("missing_parameter", code=command.code, letter="P"))
    mode = _integer(command, given, "S", 1, unsigned=True)
    timeout = _float(command, given, "T", 10.0 if mode <= 1 else 0.0)
    if mode == 0 and timeout <= 0:
        return reply(state("message_not_dismissable", code=command.code))
    lines = []
    title = given["R"].value if "R" in given else ""
    if title:
        lines.append(state("message_title", title=title))
    lines.append(state("message_text", text=given["P"].value))
    if mode == 2:
        lines.append(state("message_continue"))
    elif mode == 3:
        lines.append(state("message_continue_or_cancel"))
    return reply(*lines)


def set_name(printer, command: Command, now: float):
    """M550 [P"name"]: set the machine name, or report it."""
    given = params(command)
    if "P" in given:
        rrf_state(printer, now).name = given["P"].value
        return reply()
    return reply(state("machine_name", name=machine_name(printer)))


def network(printer, command: Command, now: float):
    """M552: the MB6HC's Ethernet (LwipEthernetInterface.cpp:286-294)."""
    return reply(state("network_state", state="enabled", configured="0.0.0.0",
                       actual="192.168.1.50"))


@_refusing
def output_mode(printer, command: Command, now: float):
    """M555 [P<n>]: the channel's compatibility (GCodes2.cpp:3540-3550). It is kept and
    reported; the emulated framing stays Marlin's (docs/firmwares.md)."""
    rrf = rrf_state(printer, now)
    given = params(command)
    if "P" in given:
        if given["P"].value:  # (P alone: nothing, as the model has always taken it)
            rrf.mode = max(0, min(len(COMPATIBILITY) - 1, _integer(command, given, "P", 0)))
        return reply()
    return reply(state("output_mode", mode=COMPATIBILITY[rrf.mode]))


def diagnostics(printer, command: Command, now: float):
    """M122: the header of RepRap::Diagnostics and the start of its Platform section."""
    rrf = rrf_state(printer, now)
    up = int(max(0.0, now - rrf.started))
    # The board's unique ID, drawn from the machine name: the same in every process (str's
    # hash() is not: PYTHONHASHSEED salts it).
    name = printer.config.machine_name
    digest = int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "big") >> 1 if name else 0
    board = "-".join(f"{(digest >> (5 * i)) & 0xFFFFF:05X}" for i in range(6))
    software = ("Last software reset details not available" if powered_up(printer) else
                "Last software reset at 2024-09-18 12:00, reason: User, Gcodes spinning, "
                "available RAM 105268, slot 0")
    return reply(state("diagnostics", firmware=FIRMWARE_NAME, version=VERSION,
                       electronics=ELECTRONICS, board_id=board, hours=up // 3600,
                       minutes=up % 3600 // 60, seconds=up % 60,
                       cause="power up" if powered_up(printer) else "software",
                       last_software_reset=software))


def not_from_usb(printer, command: Command, now: float):
    """M600 (and M601) from USB: only within a file being printed (GCodes2.cpp:1201-1207)."""
    return reply(state("only_in_file", code=command.code))


def stop(printer, command: Command, now: float):
    """M0/M1 from USB: cancels a paused print, else says to pause first (GCodes2.cpp:720)."""
    rrf = rrf_state(printer, now)
    if not rrf.paused:
        return reply(state("cancel_needs_pause", code=command.code))
    rrf.paused = False
    printer.sd.printing = False
    printer.sd.selected = None
    for heater in (*printer.hotends, printer.bed):  # no stop.g: SwitchOffAll
        heater.set_target(now, 0.0)
    return reply()


def nothing(printer, command: Command, now: float):
    """M500-M502 (config-override.g, config.g: nothing printed) and M292 from USB."""
    return reply()


CONFIG_G = """; config.g as fake-marlin emulates it (RepRapFirmware 3.5, Duet 3 MB6HC)
G90                                      ; absolute coordinates
M83                                      ; relative extruder moves
M550 P"{name}"                           ; set printer name
M552 S1                                  ; enable network
M584 X0.0 Y0.1 Z0.2 E0.3                 ; set drive mapping
M92 X80.00 Y80.00 Z400.00 E420.00        ; set steps per mm
M203 X18000.00 Y18000.00 Z2400.00 E2700.00 ; set maximum speeds (mm/min)
M201 X3000.00 Y3000.00 Z100.00 E10000.00 ; set accelerations (mm/s^2)
M208 X0 Y0 Z0 S1                         ; set axis minima
M208 X235 Y235 Z250 S0                   ; set axis maxima
M564 H0                                  ; allow moves before homing
M302 P1                                  ; allow cold extrusion
M308 S0 P"temp0" Y"thermistor" T100000 B4138 ; bed sensor
M950 H0 C"out0" T0                       ; bed heater
M140 H0                                  ; map heated bed to heater 0
M308 S1 P"temp1" Y"thermistor" T100000 B4138 ; hotend sensor
M950 H1 C"out1" T1                       ; hotend heater
M563 P0 D0 H1 F0                         ; define tool 0
G10 P0 X0 Y0 Z0                          ; set tool 0 axis offsets
G10 P0 R0 S0                             ; set initial tool 0 active and standby temperatures
T0                                       ; select first tool"""


def print_config(printer, command: Command, now: float):
    """M503: config.g, as it is on the card (the one this emulation stands for)."""
    return reply(state("text_reply", text=CONFIG_G.replace("{name}", machine_name(printer))))


# -- the SD card: 0:/gcodes/ is the model's card directory ---------------------------------
def _card_path(printer, name: str) -> Path | None:
    """MassStorage::CombineName(0:/gcodes/, name): a name starting with `/` or `0:` is from
    the card's root, where only /gcodes/ is the model's directory; None outside it."""
    root = printer.sd.root
    if root is None:
        return None
    if name.startswith("0:"):
        name = name[2:]
    if name.startswith("/"):
        parts = [part for part in name.split("/") if part]
        if not parts or parts[0] != "gcodes":
            return None
        name = "/".join(parts[1:])
    return printer.sd.inside(root / name, root_too=True)


def _print_status(printer) -> str:
    if printer.halted:
        return "halted"
    if printer.sd.printing:
        return "printing"
    if rrf_state(printer).paused:
        return "paused"
    return "idle"


@_refusing
def list_files(printer, command: Command, now: float):
    """M20 [S2|S3] [P"dir"] [R<first>] (GCodes2.cpp:947-1020, RepRap.cpp:1855-2031)."""
    given = params(command)
    kind = _integer(command, given, "S", 0)
    first = _integer(command, given, "R", 0, unsigned=True)
    asked = given["P"].value if "P" in given else GCODE_DIR
    directory = _card_path(printer, asked) if printer.sd.mounted else None
    entries = printer.sd.listing(directory) if directory is not None else None
    if kind == 2:
        head = {"dir": asked, "first": first}
        if not printer.sd.mounted:
            return _json_reply(to_json({**head, "files": [], "err": 1}) + "\n")
        if entries is None:
            return _json_reply(to_json({**head, "files": [], "err": 2}) + "\n")
        names = [("*" if entry.is_dir else "") + entry.name for entry in entries
                 if not entry.name.startswith(".")][first:]
        return _json_reply(to_json({**head, "files": names, "next": 0, "err": 0}) + "\n")
    if kind == 3:
        head = {"dir": asked, "first": first}
        if not printer.sd.mounted:
            return _json_reply(to_json({**head, "files": [], "err": 1}) + "\n")
        if entries is None:
            return _json_reply(to_json({**head, "files": [], "err": 2}) + "\n")
        files = []
        for entry in [entry for entry in entries if not entry.name.startswith(".")][first:]:
            files.append({"type": "d" if entry.is_dir else "f", "name": entry.name,
                          "size": 0 if entry.is_dir else entry.size,
                          "date": _iso_time(entry.mtime)})
        return _json_reply(to_json({**head, "files": files, "next": 0}) + "\n")
    # Marlin mode: each name on its line between Begin and End, NONE for none.
    lines = [state("file_list_begin")]
    if entries:
        lines += [state("text_reply", text=entry.name) for entry in entries]
    else:
        lines.append(state("text_reply", text="NONE"))
    lines.append(state("file_list_end"))
    return reply(*lines)


def _iso_time(stamp: float) -> str:
    try:
        return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(stamp))
    except (OverflowError, OSError, ValueError):  # beyond what the C library's time_t holds
        return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(0))


def mount(printer, command: Command, now: float):
    """M21: mounts the card again (MassStorage.cpp:1118-1210)."""
    if not printer.sd.inserted():
        return reply(state("no_card", code=command.code))
    printer.sd.reset()
    return reply(state("card_mounted", type="SDHC", slot=0, capacity=31.91, unit="Gb"))


def release(printer, command: Command, now: float):
    """M22: `SD card 0 may now be removed`."""
    printer.sd.reset()
    printer.sd.mounted = False
    return reply(state("card_removable", slot=0))


def select_file(printer, command: Command, now: float):
    """M23/M32 <name>: `File opened\\nFile selected`; M32 starts printing it too."""
    rrf = rrf_state(printer, now)
    if printer.sd.printing:
        return reply(state("already_printing", code=command.code))
    name = _unprecedented(command)
    path = _card_path(printer, name) if printer.sd.mounted and name else None
    entry = printer.sd.stat(path)
    data = printer.sd.read(entry.path) if entry is not None and entry.is_file else None
    if path is None or data is None:
        return reply(state("file_not_found", code=command.code, name=name))
    printer.sd.selected = OpenFile(path, name, data)
    printer.sd.printing = False
    rrf.paused = False
    rrf.print_name = name
    if command.code == "M32":
        printer.sd.printing = True
        rrf.print_started = now
    return reply(state("file_opened", name=name, size=len(printer.sd.selected.data),
                       long=path.name), state("file_selected"))


def start_print(printer, command: Command, now: float):
    """M24: start or resume; no reply text."""
    rrf = rrf_state(printer, now)
    if printer.sd.selected is None:
        return reply(state("no_file_selected", code=command.code))
    if not printer.sd.printing:
        if not rrf.paused:
            rrf.print_started = now
        printer.sd.printing = True
        rrf.paused = False
    return reply()


def pause_print(printer, command: Command, now: float):
    """M25: `Printing paused at X.. Y.. Z..` once the moves have stopped."""
    rrf = rrf_state(printer, now)
    if rrf.paused:
        return reply(state("already_paused", code=command.code))
    if not printer.sd.printing:
        return reply(state("not_printing", code=command.code))
    printer.sd.printing = False
    rrf.paused = True
    now = yield from motion.synchronize(printer, now)
    x, y, z, _ = printer.motion.position
    return reply(state("paused_at", x=x, y=y, z=z))


@_refusing
def set_file_position(printer, command: Command, now: float):
    """M26 S<byte>: S is required."""
    if not command.has("S"):
        return reply(state("missing_parameter", code=command.code, letter="S"))
    position = _integer(command, params(command), "S", 0, unsigned=True)
    if printer.sd.selected is not None:
        printer.sd.selected.position = position
    return reply()


def report_print(printer, command: Command, now: float):
    """M27: `SD printing byte a/b` or `Not SD printing.`."""
    selected = printer.sd.selected
    if selected is not None and (printer.sd.printing or rrf_state(printer, now).paused):
        return reply(state("sd_printing_byte", position=selected.position,
                           size=len(selected.data)))
    return reply(state("not_sd_printing"))


def begin_write(printer, command: Command, now: float):
    """M28 <name>: `ok` first, then `Writing to file: <name>`; the lines up to M29 go into the
    file unanswered (StringParser.cpp:1774-1810)."""
    name = _unprecedented(command)
    path = _card_path(printer, name) if printer.sd.mounted and name else None
    if path is None or not printer.sd.create(path, make_folders=True):
        return Reply((state("cannot_write_file", name=name),), effect="no_ok")
    printer.sd.saving = path
    printer.sd.line_end = "\n"  # StringParser::WriteToFile: the line, then '\n'
    return Reply((state("writing_to_file", name=name),), effect="ok_first")


def end_write(printer, command: Command, now: float):
    """M29: `Done saving file.`, or with nothing open `GCode end-of-file being interpreted.`."""
    if printer.sd.saving is None:
        return reply(state("end_of_file"))
    printer.sd.saving = None
    return reply(state("done_saving"))


def delete_file(printer, command: Command, now: float):
    """M30 <name>: `ok`, or `Error: M30: delete failed`."""
    path = _card_path(printer, _unprecedented(command)) if printer.sd.mounted else None
    entry = printer.sd.stat(path)
    if path is None or entry is None or not entry.is_file or not printer.sd.delete(path):
        return reply(state("delete_failed", code=command.code))
    if printer.sd.selected is not None and printer.sd.selected.path == path:
        printer.sd.selected = None
        printer.sd.printing = False
    return reply()


def file_info(printer, command: Command, now: float):
    """M36 [name]: the file's information as JSON (RepRap.cpp:2139-2235)."""
    name = _unprecedented(command)
    selected = printer.sd.selected
    if not name:
        if selected is None or not (printer.sd.printing or rrf_state(printer).paused):
            return _json_reply(to_json({"err": 1, "fileName": ""}))
        path, shown = selected.path, rrf_state(printer).print_name
    else:
        found = _card_path(printer, name) if printer.sd.mounted else None
        entry = printer.sd.stat(found)
        if found is None or entry is None or not entry.is_file:
            return _json_reply(to_json({"err": 1, "fileName": name}))
        path, shown = found, name
    entry, data = printer.sd.stat(path), printer.sd.read(path)
    if entry is None or data is None:  # the file printing is gone from the card
        return _json_reply(to_json({"err": 1, "fileName": shown}))
    info: dict[str, object] = {"err": 0, "fileName": shown, "size": len(data),
                               "lastModified": _iso_time(entry.mtime)}
    info.update(_scan_gcode(data))
    if not name:
        started = rrf_state(printer).print_started
        info["printDuration"] = int(now - started) if started is not None else 0
    info["thumbnails"] = []
    info["generatedBy"] = _generator(data)
    return _json_reply(to_json(info) + "\n")


_Z = re.compile(rb"^G[01]\b[^;\n]*?\bZ(-?\d+(?:\.\d*)?)", re.MULTILINE)
_E = re.compile(rb"^G[01]\b[^;\n]*?\bE(-?\d+(?:\.\d*)?)", re.MULTILINE)


def _scan_gcode(data: bytes) -> dict[str, object]:
    """height, layerHeight, numLayers and filament, as the file's moves say them."""
    heights = sorted({float(z) for z in _Z.findall(data)})
    height = heights[-1] if heights else 0.0
    layer = heights[0] if heights else 0.0
    extruded = sum(float(e) for e in _E.findall(data) if float(e) > 0)
    return {"height": Fixed(height, 2), "layerHeight": Fixed(layer, 2),
            "numLayers": len(heights), "filament": [Fixed(extruded, 1)] if extruded else []}


def _generator(data: bytes) -> str:
    match = re.search(rb";\s*generated (?:by|with) ([^\r\n]+)", data[:4096], re.IGNORECASE)
    return match[1].decode("utf-8", "replace").strip() if match else ""


# -- JSON status (M408) and the object model (M409) ----------------------------------------
def _positions(printer) -> tuple[list[Fixed], Fixed]:
    x, y, z, e = printer.motion.position
    return [Fixed(x, 3), Fixed(y, 3), Fixed(z, 3)], Fixed(e, 1)


def _homed(printer) -> list[int]:
    return [1 if axis in printer.motion.homed else 0 for axis in "XYZ"]


def _fan_percent(printer) -> list[int]:
    return [round(speed * 100 / 255) for speed in printer.fans]


def status_response(printer, kind: int, now: float) -> str:
    """M408 S<kind> (GCodes2.cpp:3078-3102, RepRap.cpp:1124-1849), as its OutputBuffer."""
    rrf = rrf_state(printer, now)
    rrf.report_type, rrf.last_report = "m408", now
    status = STATUS_CHARACTERS[_print_status(printer)]
    xyz, e = _positions(printer)
    heaters = [printer.bed, *printer.hotends]
    temps = [Fixed(heater.temperature(now), 1) for heater in heaters]
    actives = [Fixed(heater.target, 1) for heater in heaters]
    states = [heater_status(printer, number) for number in range(len(heaters))]
    if kind in (0, 1):  # GetLegacyStatusResponse(S + 2), for PanelDue
        legacy = {"H": "S", "S": "A"}.get(status, status)
        body: dict[str, object] = {
            "status": legacy, "heaters": temps, "active": actives,
            "standby": [Fixed(0.0 if n == 0 else printer.hotends[n - 1].target, 1)
                        for n in range(len(heaters))],
            "hstat": states, "pos": xyz, "machine": xyz, "sfactor": Fixed(
                printer.motion.feedrate_percent, 1),
            "efactor": [Fixed(printer.motion.flow_percent, 1)], "babystep": Fixed(0.0, 3),
            "tool": printer.active_tool, "probe": "0",
            "fanPercent": [Fixed(_fan_percent(printer)[0], 1), *_fan_percent(printer),
                           *([-1] * (MAX_FANS - len(printer.fans)))],
            "fanRPM": [-1] * len(printer.fans), "homed": _homed(printer)}
        selected = printer.sd.selected
        if printer.sd.printing and selected is not None and selected.data:
            body["fraction_printed"] = Fixed(selected.position / len(selected.data), 4)
        body["msgBox.mode"] = -1
        if kind == 1:
            body.update({"geometry": "cartesian", "axes": 3, "totalAxes": 3, "axisNames": "XYZ",
                         "volumes": 2, "numTools": len(printer.hotends),
                         "myName": machine_name(printer), "firmwareName": FIRMWARE_NAME})
        return to_json(body) + "\n\n"  # its own `}\n`, then GenerateJsonStatusResponse's
    if kind == 5:
        return to_json(config_response(printer)) + "\n"
    kind = kind if kind in (3, 4) else 2
    body = {
        "status": status,
        "coords": {"axesHomed": _homed(printer), "wpl": 1, "xyz": xyz, "machine": xyz,
                   "extr": [e]},
        "speeds": {"requested": Fixed(0.0, 1), "top": Fixed(0.0, 1)},
        "currentTool": printer.active_tool,
    }
    if getattr(printer, "lcd_message", ""):
        body["output"] = {"message": printer.lcd_message}
    params_table: dict[str, object] = {"atxPower": -1, "fanPercent": _fan_percent(printer)}
    if kind == 3:
        params_table["fanNames"] = [""] * len(printer.fans)
    params_table.update({"speedFactor": Fixed(printer.motion.feedrate_percent, 1),
                         "extrFactors": [Fixed(printer.motion.flow_percent, 1)],
                         "babystep": Fixed(0.0, 3)})
    body["params"] = params_table
    body["sensors"] = {"probeValue": 0, "fanRPM": [-1] * len(printer.fans)}
    temps_table: dict[str, object] = {
        "bed": {"current": temps[0], "active": actives[0], "standby": Fixed(0.0, 1),
                "state": states[0], "heater": 0},
        "current": temps, "state": states}
    if kind == 3:
        temps_table["names"] = ["" for _ in heaters]
    temps_table["tools"] = {"active": [[Fixed(h.target, 1)] for h in printer.hotends],
                            "standby": [[Fixed(h.target, 1)] for h in printer.hotends]}
    temps_table["extra"] = []
    body["temps"] = temps_table
    body["time"] = Fixed(float(int(now - rrf.started)), 1)
    if kind == 3:
        body.update({
            "coldExtrudeTemp": Fixed(0.0, 1), "coldRetractTemp": Fixed(0.0, 1),  # M302 P1
            "compensation": "None", "controllableFans": 1, "tempLimit": Fixed(285.0, 1),
            "endstops": 0, "firmwareName": FIRMWARE_NAME, "firmwareVersion": VERSION,
            "geometry": "cartesian", "axes": 3, "totalAxes": 3, "axisNames": "XYZ",
            "volumes": 2, "mountedVolumes": 1 if printer.sd.mounted else 0,
            "mode": "FFF", "name": machine_name(printer),
            "probe": {"threshold": 500, "height": Fixed(0.7, 2), "type": 0},
            "tools": [{"number": n, "heaters": [n + 1], "drives": [n], "axisMap": [[0], [1]],
                       "fans": 1, "offsets": [Fixed(0.0, 2)] * 3}
                      for n in range(len(printer.hotends))],
            "mcutemp": {"min": Fixed(35.2, 1), "cur": Fixed(35.8, 1), "max": Fixed(36.1, 1)},
            "vin": {"min": Fixed(24.0, 1), "cur": Fixed(24.1, 1), "max": Fixed(24.2, 1)}})
    elif kind == 4:
        selected = printer.sd.selected
        fraction = (100.0 * selected.position / len(selected.data)
                    if printer.sd.printing and selected is not None and selected.data else 0.0)
        started = rrf.print_started
        duration = now - started if printer.sd.printing and started is not None else 0.0
        body.update({
            "currentLayer": 0, "currentLayerTime": Fixed(0.0, 1),
            "extrRaw": [e], "fractionPrinted": Fixed(fraction, 1),
            "filePosition": selected.position if selected is not None else 0,
            "printDuration": Fixed(duration, 1), "warmUpDuration": Fixed(0.0, 1),
            "timesLeft": {"file": Fixed(0.0, 1), "filament": Fixed(0.0, 1)}})
    return to_json(body) + "\n"


def config_response(printer) -> dict[str, object]:
    """M408 S5: GetConfigResponse (RepRap.cpp:1606-1690); the space before "sysdir" is RRF's
    (RepRap.cpp:1675), which to_json cannot keep, so status() puts it back."""
    limits = printer.limits
    drives = 10  # MaxAxesPlusExtruders shown as RRF does: every drive the build has
    feedrates = [*limits.max_feedrate, *([limits.max_feedrate[3]] * (drives - 4))]
    return {
        "axisMins": [Fixed(0.0, 2)] * 3, "axisMaxes": [Fixed(235.0, 2), Fixed(235.0, 2),
                                                       Fixed(250.0, 2)],
        "accelerations": [Fixed(limits.acceleration, 2)] * drives,
        "currents": [800] * drives, "firmwareElectronics": ELECTRONICS,
        "firmwareName": FIRMWARE_NAME, "firmwareVersion": VERSION, "boardName": BOARD_NAME,
        "firmwareDate": DATE, "sysdir": "0:/sys/", "idleCurrentFactor": Fixed(30.0, 1),
        "idleTimeout": Fixed(30.0, 1), "minFeedrates": [Fixed(10.0, 2)] * drives,
        "maxFeedrates": [Fixed(rate, 2) for rate in feedrates]}


@_refusing
def status(printer, command: Command, now: float):
    kind = _integer(command, params(command), "S", 0, unsigned=True)
    text = status_response(printer, kind, now)
    if kind == 5:
        text = text.replace(',"sysdir":', ', "sysdir":', 1)
    return _json_reply(text)


def object_model(printer, now: float) -> dict[str, object]:
    """The parts of RRF's object model fake-marlin has, in RRF's names and (alphabetical)
    order; fields RRF leaves out (FUNC_IF false, verbose) are left out here too."""
    rrf = rrf_state(printer, now)
    heaters = [printer.bed, *printer.hotends]
    xyz, e = _positions(printer)
    selected = printer.sd.selected
    printing = printer.sd.printing or rrf.paused
    limits = printer.limits
    uptime = int(max(0.0, now - rrf.started))
    job: dict[str, object] = {}
    if printing:
        job["build"] = None
        job["duration"] = int(now - rrf.print_started) if rrf.print_started is not None else 0
    file: dict[str, object] = {"filament": []}
    if printing:
        file["fileName"] = rrf.print_name
    file.update({"height": Fixed(0.0, 2), "lastModified": None, "layerHeight": Fixed(0.0, 2),
                 "numLayers": 0, "size": len(selected.data) if selected else 0,
                 "thumbnails": []})
    job["file"] = file
    job["filePosition"] = selected.position if selected is not None else 0
    if not printing:
        job["lastDuration"] = 0
        job["lastWarmUpDuration"] = 0
    job["timesLeft"] = {"filament": None, "file": None, "slicer": None}
    if printing:
        job["warmUpDuration"] = 0
    return {
        "boards": [{"canAddress": 0, "firmwareDate": DATE, "firmwareFileName":
                    "Duet3Firmware_MB6HC.bin", "firmwareName": FIRMWARE_NAME,
                    "firmwareVersion": VERSION, "name": ELECTRONICS, "shortName": BOARD_NAME,
                    "supportsDirectDisplay": False, "uniqueId": None}],
        "directories": {"system": "0:/sys/"},
        "fans": [{"actualValue": Fixed(speed / 255, 2), "name": "", "requestedValue":
                  Fixed(speed / 255, 2), "rpm": -1} for speed in printer.fans],
        "global": {},
        "heat": {
            "bedHeaters": [0, *([-1] * 11)], "chamberHeaters": [-1] * 4,
            "coldExtrudeTemperature": Fixed(0.0, 1), "coldRetractTemperature": Fixed(0.0, 1),
            "heaters": [{"active": Fixed(heater.target, 1), "avgPwm": Fixed(
                heater.power(now) / 127, 3), "current": Fixed(heater.temperature(now), 2),
                "max": Fixed(heater.spec.max_target, 1), "min": Fixed(-273.1, 1),
                "sensor": number, "standby": Fixed(0.0 if number == 0 else heater.target, 1),
                "state": HEATER_STATES[heater_status(printer, number)]}
                for number, heater in enumerate(heaters)]},
        "inputs": [{"compatibility": COMPATIBILITY[rrf.mode], "name": "usb",
                    "state": "idle" if not printer.sd.printing else "executing"}],
        "job": job,
        "limits": {},
        "move": {
            "axes": [{"homed": axis in printer.motion.homed, "letter": axis,
                      "machinePosition": xyz[index], "max": Fixed(235.0 if axis != "Z" else 250.0,
                                                                  1),
                      "min": Fixed(0.0, 1), "speed": Fixed(limits.max_feedrate[index] * 60, 1),
                      "userPosition": xyz[index], "visible": True}
                     for index, axis in enumerate("XYZ")],
            "currentMove": {"acceleration": Fixed(0.0, 1), "deceleration": Fixed(0.0, 1),
                            "extrusionRate": Fixed(0.0, 2), "requestedSpeed": Fixed(0.0, 1),
                            "topSpeed": Fixed(0.0, 1)},
            "extruders": [{"position": e, "rawPosition": e} for _ in printer.hotends],
            "kinematics": {"name": "cartesian"},
            "printingAcceleration": Fixed(limits.acceleration, 1),
            "speedFactor": Fixed(printer.motion.feedrate_percent / 100, 2),
            "travelAcceleration": Fixed(limits.acceleration, 1),
            "virtualEPos": Fixed(float(e), 5), "workplaceNumber": 0},
        "network": {"name": machine_name(printer), "interfaces": [
            {"actualIP": "192.168.1.50", "state": "active", "type": "ethernet"}]},
        "sensors": {"analog": [{"lastReading": Fixed(heater.temperature(now), 2),
                                "name": f"temp{number}", "type": "thermistor"}
                               for number, heater in enumerate(heaters)],
                    "endstops": [None, None, None], "probes": []},
        "seqs": {"boards": 0, "directories": 0, "fans": 0, "global": 0, "heat": 0,
                 "inputs": 0, "job": 0, "move": 0, "network": 0, "reply": 0, "sensors": 0,
                 "spindles": 0, "state": 0, "tools": 0, "volumes": 0},
        "spindles": [],
        "state": {"currentTool": printer.active_tool,
                  "displayMessage": getattr(printer, "lcd_message", ""), "gpOut": [],
                  "logFile": None, "logLevel": "off", "machineMode": "FFF",
                  "macroRestarted": False, "msUpTime": 0, "nextTool": printer.active_tool,
                  "powerFailScript": "", "previousTool": -1, "restorePoints": [],
                  "status": _print_status(printer), "time": None, "upTime": uptime},
        "tools": [{"active": [Fixed(heater.target, 1)], "axes": [[0], [1]],
                   "extruders": [number], "fans": [0], "heaters": [number + 1],
                   "name": "", "number": number, "offsets": [Fixed(0.0, 2)] * 3,
                   "standby": [Fixed(heater.target, 1)],
                   "state": "active" if number == printer.active_tool else "off"}
                  for number, heater in enumerate(printer.hotends)],
        "volumes": [{"mounted": printer.sd.mounted, "path": "0:/"},
                    {"mounted": False, "path": "1:/"}],
    }


_INDEX = re.compile(r"([^.\[\]]+)|\[(\d+)\]")


def lookup(model: object, key: str) -> tuple[bool, object]:
    """The value at `key` (`state.status`, `heat.heaters[1].current`); (False, None) where
    there is none."""
    value = model
    for name, index in _INDEX.findall(key):
        if name:
            if not isinstance(value, dict) or name not in value:
                return False, None
            value = value[name]
        else:
            if not isinstance(value, list) or int(index) >= len(value):
                return False, None
            value = value[int(index)]
    return True, value


def _limited(value: object, level: int, max_depth: int) -> object:
    """ObjectModel's depth limit (ObjectModel.cpp:644): an object at a level past it is `{}`;
    the root is level 1, each object inside another one level more (arrays do not count)."""
    if isinstance(value, dict):
        if level > max_depth:
            return {}
        return {key: _limited(item, level + 1, max_depth) for key, item in value.items()}
    if isinstance(value, list):
        return [_limited(item, level, max_depth) for item in value]
    return value


def model_query(printer, command: Command, now: float):
    """M409 [K"key"] [F"flags"]: `{"key":..,"flags":..,"result":..}` (RepRap.cpp:2300-2332);
    depth 1 for the whole model, 99 for a key, as F"d<n>" sets it (ObjectModel.cpp:512-708)."""
    rrf = rrf_state(printer, now)
    given = params(command)
    key = given["K"].value if "K" in given else ""
    flags = given["F"].value if "F" in given else ""
    rrf.report_type, rrf.last_report = "m409", now
    want_length = key.startswith("#")
    path = key[1:] if want_length else key
    depth = 99 if (want_length or path) else 1
    if (match := re.search(r"d(\d*)", flags)) is not None:
        depth = int(match[1] or 0)
    found, value = lookup(object_model(printer, now), path)
    if not found:
        result: object = None
    elif want_length:
        result = len(value) if isinstance(value, list) else None
    else:
        # The levels on the way count: the root and each object the key goes through.
        level = 1 + sum(1 for name, _ in _INDEX.findall(path) if name)
        result = _limited(value, level, depth)
    text = "{" + f'"key":{json.dumps(key)},"flags":{json.dumps(flags)},"result":' + to_json(
        result) + "}\n"
    return _json_reply(text)


HANDLERS: dict = {
    "(line)": read_line,
    failures.HEATER_FAULT: heater_fault,
    "T": report_tool,
    "M0": stop,
    "M1": stop,
    "M2": stop,
    "M20": list_files,
    "M21": mount,
    "M22": release,
    "M23": select_file,
    "M24": start_print,
    "M25": pause_print,
    "M26": set_file_position,
    "M27": report_print,
    "M28": begin_write,
    "M29": end_write,
    "M30": delete_file,
    "M32": select_file,
    "M36": file_info,
    "M104": set_hotend,
    "M105": report_temperatures,
    "M109": reporting(wait_hotend),
    "M112": emergency_stop,
    "M116": reporting(wait_all),
    "M118": serial_print,
    "M122": diagnostics,
    "M140": set_bed,
    "M190": reporting(wait_bed),
    "M291": message_box,
    "M292": nothing,
    "M408": status,
    "M409": model_query,
    "M500": nothing,
    "M501": nothing,
    "M502": nothing,
    "M503": print_config,
    "M550": set_name,
    "M552": network,
    "M555": output_mode,
    "M562": clear_fault,
    "M600": not_from_usb,
    "M601": not_from_usb,
    "M999": reset,
    # Marlin's, with the report RRF sends while they execute.
    **{code: reporting(motion.HANDLERS[code])
       for code in ("G0", "G1", "G2", "G3", "G4", "G28", "G29", "M400")},
}
