"""The commands of klipper that Marlin does not have (its profile's command set "klipper").

Each handler is `handler(printer, command, now) -> Reply | Step`, as in the other modules: it
states what happened (printer/statements.py); the profile says it in the firmware's words.

As Klipper v0.13.0's klippy does it (Klipper3d/klipper 61c0c8d2e: klippy/gcode.py,
extras/heaters.py, extras/gcode_move.py, extras/virtual_sdcard.py, extras/pause_resume.py,
extras/respond.py, extras/display_status.py, toolhead.py) for a printer.cfg with one extruder
(min_temp 0, max_temp 285: the model's), a heated bed, [fan], [virtual_sdcard], [pause_resume],
[display_status] and [respond]. Klipper's own commands (STATUS, SET_GCODE_OFFSET...) are word
commands, `KEY=value` parameters in shell quoting; the G/M codes it shares with Marlin it often
answers otherwise (M105 and M115 on the `ok` line, M109 waiting for 1 degree, M20 with its own
names), so those are here too. docs/firmwares.md has the source of each.
"""

import math
import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path

from fake_marlin.emulator.printer import heating, motion
from fake_marlin.emulator.printer.gcode import Command
from fake_marlin.emulator.printer.sdcard import OpenFile
from fake_marlin.emulator.printer.statements import Statement, state
from fake_marlin.emulator.printer.steps import Reply, Report, Sleep, reply
from fake_marlin.emulator.printer.thermal import Heater

# What these handlers state that the other sets do not, with sample values: the profiles with
# this set say each in their [messages] (printer/statements.py has the rest).
STATEMENTS: dict[str, dict[str, object]] = {
    # gcode.py: STATUS, HELP, ECHO; errors of a command's parameters
    "klipper_state": {"state": "Ready"},
    "status_halted": {},  # STATUS in the shutdown state: the message, `Not ready`, the error
    "help_not_ready": {},
    "help_header": {},
    "help_entry": {"command": "STATUS", "help": "Report the printer status"},
    "echo": {"text": "ECHO hello"},
    "malformed_command": {"line": "RESTART now"},
    "parameter_missing": {"line": "M26", "param": "S"},
    "parameter_unparsable": {"line": "M220 S=x", "value": "x"},
    "parameter_minimum": {"line": "G4 P-1", "param": "P", "limit": 0.0},
    "parameter_maximum": {"line": "M106 S300", "param": "S", "limit": 255.0},
    "parameter_above": {"line": "M220 S0", "param": "S", "limit": 0.0},
    "parameter_below": {"line": "SET_VELOCITY_LIMIT MINIMUM_CRUISE_RATIO=1", "param":
                        "MINIMUM_CRUISE_RATIO", "limit": 1.0},
    "invalid_value": {"value": "chamber", "param": "HEATER"},
    # heaters.py
    "temperature_out_of_range": {"target": 300.0, "minimum": 0.0, "maximum": 285.0},
    "unknown_sensor": {"sensor": "chamber"},
    "temperature_wait_unbounded": {},
    # gcode_move.py, toolhead.py, query_endstops.py, idle_timeout.py
    "no_inches": {},
    "position_details": {"mcu": (0, 0, 0), "stepper": (0.0, 0.0, 0.0),
                         "kinematic": (0.0, 0.0, 0.0), "toolhead": (0.0, 0.0, 0.0, 0.0),
                         "gcode": (0.0, 0.0, 0.0, 0.0), "base": (0.0, 0.0, 0.0, 0.0),
                         "homing": (0.0, 0.0, 0.0)},
    "unknown_gcode_state": {"name": "PAUSE_STATE"},
    "invalid_m204": {"line": "M204"},
    "velocity_limits": {"velocity": 300.0, "accel": 3000.0, "cruise_ratio": 0.5,
                        "corner": 5.0},
    "idle_timeout_set": {"seconds": 600.0},
    "endstops": {},
    # pause_resume.py
    "already_paused": {},
    "not_paused": {},
    # respond.py
    "respond_echo": {"text": "hello"},
    "respond_echo_no_space": {"text": "hello"},
    "respond_command": {"text": "action:pause"},
    "respond_error": {"text": "hello"},
    "respond_prefixed": {"prefix": "ok: ", "text": "hello"},  # the prefix with its space
    "invalid_respond_type": {"type": "warning"},
    # virtual_sdcard.py
    "sd_busy": {},
    "sd_write_unsupported": {},
    "file_list_failed": {},
}

