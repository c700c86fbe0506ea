"""g2core's configuration values and reports over the printer model: what `{name:n}` reads, what
`{name:value}` sets, the status report's fields and the machine state (`stat`).

From g2core's config_app.cpp, report.cpp, canonical_machine.h and settings_default.h
(synthetos/g2 edge @ c5b1cd72, 101.03; master @ 1ff7f600, 100.26). Pure: every value is read
from the printer at a `now` the caller gives.
"""

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import IntEnum

from fake_marlin.wire import g2core
from fake_marlin.wire.g2core import NULL, JsonValue, Number, OutValue


class MachineState(IntEnum):
    """`stat` (canonical_machine.h:71-85)."""

    INITIALIZING = 0
    READY = 1
    ALARM = 2
    PROGRAM_STOP = 3
    PROGRAM_END = 4
    RUN = 5
    HOLD = 6
    PROBE = 7
    CYCLE = 8
    HOMING = 9
    JOG = 10
    INTERLOCK = 11
    SHUTDOWN = 12
    PANIC = 13


# settings_default.h:187: the status report's fields unless a host sets its own.
DEFAULT_SR = ("line", "posx", "posy", "posz", "posa", "feed", "vel", "unit", "coor", "dist",
              "admo", "frmo", "momo", "stat")
SR_MIN_INTERVAL = 100  # ms, STATUS_REPORT_MIN_MS
AXES = "xyzabc"


@dataclass
class Build:
    """What the board says it is: its banner and `sys` group."""

    fb: float = 101.03  # G2CORE_FIRMWARE_BUILD
    fv: float = 0.99  # G2CORE_FIRMWARE_VERSION
    fbs: str = "101.03"  # git describe of the build
    fbc: str = "settings_default.h"  # the settings file it was built with
    hp: str | int = "g2v9"  # 101.x: a string; 100.x: a number (3)
    hv: str | int = "k"
    id: str = "0084-d639-18c6-7bd0"


@dataclass
class Settings:
    """The communication settings: what a reset (^X) puts back (settings_default.h)."""

    ej: int = 1  # JSON mode
    jv: int = 2  # JSON verbosity: messages
    qv: int = 0  # queue reports off
    sv: int = 1  # filtered status reports
    si: int = 250  # ms between status reports
    tv: int = 1  # text verbosity
    mt: float = 2.0  # minutes before idle motors are released
    sr: tuple[str, ...] = DEFAULT_SR


@dataclass
class BoardState:
    """A boot's state besides the printer model's."""

    settings: Settings = field(default_factory=Settings)
    stat: MachineState = MachineState.READY
    line: int = 0  # the last N read (the runtime line)
    last_sr: dict[str, OutValue] = field(default_factory=dict)  # what the host was last told
    queue_in: int = 0  # qi: buffers added since the last queue report
    queue_out: int = 0  # qo: buffers removed
    spindle: int = 0  # spc
    spindle_speed: float = 0.0  # sps
    coolant: tuple[int, int] = (0, 0)  # com, cof
    motion_mode: int = 4  # momo: G80 (motion canceled) until a G0-G3


class G2coreError(Exception):
    """A request the board refuses: its status code."""

    def __init__(self, status: int, body: dict[str, OutValue] | None = None) -> None:
        super().__init__(status)
        self.status = status
        self.body = body or {}


Getter = Callable[["BoardView"], OutValue]


@dataclass
class BoardView:
    """The printer and the board's state at one moment: what a value is read from."""

    printer: object
    state: BoardState
    build: Build
    now: float
    room: int  # free planner buffers

    def position(self) -> tuple[float, ...]:
        printer = self.printer
        motion = printer.motion  # type: ignore[attr-defined]
        return tuple(printer.planner.stepper_position(  # type: ignore[attr-defined]
            self.now, tuple(motion.position)))

    def velocity(self) -> float:
        """mm/min: the planned feed while moves run, 0 idle."""
        printer = self.printer
        if printer.planner.moves(self.now) == 0:  # type: ignore[attr-defined]
            return 0.0
        return float(printer.motion.feedrate)  # type: ignore[attr-defined]


def _position(index: int) -> Getter:
    def get(view: BoardView) -> OutValue:
        position = view.position()
        return Number(position[index] if index < len(position) else 0.0, 3)
    return get


def _heater(index: int, what: str) -> Getter:
    def get(view: BoardView) -> OutValue:
        printer = view.printer
        heater = printer.bed if index == 3 else printer.hotends[0]  # type: ignore[attr-defined]
        if what == "st":
            return Number(heater.target, 1)
        if what == "t":
            return Number(heater.temperature(view.now), 2)
        if what == "at":
            return bool(heater.target > 0 and abs(heater.temperature(view.now) - heater.target) < 1)
        if what == "op":
            return Number(1.0 if heater.temperature(view.now) < heater.target else 0.0, 3)
        return 1  # he1e: enabled
    return get


