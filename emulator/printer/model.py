"""The printer: its state, and a dispatch table from G-code to handlers.

execute() is a generator: it yields Sleep(until) when a command must wait for simulated time
(a full planner, a dwell, homing, heating) and Report(statement) for what it states while it
waits; the value sent back in is the new current time. It returns the Reply for the command.
Whoever drives it (a trio session, or a test) owns the clock. Handlers live in the modules
named after what they handle; each is `handler(printer, command, now) -> Reply | Step`.

The model knows no wire format and no firmware's words: what it says is Statements
(statements.py), which the firmware's profile says in its words. Which commands exist is the
profile's too: `command_sets` and `unsupported` of the config choose the handlers.
"""

from collections.abc import Generator
from dataclasses import dataclass
from pathlib import Path

from fake_marlin.emulator.printer import (
    eeprom,
    gcode,
    heating,
    host_actions,
    klipper,
    motion,
    password,
    prusa,
    reprapfirmware,
    sdcard,
    smoothieware,
    system,
)
from fake_marlin.emulator.printer.gcode import Command, PlainMove, parse
from fake_marlin.emulator.printer.motion import Limits, MotionState
from fake_marlin.emulator.printer.planner import MAX_MOVES, Planner
from fake_marlin.emulator.printer.statements import Statement, state
from fake_marlin.emulator.printer.steps import Reply, Report, Sleep, Step
from fake_marlin.emulator.printer.thermal import BED, HOTEND, Heater

__all__ = ["Printer", "PrinterConfig", "Reply", "Report", "Sleep", "Statement", "Step"]


DEFAULT_CAPABILITIES = (
    ("SERIAL_XON_XOFF", False),
    ("BINARY_FILE_TRANSFER", True),
    ("EEPROM", True),
    ("VOLUMETRIC", True),
    ("AUTOREPORT_POS", True),
    ("AUTOREPORT_TEMP", True),
    ("PROGRESS", False),
    ("PRINT_JOB", True),
    ("AUTOLEVEL", True),
    ("RUNOUT", False),
    ("Z_PROBE", True),
    ("LEVELING_DATA", True),
    ("BUILD_PERCENT", False),
    ("SOFTWARE_POWER", False),
    ("TOGGLE_LIGHTS", False),
    ("CASE_LIGHT_BRIGHTNESS", False),
    ("EMERGENCY_PARSER", True),
    ("HOST_ACTION_COMMANDS", True),
    ("PROMPT_SUPPORT", True),
    ("SDCARD", True),
    ("REPEAT", False),
    ("SD_WRITE", True),
    ("AUTOREPORT_SD_STATUS", True),
    ("LONG_FILENAME", True),
    ("LFN_WRITE", False),
    ("CUSTOM_FIRMWARE_UPLOAD", False),
    ("EXTENDED_M20", True),
    ("THERMAL_PROTECTION", True),
    ("MOTION_MODES", False),
    ("ARCS", True),
    ("BABYSTEPPING", False),
    ("CHAMBER_TEMPERATURE", False),
    ("COOLER_TEMPERATURE", False),
    ("MEATPACK", False),
    ("CONFIG_EXPORT", False),
)


@dataclass(frozen=True)
class PrinterConfig:
    extruders: int = 1
    capabilities: tuple[tuple[str, bool], ...] = DEFAULT_CAPABILITIES
    command_sets: tuple[str, ...] = ("marlin",)  # the handlers this firmware has, in order
    unsupported: frozenset[str] = frozenset()  # commands of those sets it does not know
    # PASSWORD_FEATURE (the password quirk): M510-M512, the password, locked at power-up.
    password_feature: bool = False
    password: str = ""
    locked_at_boot: bool = False
    eeprom_file: Path | None = None  # where M500 keeps the settings (None: in memory only)
    # An unknown G/M/T code gets a plain `ok`, not unknown_command (Marlin 1.0, Ultimaker 2).
    silent_unknown_codes: bool = False
    heat_wait: heating.HeatWait = heating.HeatWait()  # how M109/M190 wait (a profile's [heating])
    sd_dir: Path | None = None  # None: the printer has no SD card inserted
    machine_name: str = ""  # the identity's, for a firmware that reports it (RRF's M550)
    acceleration: float = 3000.0  # mm/s^2
    junction_speed: float = 10.0  # mm/s, what a move may enter and leave at
    max_feedrate: tuple[float, float, float, float] = (300.0, 300.0, 40.0, 45.0)  # mm/s
    steps_per_mm: tuple[float, float, float] = (80.0, 80.0, 400.0)
    homing_feedrate: tuple[float, float, float] = (50.0, 50.0, 10.0)  # mm/s
    default_feedrate: float = 1500.0  # mm/min until the first F word
    planner_moves: int = MAX_MOVES  # moves the planner holds (a profile's planner_moves)

    def capability(self, name: str) -> bool:
        return dict(self.capabilities).get(name, False)