MIN_TEMP = 0.0  # printer.cfg's min_temp of both heaters (the max is the model's max_target)
PID_SETTLE_DELTA = 1.0  # heaters.py ControlPID.check_busy(): busy while further off than this
WAIT_REPORT = 1.0  # _wait_for_temperature(): the M105 payload at once, then each second
RESTART_DWELL = 0.5  # request_restart(): toolhead.dwell(0.500), then wait_moves()
IDLE_TIMEOUT = 600.0  # idle_timeout.py's default
RECOVER_VELOCITY = 50.0  # pause_resume.py's recover_velocity default, mm/s
SD_EXTENSIONS = ("gcode", "g", "gco")  # virtual_sdcard.py VALID_GCODE_EXTS (subdirectories)
VELOCITY = 300.0  # printer.cfg's max_velocity, mm/s
SQUARE_CORNER_VELOCITY = 5.0  # toolhead.py's default
MINIMUM_CRUISE_RATIO = 0.5  # toolhead.py's default

# gcode.py: the commands registered with when_not_ready (and M118/RESPOND, GET_POSITION, M105,
# M114: their modules register them so): the only ones a shut-down Klipper still has.
WHEN_NOT_READY = frozenset({"M110", "M112", "M115", "RESTART", "FIRMWARE_RESTART", "ECHO",
                            "STATUS", "HELP", "M105", "M114", "GET_POSITION", "M118",
                            "RESPOND"})

# Each extended command's help text, as HELP lists them (`%-10s: %s`).
HELP_TEXTS = {
    "CANCEL_PRINT": "Cancel the current print",
    "CLEAR_PAUSE": "Clears the current paused state without resuming the print",
    "FIRMWARE_RESTART": "Restart firmware, host, and reload config",
    "GET_POSITION": "Return information on the current location of the toolhead",
    "HELP": "Report the list of available extended G-Code commands",
    "PAUSE": "Pauses the current print",
    "QUERY_ENDSTOPS": "Report on the status of each endstop",
    "RESPOND": "Echo the message prepended with a prefix",
    "RESTART": "Reload config file and restart host software",
    "RESTORE_GCODE_STATE": "Restore a previously saved G-Code state",
    "RESUME": "Resumes the print from a pause",
    "SAVE_GCODE_STATE": "Save G-Code coordinate state",
    "SDCARD_PRINT_FILE": "Loads a SD file and starts the print.  May include files in "
                         "subdirectories.",
    "SDCARD_RESET_FILE": "Clears a loaded SD File. Stops the print if necessary",
    "SET_DISPLAY_TEXT": "Set or clear the display message",
    "SET_GCODE_OFFSET": "Set a virtual offset to g-code positions",
    "SET_HEATER_TEMPERATURE": "Sets a heater temperature",
    "SET_IDLE_TIMEOUT": "Set the idle timeout in seconds",
    "SET_VELOCITY_LIMIT": "Set printer velocity limits",
    "STATUS": "Report the printer status",
    "TEMPERATURE_WAIT": "Wait for a temperature on a sensor",
    "TURN_OFF_HEATERS": "Turn off all heaters",
}


@dataclass
class KlipperState:
    """What klippy keeps beside the model's state, for one boot (a restart builds it anew)."""

    boot: int
    base: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])  # base_position
    homing: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0, 0.0])  # homing_position
    saved: dict[str, dict[str, object]] = field(default_factory=dict)  # SAVE_GCODE_STATE
    paused: bool = False  # pause_resume: is_paused
    sd_paused: bool = False
    pause_sent: bool = False
    display: str | None = None  # M117 / SET_DISPLAY_TEXT
    progress: float | None = None  # M73
    idle_timeout: float = IDLE_TIMEOUT
    velocity: float = VELOCITY
    corner_velocity: float = SQUARE_CORNER_VELOCITY
    cruise_ratio: float = MINIMUM_CRUISE_RATIO


def klipper_state(printer) -> KlipperState:
    """This boot's state (a new one after a reset: RESTART builds a new Printer object)."""
    current = printer.extensions.get("klipper")
    if not isinstance(current, KlipperState) or current.boot != printer.boots:
        current = KlipperState(boot=printer.boots)
        printer.extensions["klipper"] = current
    return current


class _Refused(Exception):
    """gcmd.error(): the command stops here, and the statement says why (then `ok`)."""

    def __init__(self, statement: Statement) -> None:
        super().__init__(statement.key)
        self.statement = statement


# -- parameters, as GCodeCommand.get() and _get_extended_params() read them ---------------
def extended_params(command: Command) -> dict[str, str]:
    """`KEY=value` pairs in shell quoting, `#` and `;` starting a comment, keys upper case."""
    lexer = shlex.shlex(command.string_argument, posix=True)
    lexer.whitespace_split = True
    lexer.commenters = "#;"
    try:
        pairs = [argument.split("=", 1) for argument in lexer]
        return {key.upper(): value for key, value in pairs}
    except ValueError:  # a word without `=`, an open quote
        raise _Refused(state("malformed_command", line=command.text)) from None


_MISSING = object()