def _constant(value: OutValue) -> Getter:
    return lambda view: value


# What each readable name is, in g2core's table order within each group.
READ: dict[str, Getter] = {
    "stat": lambda view: int(view.state.stat),
    "line": lambda view: view.state.line,
    "n": lambda view: view.state.line,
    "vel": lambda view: Number(view.velocity(), 2),
    "feed": lambda view: Number(view.printer.motion.feedrate, 2),  # type: ignore[attr-defined]
    "unit": _constant(1),  # G21
    "coor": _constant(1),  # G54
    "momo": lambda view: view.state.motion_mode,
    "plan": _constant(0),
    "path": _constant(2),
    "dist": lambda view: int(view.printer.motion.relative),  # type: ignore[attr-defined]
    "admo": lambda view: int(view.printer.motion.relative),  # type: ignore[attr-defined]
    "frmo": _constant(1),  # G94
    "tool": lambda view: view.printer.active_tool,  # type: ignore[attr-defined]
    "qr": lambda view: view.room,
    "spc": lambda view: view.state.spindle,
    "sps": lambda view: Number(view.state.spindle_speed, 1),
    "com": lambda view: view.state.coolant[0],
    "cof": lambda view: view.state.coolant[1],
    "fb": lambda view: Number(view.build.fb, 2),
    "fv": lambda view: Number(view.build.fv, 2),
    "fbs": lambda view: view.build.fbs,
    "fbc": lambda view: view.build.fbc,
    "hp": lambda view: view.build.hp,
    "hv": lambda view: view.build.hv,
    "id": lambda view: view.build.id,
    "jt": _constant(Number(0.75, 2)),
    "ct": _constant(Number(0.01, 4)),
    "sl": _constant(0),
    "lim": _constant(1),
    "saf": _constant(1),
    "m48": _constant(1),
    "froe": _constant(0),
    "fro": _constant(1),
    "troe": _constant(0),
    "tro": _constant(1),
    "mt": lambda view: Number(view.state.settings.mt, 2),
    "tv": lambda view: view.state.settings.tv,
    "ej": lambda view: view.state.settings.ej,
    "jv": lambda view: view.state.settings.jv,
    "qv": lambda view: view.state.settings.qv,
    "sv": lambda view: view.state.settings.sv,
    "si": lambda view: view.state.settings.si,
    "gpl": _constant(0), "gun": _constant(1), "gco": _constant(1), "gpa": _constant(2),
    "gdi": _constant(0),
}
for _index, _axis in enumerate(AXES):
    READ[f"pos{_axis}"] = _position(_index if _axis in "xyz" else 3 if _axis == "a" else 9)
    READ[f"mpo{_axis}"] = READ[f"pos{_axis}"]
    READ[f"ofs{_axis}"] = _constant(0)
    READ[f"tof{_axis}"] = _constant(0)
for _number in (1, 2, 3):
    for _what in ("e", "st", "t", "at", "op"):
        READ[f"he{_number}{_what}"] = _heater(_number, _what)

SYS_GROUP = ("fb", "fv", "fbs", "fbc", "hp", "hv", "id", "jt", "ct", "sl", "lim", "saf", "m48",
             "froe", "fro", "troe", "tro", "mt", "tv", "ej", "jv", "qv", "sv", "si", "gpl", "gun",
             "gco", "gpa", "gdi")
# {"x":n}: an axis's settings (config_app.cpp:304-316), as the default settings file has them.
AXIS_GROUP: Mapping[str, OutValue] = {
    "am": 1, "vm": 18000, "fr": 18000, "tn": 0, "tm": 300, "jm": 5000, "jh": 10000, "hi": 1,
    "hd": 0, "sv": 1000, "lv": 100, "lb": 5, "zb": 1,
}
MOTOR_GROUP: Mapping[str, OutValue] = {
    "ma": 0, "sa": Number(1.8, 3), "tr": Number(40, 4), "su": Number(40, 5), "mi": 8, "po": 0,
    "pm": 2, "pl": Number(0.375, 3),
}
GROUPS: Mapping[str, Callable[[BoardView], dict[str, OutValue]]] = {
    "sys": lambda view: {name: READ[name](view) for name in SYS_GROUP},
    **{axis: (lambda view: dict(AXIS_GROUP)) for axis in AXES},
    **{str(motor): (lambda view: dict(MOTOR_GROUP)) for motor in range(1, 7)},
    "pos": lambda view: {axis: READ[f"pos{axis}"](view) for axis in AXES},
    "mpo": lambda view: {axis: READ[f"mpo{axis}"](view) for axis in AXES},
    "pwr": lambda view: {str(motor): Number(0, 3) for motor in range(1, 7)},
}
ACTIONS = ("clear", "clr", "me", "md")  # names that do something when read or set (clear an
# alarm, enable or disable the motors: config_app.cpp:741-781)
SETTINGS_RANGES = {"ej": (0, 2), "jv": (0, 8), "qv": (0, 2), "sv": (0, 2), "si": (100, 50000),
                   "tv": (0, 1)}