@dataclass
class AutoReports:
    """Intervals (seconds, 0 = off) of the reports the printer sends on its own."""

    temperature: float = 0.0  # M155
    position: float = 0.0  # M154
    sd_status: float = 0.0  # M27 S


HANDLERS = {**motion.HANDLERS, **heating.HANDLERS, **sdcard.HANDLERS, **system.HANDLERS,
            **host_actions.HANDLERS, **eeprom.HANDLERS}
# A profile's command_sets name these, in order: a later set's handler replaces an earlier's.
COMMAND_SETS: dict[str, dict] = {
    "marlin": HANDLERS,
    "prusa": prusa.HANDLERS,
    "klipper": klipper.HANDLERS,
    "reprapfirmware": reprapfirmware.HANDLERS,
    "smoothieware": smoothieware.HANDLERS,
}


# What each set's handlers state beyond printer/statements.py's CATALOG (each set's STATEMENTS).
SET_STATEMENTS: dict[str, dict[str, dict[str, object]]] = {
    "marlin": {},
    "prusa": prusa.STATEMENTS,
    "klipper": klipper.STATEMENTS,
    "reprapfirmware": reprapfirmware.STATEMENTS,
    "smoothieware": smoothieware.STATEMENTS,
}


def handlers_for(config: "PrinterConfig") -> dict:
    """The dispatch table of a firmware: its command sets, later ones over earlier ones,
    without what it does not know."""
    table: dict = {}
    for name in config.command_sets:
        table.update(COMMAND_SETS[name])
    if config.password_feature:
        table.update(password.HANDLERS)
    for code in config.unsupported:
        table.pop(code, None)
    return table
# A command set's handler under this key sees every line before the handler of its code: it
# returns what the line does (a Reply or a Step), or None for the code's handler to run it
# (Smoothieware reads a line by its first character: `$` and lower case are console commands).
LINE_READER = "(line)"
# Commands that report temperatures themselves while they wait, so no `busy:` lines.
SELF_REPORTING = frozenset({"M109", "M190"})