def _get(command: Command, params: dict[str, str], name: str, parse, default):
    """GCodeCommand._get_wrapper(): the parameter's text through `parse`, or the refusal."""
    text = params.get(name)
    if text is None:
        if default is _MISSING:
            raise _Refused(state("parameter_missing", line=command.text, param=name))
        return default, False
    try:
        return parse(text), True
    except ValueError:
        raise _Refused(state("parameter_unparsable", line=command.text, value=text)) from None


def get_float(command: Command, params: dict[str, str], name: str, default=_MISSING,
              minval: float | None = None, maxval: float | None = None,
              above: float | None = None, below: float | None = None):
    """GCodeCommand.get_float() of an extended command's parameters."""
    value, given = _get(command, params, name, float, default)
    if given:
        _check_limits(command, name, value, minval, maxval, above, below)
    return value


def get_int(command: Command, params: dict[str, str], name: str, default=_MISSING,
            minval: int | None = None):
    """GCodeCommand.get_int() of an extended command's parameters: Python's int() of the
    text (`MOVE=1.5` and `MOVE=inf` cannot be parsed)."""
    value, given = _get(command, params, name, int, default)
    if given:
        _check_limits(command, name, value, minval, None, None, None)
    return value


# GCodeDispatch._process_commands: a traditional command's parameters are what follows each
# run of letters (the line upper case), as text.
_ARGS = re.compile(r"([A-Z_]+|[A-Z*])")


def _integer(command: Command, name: str, default=_MISSING, minval: int | None = None):
    """get_int() of a traditional G/M code's letter: its text as klippy splits the line
    (`M26 S1.5` cannot be parsed; a number of any size is one)."""
    parts = _ARGS.split(command.text.upper())
    params = {parts[index]: parts[index + 1].strip() for index in range(1, len(parts), 2)}
    return get_int(command, params, name, default, minval)


def _number(command: Command, name: str, default: float, minval: float | None = None,
            maxval: float | None = None, above: float | None = None) -> float:
    """The same for a traditional G/M code's letter (parsed as the model parses numbers)."""
    value = command.value(name)
    if value is None:
        return default
    _check_limits(command, name, value, minval, maxval, above, None)
    return value


def _check_limits(command: Command, name: str, value: float, minval, maxval, above,
                  below) -> None:
    for limit, key, fails in ((minval, "parameter_minimum", lambda v, m: v < m),
                              (maxval, "parameter_maximum", lambda v, m: v > m),
                              (above, "parameter_above", lambda v, m: v <= m),
                              (below, "parameter_below", lambda v, m: v >= m)):
        if limit is not None and fails(value, limit):
            raise _Refused(state(key, line=command.text, param=name, limit=limit))


def _refusable(handler):
    """A plain handler whose _Refused becomes its reply (the error, then `ok`)."""
    def run(printer, command: Command, now: float):
        try:
            return handler(printer, command, now)
        except _Refused as refused:
            return reply(refused.statement)
    run.__name__ = handler.__name__
    run.__doc__ = handler.__doc__
    return run


# -- gcode.py: the commands there before the config is read --------------------------------
def firmware_info(printer, command: Command, now: float):
    """M115: `ok FIRMWARE_NAME:Klipper FIRMWARE_VERSION:...`, on the `ok` line, in any state."""
    return Reply(answer=state("firmware_info", extruders=printer.config.extruders))


def status(printer, command: Command, now: float):
    if printer.halted:
        return reply(state("status_halted"))
    return reply(state("klipper_state", state="Ready"))


def help_list(printer, command: Command, now: float):
    names = [name for name in printer.handlers if name in HELP_TEXTS]
    lines: list[Statement] = []
    if printer.halted:
        names = [name for name in names if name in WHEN_NOT_READY]
        lines.append(state("help_not_ready"))
    lines.append(state("help_header"))
    lines += [state("help_entry", command=name, help=HELP_TEXTS[name]) for name in sorted(names)]
    return reply(*lines)


def echo(printer, command: Command, now: float):
    return reply(state("echo", text=command.text))


def restart(printer, command: Command, now: float):
    """RESTART, FIRMWARE_RESTART: heaters off, the moves done and half a second's dwell; then
    its `ok`, and klippy goes down (the session's restart effect) and comes up Ready."""
    for heater in (*printer.hotends, printer.bed):
        heater.set_target(now, 0.0)
    now = yield from motion.synchronize(printer, now)
    yield Sleep(now + RESTART_DWELL)
    return Reply(effect="restart")


# -- heaters.py, extruder.py, heater_bed.py -----------------------------------------------
def report_temperatures(printer, command: Command, now: float):
    """M105: every heater, sorted by its id (`B` before `T0`); a T word changes nothing."""
    return Reply(answer=heating.temperature_report(printer, now, 0))


def _waiting(printer, now: float) -> Statement:
    """The M105 payload as the waits print it each second, without `ok`."""
    return Statement("heating", {**heating.heats(printer, now, 0), "remaining": "?",
                                 "heater": "T0"})