def status_report(view: BoardView, fields: tuple[str, ...] | None = None) -> dict[str, OutValue]:
    return {name: READ[name](view) for name in (fields or view.state.settings.sr)}


def changed_fields(view: BoardView) -> dict[str, OutValue]:
    """A filtered report (sv 1): the fields that changed since the host was last told; `stat`
    always while it is 3 or 4 (report.cpp:375-425)."""
    now = status_report(view)
    changed = {name: value for name, value in now.items() if view.state.last_sr.get(name) != value}
    if view.state.stat in (MachineState.PROGRAM_STOP, MachineState.PROGRAM_END):
        changed.setdefault("stat", int(view.state.stat))
    return changed


def get(view: BoardView, name: str) -> OutValue:
    if name == "sr":
        return status_report(view)
    if name in GROUPS:
        return GROUPS[name](view)
    if name in READ:
        return READ[name](view)
    raise G2coreError(g2core.UNRECOGNIZED_NAME)


def set_value(view: BoardView, name: str, value: JsonValue) -> dict[str, OutValue]:
    """A SET: what the answer's body says of it (the value as now set)."""
    settings = view.state.settings
    if name == "sr":
        if not isinstance(value, dict) or not value:
            raise G2coreError(g2core.INPUT_LESS_THAN_MIN)
        unknown = [field_name for field_name in value if field_name not in READ]
        if unknown:
            echo: dict[str, OutValue] = {key: None for key in value}
            raise G2coreError(g2core.UNRECOGNIZED_NAME, {"sr": echo})
        if any(item is not True for item in value.values()):
            raise G2coreError(g2core.UNSUPPORTED_TYPE)
        settings.sr = tuple(value)
        view.state.last_sr = {}
        report = status_report(view)
        view.state.last_sr = dict(report)
        return {"sr": report}
    if name in SETTINGS_RANGES:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise G2coreError(g2core.JSON_TYPE_MISMATCH, {name: None})
        low, high = SETTINGS_RANGES[name]
        if value < low:
            raise G2coreError(g2core.INPUT_LESS_THAN_MIN, {
                name: None, "msg": f"Input less than minimum value {low}"})
        if value > high:
            raise G2coreError(g2core.INPUT_EXCEEDS_MAX, {
                name: None, "msg": f"Input more than maximum value {high}"})
        setattr(settings, name, int(value))
        return {name: int(value)}
    if name == "mt" and isinstance(value, (int, float)) and not isinstance(value, bool):
        settings.mt = float(value)
        return {name: Number(settings.mt, 2)}
    if name in ("clear", "clr"):
        if view.state.stat in (MachineState.ALARM, MachineState.SHUTDOWN):
            view.state.stat = MachineState.PROGRAM_STOP
            view.printer.clear_halt()  # type: ignore[attr-defined]
        return {name: None}
    if name in ("me", "md"):
        return {name: None}
    if len(name) == 5 and name.startswith("he") and name[3:] == "st":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise G2coreError(g2core.JSON_TYPE_MISMATCH, {name: None})
        printer = view.printer
        heater = printer.bed if name[2] == "3" else printer.hotends[0]  # type: ignore[attr-defined]
        heater.set_target(view.now, float(value))
        return {name: Number(float(value), 1)}
    if name in READ or name in GROUPS:
        raise G2coreError(g2core.READ_ONLY, {name: None})
    raise G2coreError(g2core.UNRECOGNIZED_NAME, {name: None})


def answer(view: BoardView, pairs: dict[str, JsonValue]) -> tuple[dict[str, OutValue], int]:
    """A JSON request's body and status: its GETs and SETs in order; an unknown name refuses
    the whole line, echoing what was read up to it with that one as null."""
    for index, name in enumerate(pairs):
        if name not in READ and name not in GROUPS and name not in ("sr", *ACTIONS) and not (
                name.startswith("he") and name.endswith("st")):
            echo: dict[str, OutValue] = {key: None for key in list(pairs)[:index + 1]}
            return echo, g2core.UNRECOGNIZED_NAME
    body: dict[str, OutValue] = {}
    for name, value in pairs.items():
        if value is not NULL and name not in ("clear", "clr") and view.state.stat in (
                MachineState.ALARM, MachineState.SHUTDOWN):
            body[name] = None  # alarm.cpp:106-112: a SET is refused; GETs still work
            return body, g2core.ALARMED
        try:
            if value is NULL and name not in ACTIONS:
                body[name] = get(view, name)
            else:
                body.update(set_value(view, name, value))
        except G2coreError as refused:
            body.update(refused.body or {name: None})
            return body, refused.status
    return body, g2core.OK