class Printer:
    def __init__(self, config: PrinterConfig | None = None, now: float = 0.0) -> None:
        self.config = config or PrinterConfig()
        self.handlers = handlers_for(self.config)
        # A command set's own state, by its name (Prusa's EEPROM bytes, RepRapFirmware's
        # machine name): it outlives resets, as the board does; a set that forgets its state
        # at a reset keeps the boot it belongs to (`boots`) beside it.
        self.extensions: dict[str, object] = {}
        self.boots = 0
        self.eeprom = eeprom.EepromFile(self.config.eeprom_file)  # outlives resets
        self.password = self.config.password
        self.locked = False
        self._planner = Planner(self.config.planner_moves)
        self._unplanned: list[tuple[PlainMove, float]] = []  # see move_at_once()
        self.hotends = [Heater(HOTEND, now) for _ in range(self.config.extruders)]
        self.bed = Heater(BED, now)
        self.sd = sdcard.SdCard(self.config.sd_dir)
        self.reset(now)

    def reset(self, now: float) -> None:
        """A reset: motion, modes and heater targets forgotten; the heaters stay as hot as they are."""
        self.boots = getattr(self, "boots", 0) + 1
        self._unplanned.clear()  # as good as planned and cleared: motion starts afresh
        self._planner.clear()
        self._motion = MotionState(feedrate=self.config.default_feedrate)
        self.reset_settings()
        self.password = self.config.password  # as built, unless M500 stored another
        if self.config.capability("EEPROM"):
            eeprom.apply_stored(self)  # settings.first_load(): what M500 stored, if anything
        self.host_prompt = host_actions.HostPrompt()
        # A board boots unlocked, but with PASSWORD_ON_STARTUP.
        self.locked = self.config.locked_at_boot and self.config.password_feature
        self.active_tool = 0
        self.fans = [0] * max(1, self.config.extruders)
        self.auto_reports = AutoReports()
        self.heating_cancelled = False
        self.halted = False
        self.debug_flags = 0
        for heater in (*self.hotends, self.bed):
            heater.set_target(now, 0.0)
        self.sd.reset()

    def reset_settings(self) -> None:
        """The settings as the firmware was built (M502, a reset): the limits of the config."""
        self._unplanned_first()
        self._limits = Limits.from_config(self.config)

    def _unplanned_first(self) -> None:
        if getattr(self, "_unplanned", None):
            self._plan_moves()  # under the limits they came with

    # Motion, the planner and the limits are read through these: the moves that went at once
    # (move_at_once) are planned before anyone looks.
    @property
    def motion(self) -> MotionState:
        if self._unplanned:
            self._plan_moves()
        return self._motion

    @property
    def planner(self) -> Planner:
        if self._unplanned:
            self._plan_moves()
        return self._planner

    @property
    def limits(self) -> Limits:
        if self._unplanned:
            self._plan_moves()
        return self._limits

    def _plan_moves(self) -> None:
        moves, self._unplanned = self._unplanned, []
        motion.plan_plain_moves(self, moves)

    # -- the interface the sessions use ------------------------------------------------
    def room(self, now: float) -> int:
        return self.planner.room(now)

    def next_room_change(self, now: float) -> float | None:
        return self.planner.next_change(now)

    def execute(self, line: str, now: float, command: Command | None = None) -> Step:
        """Run `line` (`command` if the caller has parsed it already)."""
        if command is None:
            command = parse(line)
        if not command.text:
            return Reply()
        if self.locked and (refusal := password.refused(self, command)) is not None:
            return refusal
        reader = self.handlers.get(LINE_READER)  # a set's first look at every line
        outcome = None if reader is None else reader(self, command, now)
        if outcome is None:
            handler = self.handlers.get(command.code)
            if handler is None:
                if (self.config.silent_unknown_codes and command.code[:1] in ("G", "M", "T")
                        and command.code[1:].isdigit()):
                    return Reply()  # a G, M or T code it lacks: just `ok`
                return Reply((state("unknown_command", command=command.text,
                                    name=command.code or command.text.upper()),))
            outcome = handler(self, command, now)
        if isinstance(outcome, Generator):
            outcome = yield from outcome
        return outcome

    def move_at_once(self, move: PlainMove, now: float) -> bool:
        """G0/G1 as gcode.plain_move() read it (`G1 X10.4 Y10.0 E0.020 F6000`), when the
        planner has room for it now: what execute() does for it, which then neither waits nor
        prints, and True. False, and nothing done, when the planner is full.

        Planned later: when anything next reads motion, planner or limits, or when the moves
        not planned yet could fill the planner; each at the time it arrived, with the same
        result. A session's most common command then costs a list append on its way to the
        `ok`, and the planning is done a dozen moves at a time, with the code warm: 8 µs of CPU
        a move instead of 34 between a host's lines (a 2-CPU VM, 2,000 short moves)."""
        if self.locked:
            return False  # execute() refuses it
        # Room for certain: blocks are retired only as planning goes, in order of arrival, so
        # the planner holds at most this many moves that have not finished.
        if len(self._unplanned) + self._planner.held() >= self._planner.max_moves:
            self._plan_moves()
            if self._planner.room(now) <= 0:
                return False
        self._unplanned.append((move, now))
        return True

    def catch_up(self) -> None:
        """Plan the moves move_at_once() left for later if one more would make it plan them on
        its way. For a session to call when its answer is out and the host is busy: the batch
        is then planned now, not on the way to the next answer. (The larger the batch, the less
        its first move's cold start costs each: this makes it as large as it can be.)"""
        if self._unplanned and len(self._unplanned) + self._planner.held() >= (
                self._planner.max_moves - 1):
            self._plan_moves()

    def emergency(self, text: str, now: float) -> tuple[Statement, ...]:
        """What the emergency parser does the moment M108/M112/M410/M876 arrives."""
        command: Command = parse(text)
        if command.code == "M108":
            self.heating_cancelled = True
            host_actions.user_continues(self)
        elif command.code == "M876":
            host_actions.respond(self, gcode.whole(command.value("S", 0.0)))
        elif command.code == "M112":
            return self.kill(state("m112_shutdown"), now)
        elif command.code == "M410":
            motion.quickstop(self, now)
        return ()

    def kill(self, reason: Statement, now: float) -> tuple[Statement, ...]:
        """kill(): heaters off, motion stopped, and nothing more until a reset.

        `reason` says why (m112_shutdown, thermal_runaway...).
        """
        self.halted = True
        self.planner.clear()
        for heater in (*self.hotends, self.bed):
            heater.set_target(now, 0.0)
        lines = [reason, state("killed")]
        if self.config.capability("HOST_ACTION_COMMANDS"):
            lines.append(state("action", action="poweroff"))
        return tuple(lines)

    def realtime(self, text: str, now: float) -> tuple[Statement, ...]:
        """A character the firmware acts on the moment it arrives, wherever it is in a line
        (the line rules' `realtime`: Smoothieware's `?` and ^X): the handler its command set
        has under that character says what it says, at once (it never waits)."""
        handler = self.handlers.get(text)
        if handler is None:
            return ()
        return handler(self, Command(text, text, {}), now).response_data()

    def clear_halt(self) -> None:
        """M999 where a firmware has it (Smoothieware, Repetier): running again, heaters off
        as the halt left them, without a reset."""
        self.halted = False

    def temperature_report(self, now: float, key: str = "temperatures") -> Statement:
        return heating.temperature_report(self, now, key=key)

    def position_report(self, now: float, key: str = "position") -> Statement:
        return motion.position_report(self, now, key=key)