def _set_target(heater, target: float, now: float) -> None:
    """Heater.set_temp(): a target outside min_temp..max_temp (but 0) is an error."""
    maximum = heater.spec.max_target
    if target and not MIN_TEMP <= target <= maximum:
        raise _Refused(state("temperature_out_of_range", target=target, minimum=MIN_TEMP,
                             maximum=maximum))
    heater.set_target(now, target)


def _wait_for(printer, heater, now: float):
    """_wait_for_temperature(): while check_busy() (PID: more than a degree off, either way),
    the temperatures at once and each second after; a shutdown ends it."""
    while not printer.halted and abs(heater.target - heater.temperature(now)) > PID_SETTLE_DELTA:
        yield Report(_waiting(printer, now))
        now = yield Sleep(now + WAIT_REPORT)
    return now


def _hotend(printer, command: Command):
    """The heater M104/M109 set: T<n> or the active extruder; None for a T<n> that is not
    configured and a target of 0 (nothing to do)."""
    target = command.value("S", 0.0)
    tool = _integer(command, "T", None, minval=0)  # PrinterExtruder.cmd_M104
    if tool is None:
        return printer.hotends[printer.active_tool], target
    if tool >= len(printer.hotends):
        if target <= 0:
            return None, target
        raise _Refused(state("invalid_extruder", code=command.code, tool=tool))
    return printer.hotends[tool], target


def set_heater(printer, command: Command, now: float):
    """M104, M140 (M109, M190 wait): S, or 0 without it."""
    try:
        if command.code in ("M104", "M109"):
            heater, target = _hotend(printer, command)
        else:
            heater, target = printer.bed, command.value("S", 0.0)
        if heater is not None:
            _set_target(heater, target, now)
    except _Refused as refused:
        return reply(refused.statement)
    if heater is not None and target and command.code in ("M109", "M190"):
        yield from _wait_for(printer, heater, now)
    return reply()


def _heaters_by_name(printer) -> dict[str, Heater]:
    names = {("extruder" if index == 0 else f"extruder{index}"): heater
             for index, heater in enumerate(printer.hotends)}
    return {**names, "heater_bed": printer.bed}


@_refusable
def set_heater_temperature(printer, command: Command, now: float):
    """SET_HEATER_TEMPERATURE HEATER=<name> [TARGET=<degrees>] (a mux command)."""
    params = extended_params(command)
    name = params.get("HEATER")
    if name is None:
        raise _Refused(state("parameter_missing", line=command.text, param="HEATER"))
    heater = _heaters_by_name(printer).get(name)
    if heater is None:
        raise _Refused(state("invalid_value", value=name, param="HEATER"))
    _set_target(heater, get_float(command, params, "TARGET", 0.0), now)
    return reply()


def turn_off_heaters(printer, command: Command, now: float):
    for heater in (*printer.hotends, printer.bed):
        heater.set_target(now, 0.0)
    return reply()


def temperature_wait(printer, command: Command, now: float):
    """TEMPERATURE_WAIT SENSOR=<name> [MINIMUM=] [MAXIMUM=]: until the sensor is in range."""
    try:
        params = extended_params(command)
        name = params.get("SENSOR")
        if name is None:
            raise _Refused(state("parameter_missing", line=command.text, param="SENSOR"))
        sensor = _heaters_by_name(printer).get(name)
        if sensor is None:
            raise _Refused(state("unknown_sensor", sensor=name))
        low = get_float(command, params, "MINIMUM", -math.inf)
        high = get_float(command, params, "MAXIMUM", math.inf, above=low)
        if low == -math.inf and high == math.inf:
            raise _Refused(state("temperature_wait_unbounded"))
    except _Refused as refused:
        return reply(refused.statement)
    while not printer.halted and not low <= sensor.temperature(now) <= high:
        yield Report(_waiting(printer, now))
        now = yield Sleep(now + WAIT_REPORT)
    return reply()


# -- gcode_move.py: positions, offsets and saved states ---------------------------------
@_refusable
def speed_factor(printer, command: Command, now: float):
    """M220 [S<percent>] (100 without S); S must be above 0."""
    printer.motion.feedrate_percent = _number(command, "S", 100.0, above=0.0)
    return reply()


@_refusable
def extrude_factor(printer, command: Command, now: float):
    """M221 [S<percent>] (100 without S); S must be above 0."""
    printer.motion.flow_percent = _number(command, "S", 100.0, above=0.0)
    return reply()


def inches(printer, command: Command, now: float):
    return reply(state("no_inches"))


def millimetres(printer, command: Command, now: float):
    return reply()


def home(printer, command: Command, now: float):
    """G28: Marlin's homing, then each homed axis's g-code position is the endstop (0) less
    the SET_GCODE_OFFSET of that axis (_handle_home_rails_end: base = homing_position)."""
    result = yield from motion.home(printer, command, now)
    klipper = klipper_state(printer)
    for index, axis in enumerate("XYZ"):
        if command.has(axis) or not any(command.has(a) for a in "XYZ"):
            klipper.base[index] = klipper.homing[index]
            printer.motion.position[index] = 0.0 - klipper.homing[index]  # (never -0.0)
    return result


def set_position(printer, command: Command, now: float):
    """G92: moves the base, not the toolhead (so GET_POSITION's toolhead stays)."""
    klipper = klipper_state(printer)
    before = list(printer.motion.position)
    result = motion.set_position(printer, command, now)
    for index, (old, new) in enumerate(zip(before, printer.motion.position)):
        klipper.base[index] += old - new
    return result


def toolhead_position(printer) -> list[float]:
    """last_position: the g-code position plus the base."""
    klipper = klipper_state(printer)
    return [gcode + base for gcode, base in zip(printer.motion.position, klipper.base)]


@_refusable
def set_gcode_offset(printer, command: Command, now: float):
    """SET_GCODE_OFFSET [X|Y|Z|E=<offset>] [<axis>_ADJUST=<delta>] [MOVE=1 [MOVE_SPEED=]]:
    without MOVE the toolhead stays and the g-code position shifts; with it, the other way."""
    params = extended_params(command)
    klipper = klipper_state(printer)
    deltas = [0.0, 0.0, 0.0, 0.0]
    for index, axis in enumerate("XYZE"):
        offset = get_float(command, params, axis, None)
        if offset is None:
            adjust = get_float(command, params, axis + "_ADJUST", None)
            if adjust is None:
                continue
            offset = adjust + klipper.homing[index]
        deltas[index] = offset - klipper.homing[index]
        klipper.base[index] += deltas[index]
        klipper.homing[index] = offset
    move = get_int(command, params, "MOVE", 0)
    get_float(command, params, "MOVE_SPEED", 1.0, above=0.0)
    if not move:
        for index, delta in enumerate(deltas):
            printer.motion.position[index] -= delta
    return reply()


@_refusable
def save_gcode_state(printer, command: Command, now: float):
    params = extended_params(command)
    klipper = klipper_state(printer)
    motion_state = printer.motion
    klipper.saved[params.get("NAME", "default")] = {
        "relative": motion_state.relative, "relative_e": motion_state.relative_e,
        "base": list(klipper.base), "last": toolhead_position(printer),
        "homing": list(klipper.homing), "feedrate": motion_state.feedrate,
        "feedrate_percent": motion_state.feedrate_percent,
        "flow_percent": motion_state.flow_percent,
    }
    return reply()


def restore_gcode_state(printer, command: Command, now: float):
    """RESTORE_GCODE_STATE [NAME=] [MOVE=1 [MOVE_SPEED=]]: the modes, offsets and speed back;
    E where it was; with MOVE, the toolhead back to where it was (a move)."""
    try:
        params = extended_params(command)
        name = params.get("NAME", "default")
        klipper = klipper_state(printer)
        saved = klipper.saved.get(name)
        if saved is None:
            raise _Refused(state("unknown_gcode_state", name=name))
        move = get_int(command, params, "MOVE", 0)
        speed = get_float(command, params, "MOVE_SPEED", printer.motion.feedrate / 60.0,
                          above=0.0)
    except _Refused as refused:
        return reply(refused.statement)
    last = toolhead_position(printer)
    motion_state = printer.motion
    motion_state.relative = bool(saved["relative"])
    motion_state.relative_e = bool(saved["relative_e"])
    motion_state.feedrate = float(saved["feedrate"])  # type: ignore[arg-type]
    motion_state.feedrate_percent = float(saved["feedrate_percent"])  # type: ignore[arg-type]
    motion_state.flow_percent = float(saved["flow_percent"])  # type: ignore[arg-type]
    saved_last: list[float] = saved["last"]  # type: ignore[assignment]
    klipper.base = list(saved["base"])  # type: ignore[call-overload]
    klipper.homing = list(saved["homing"])  # type: ignore[call-overload]
    klipper.base[3] += last[3] - saved_last[3]
    here = [toolhead - base for toolhead, base in zip(last, klipper.base)]
    if move:
        target = [saved_last[index] - klipper.base[index] for index in range(3)] + [here[3]]
        motion_state.position = here
        yield from motion.plan_move(printer, target, speed, now)
    else:
        motion_state.position = here
    return reply()


def get_position(printer, command: Command, now: float):
    """GET_POSITION: where the steppers are now (mcu, stepper, kinematic) and where the moves
    end (toolhead, gcode), with the offsets."""
    klipper = klipper_state(printer)
    toolhead = toolhead_position(printer)
    stepper = printer.planner.stepper_position(now, tuple(printer.motion.position))
    stepper = [value + base for value, base in zip(stepper[:3], klipper.base)]
    steps = [round(value * per_mm) for value, per_mm in zip(stepper, printer.config.steps_per_mm)]
    return reply(state("position_details", mcu=tuple(steps), stepper=tuple(stepper),
                       kinematic=tuple(stepper), toolhead=tuple(toolhead),
                       gcode=tuple(toolhead), base=tuple(klipper.base),
                       homing=tuple(klipper.homing[:3])))


# -- toolhead.py, query_endstops.py, idle_timeout.py, display_status.py, respond.py ---------
@_refusable
def dwell(printer, command: Command, now: float):
    """G4 P<ms> (no S in Klipper)."""
    seconds = _number(command, "P", 0.0, minval=0.0) / 1000.0
    return _dwell(printer, now, seconds)


def _dwell(printer, now: float, seconds: float):
    now = yield from motion.synchronize(printer, now)
    if seconds > 0:
        yield Sleep(now + seconds)
    return reply()


@_refusable
def acceleration(printer, command: Command, now: float):
    """M204 S<accel>, or P and T (the lower); else an info line and nothing changes."""
    accel = _number(command, "S", math.nan, above=0.0)
    if math.isnan(accel):
        print_accel = _number(command, "P", math.nan, above=0.0)
        travel_accel = _number(command, "T", math.nan, above=0.0)
        if math.isnan(print_accel) or math.isnan(travel_accel):
            return reply(state("invalid_m204", line=command.text))
        accel = min(print_accel, travel_accel)
    printer.limits.acceleration = accel
    return reply()


@_refusable
def set_velocity_limit(printer, command: Command, now: float):
    params = extended_params(command)
    klipper = klipper_state(printer)
    velocity = get_float(command, params, "VELOCITY", None, above=0.0)
    accel = get_float(command, params, "ACCEL", None, above=0.0)
    corner = get_float(command, params, "SQUARE_CORNER_VELOCITY", None, minval=0.0)
    ratio = get_float(command, params, "MINIMUM_CRUISE_RATIO", None, minval=0.0, below=1.0)
    if velocity is not None:
        klipper.velocity = velocity
    if accel is not None:
        printer.limits.acceleration = accel
    if corner is not None:
        klipper.corner_velocity = corner
    if ratio is not None:
        klipper.cruise_ratio = ratio
    if velocity is None and accel is None and corner is None and ratio is None:
        return reply(state("velocity_limits", velocity=klipper.velocity,
                           accel=printer.limits.acceleration, cruise_ratio=klipper.cruise_ratio,
                           corner=klipper.corner_velocity))
    return reply()


@_refusable
def set_idle_timeout(printer, command: Command, now: float):
    klipper = klipper_state(printer)
    params = extended_params(command)
    klipper.idle_timeout = get_float(command, params, "TIMEOUT", klipper.idle_timeout, above=0.0)
    return reply(state("idle_timeout_set", seconds=klipper.idle_timeout))


def query_endstops(printer, command: Command, now: float):
    """M119, QUERY_ENDSTOPS: homing retracts from the switches, so every one is open."""
    return reply(state("endstops"))


def display_message(printer, command: Command, now: float):
    """M117 <text>: the display's message, nothing said."""
    klipper_state(printer).display = command.string_argument or None
    return reply()


def progress(printer, command: Command, now: float):
    """M73 P<percent>: the display's progress, nothing said."""
    percent = command.value("P")
    if percent is not None:
        klipper_state(printer).progress = min(1.0, max(0.0, percent / 100.0))
    return reply()


@_refusable
def set_display_text(printer, command: Command, now: float):
    klipper_state(printer).display = extended_params(command).get("MSG")
    return reply()


def serial_print(printer, command: Command, now: float):
    """M118 <text>: `echo: <text>` ([respond]'s default prefix)."""
    return reply(state("respond_echo", text=command.string_argument))


_RESPOND_KINDS = {"echo": "respond_echo", "command": "respond_command", "error": "respond_error",
                  "echo_no_space": "respond_echo_no_space"}


@_refusable
def respond(printer, command: Command, now: float):
    """RESPOND [TYPE=echo|echo_no_space|command|error] [PREFIX=<prefix>] [MSG=<text>]."""
    params = extended_params(command)
    kind = params.get("TYPE")
    key = "respond_echo"
    if kind is not None:
        key = _RESPOND_KINDS.get(kind.lower(), "")
        if not key:
            raise _Refused(state("invalid_respond_type", type=kind.lower()))
    text = params.get("MSG", "")
    if "PREFIX" in params:
        separator = "" if key == "respond_echo_no_space" else " "
        return reply(state("respond_prefixed", prefix=params["PREFIX"] + separator,
                           text=text))
    return reply(state(key, text=text))


# -- pause_resume.py ---------------------------------------------------------------------
def _sd_active(printer) -> bool:
    return printer.sd.printing


def pause(printer, command: Command, now: float):
    klipper = klipper_state(printer)
    if klipper.paused:
        return reply(state("already_paused"))
    lines = []
    if not klipper.pause_sent:
        if _sd_active(printer):
            klipper.sd_paused = True
            printer.sd.printing = False
        else:
            klipper.sd_paused = False
            lines.append(state("action", action="paused"))
        klipper.pause_sent = True
    save_gcode_state(printer, Command("SAVE_GCODE_STATE NAME=PAUSE_STATE", "SAVE_GCODE_STATE"),
                     now)
    klipper.paused = True
    return reply(*lines)


def resume(printer, command: Command, now: float):
    klipper = klipper_state(printer)
    if not klipper.paused:
        return reply(state("not_paused"))
    try:
        velocity = get_float(command, extended_params(command), "VELOCITY", RECOVER_VELOCITY)
    except _Refused as refused:
        return reply(refused.statement)
    restore = Command(f"RESTORE_GCODE_STATE NAME=PAUSE_STATE MOVE=1 MOVE_SPEED={velocity:.4f}",
                      "RESTORE_GCODE_STATE")
    outcome = yield from restore_gcode_state(printer, restore, now)
    lines = list(outcome.lines)
    if klipper.sd_paused:
        if printer.sd.printing:
            return reply(*lines, state("sd_busy"))
        printer.sd.printing = True
        klipper.sd_paused = False
    else:
        lines.append(state("action", action="resumed"))
    klipper.pause_sent = False
    klipper.paused = False
    return reply(*lines)


def clear_pause(printer, command: Command, now: float):
    klipper = klipper_state(printer)
    klipper.paused = klipper.pause_sent = False
    return reply()


def cancel_print(printer, command: Command, now: float):
    klipper = klipper_state(printer)
    lines = []
    if _sd_active(printer) or klipper.sd_paused:
        printer.sd.printing = False  # do_cancel(): the file closed
        printer.sd.selected = None
    else:
        lines.append(state("action", action="cancel"))
    klipper.paused = klipper.pause_sent = False
    return reply(*lines)


# -- virtual_sdcard.py ---------------------------------------------------------------------
def _files(printer, subdirectories: bool = False) -> list[tuple[str, int, Path]]:
    """get_file_list(): the top level's files (not hidden, any name) sorted case-blind; with
    subdirectories, every G-code file below, by its path."""
    sd = printer.sd
    entries = sd.listing()
    if entries is None:
        raise _Refused(state("file_list_failed"))
    if subdirectories:
        found = [(relative, entry.size, entry.path) for relative, entry in sd.files_below()
                 if entry.name[entry.name.rfind(".") + 1:] in SD_EXTENSIONS]
        return sorted(found, key=lambda entry: entry[0].lower())
    return [(entry.name, entry.size, entry.path)
            for entry in sorted(entries, key=lambda entry: entry.name.lower())
            if not entry.name.startswith(".") and entry.is_file]


def _finished(printer) -> bool:
    """At the end of a file klippy closes it (current_file = None); the model keeps it
    selected, read to its end."""
    selected = printer.sd.selected
    return (selected is not None and not printer.sd.printing and len(selected.data) > 0
            and selected.position >= len(selected.data))


def _current(printer) -> OpenFile | None:
    return None if _finished(printer) else printer.sd.selected


@_refusable
def list_files(printer, command: Command, now: float):
    """M20: `<name> <size>` for each file, between the list's first and last lines."""
    files = _files(printer)
    return reply(state("file_list_begin"),
                 *(state("file_entry", short=name, size=size, long=name, stamp="")
                   for name, size, _ in files),
                 state("file_list_end"))


def card_ok(printer, command: Command, now: float):
    """M21: `SD card ok` (silently, when klippy is shut down: cmd_default's M21)."""
    return reply() if printer.halted else reply(state("sd_ok"))


def _load(printer, command: Command, name: str, subdirectories: bool = False) -> Reply:
    """_load_file(): the name as given, or the one that matches it ignoring case."""
    try:
        files = {entry[0]: entry for entry in _files(printer, subdirectories)}
    except _Refused:
        files = {}
    found = files.get(name) or next((entry for key, entry in files.items()
                                     if key.lower() == name.lower()), None)
    if found is None:
        return reply(state("open_failed", name=name))
    _, _, path = found
    data = printer.sd.read(path)
    if data is None:
        return reply(state("open_failed", name=name))
    printer.sd.selected = OpenFile(path, name, data)
    printer.sd.printing = False
    return reply(state("file_opened", name=name, size=len(data), long=name),
                 state("file_selected"))


def select_file(printer, command: Command, now: float):
    """M23 <file>: `File opened:<file> Size:<n>`, `File selected` (not while printing)."""
    if printer.sd.printing:
        return reply(state("sd_busy"))
    printer.sd.selected = None  # _reset_file()
    name = command.string_argument.strip()
    return _load(printer, command, name[1:] if name.startswith("/") else name)


def start_print(printer, command: Command, now: float):
    """M24: prints the selected file from where it is; SD busy if it is printing already."""
    if printer.sd.printing:
        return reply(state("sd_busy"))
    if _current(printer) is not None:
        printer.sd.printing = True
    return reply()


def pause_print(printer, command: Command, now: float):
    printer.sd.printing = False
    return reply()


@_refusable
def set_file_position(printer, command: Command, now: float):
    """M26 S<byte>."""
    if printer.sd.printing:
        raise _Refused(state("sd_busy"))
    position = _integer(command, "S", minval=0)  # VirtualSD.cmd_M26
    if printer.sd.selected is not None:
        printer.sd.selected.position = position
    return reply()


def report_status(printer, command: Command, now: float):
    """M27: the position whenever a file is open, printing or paused; no S auto-report."""
    selected = _current(printer)
    if selected is None:
        return reply(state("not_sd_printing"))
    return reply(state("sd_printing_byte", position=selected.position, size=len(selected.data)))


def write_unsupported(printer, command: Command, now: float):
    """M28, M29, M30: a virtual SD card is read only."""
    return reply(state("sd_write_unsupported"))


def reset_file(printer, command: Command, now: float):
    printer.sd.printing = False
    printer.sd.selected = None
    return reply()


@_refusable
def print_file(printer, command: Command, now: float):
    """SDCARD_PRINT_FILE FILENAME=<path>: select it (subdirectories too) and print it."""
    if printer.sd.printing:
        raise _Refused(state("sd_busy"))
    printer.sd.selected = None
    name = extended_params(command).get("FILENAME")
    if name is None:
        raise _Refused(state("parameter_missing", line=command.text, param="FILENAME"))
    loaded = _load(printer, command, name[1:] if name.startswith("/") else name, True)
    if printer.sd.selected is not None:
        printer.sd.printing = True
    return loaded


def _extended(handler):
    """An extended command (a word): klippy reads its `KEY=value` parameters before it runs,
    so a word without `=` is `Malformed command` whatever the command (ECHO, RESTART too)."""
    def run(printer, command: Command, now: float):
        try:
            extended_params(command)
        except _Refused as refused:
            return reply(refused.statement)
        return handler(printer, command, now)
    run.__name__ = handler.__name__
    run.__doc__ = handler.__doc__
    return run


HANDLERS: dict = {
    # gcode.py
    "M115": firmware_info,
    "STATUS": status,
    "HELP": help_list,
    "ECHO": echo,
    "RESTART": restart,
    "FIRMWARE_RESTART": restart,
    # heaters
    "M104": set_heater,
    "M105": report_temperatures,
    "M109": set_heater,
    "M140": set_heater,
    "M190": set_heater,
    "SET_HEATER_TEMPERATURE": set_heater_temperature,
    "TURN_OFF_HEATERS": turn_off_heaters,
    "TEMPERATURE_WAIT": temperature_wait,
    # gcode_move.py
    "G20": inches,
    "G21": millimetres,
    "G28": home,
    "G92": set_position,
    "M220": speed_factor,
    "M221": extrude_factor,
    "SET_GCODE_OFFSET": set_gcode_offset,
    "SAVE_GCODE_STATE": save_gcode_state,
    "RESTORE_GCODE_STATE": restore_gcode_state,
    "GET_POSITION": get_position,
    # toolhead.py and the rest of the default modules
    "G4": dwell,
    "M204": acceleration,
    "SET_VELOCITY_LIMIT": set_velocity_limit,
    "SET_IDLE_TIMEOUT": set_idle_timeout,
    "M119": query_endstops,
    "QUERY_ENDSTOPS": query_endstops,
    # display_status, respond
    "M73": progress,
    "M117": display_message,
    "SET_DISPLAY_TEXT": set_display_text,
    "M118": serial_print,
    "RESPOND": respond,
    # pause_resume
    "PAUSE": pause,
    "RESUME": resume,
    "CLEAR_PAUSE": clear_pause,
    "CANCEL_PRINT": cancel_print,
    # virtual_sdcard
    "M20": list_files,
    "M21": card_ok,
    "M23": select_file,
    "M24": start_print,
    "M25": pause_print,
    "M26": set_file_position,
    "M27": report_status,
    "M28": write_unsupported,
    "M29": write_unsupported,
    "M30": write_unsupported,
    "SDCARD_RESET_FILE": reset_file,
    "SDCARD_PRINT_FILE": print_file,
}
# The words (not G/M codes) read their parameters first, as klippy's register_command() does.
HANDLERS = {code: handler if code[1:].isdigit() else _extended(handler)
            for code, handler in HANDLERS.items()}
