"""The commands of Smoothieware that Marlin does not have (its profile's command set
"smoothieware").

Each handler is `handler(printer, command, now) -> Reply | Step`, as in the other modules: it
states what happened (printer/statements.py); the profile says it in the firmware's words.

Smoothieware (edge bb41e99, the 3D-printer build, not grbl mode) reads a line by its first
character (GcodeDispatch::on_console_line_received): `G M T S N` are G-code, `$` and lower case
are console commands (SimpleShell, which never says `ok`), `X Y Z F` are moves without their G
("pycam"), anything else is `ok - ignored`. line_reader() is that, for every line, before the
handler of its code (model.LINE_READER). Its M codes that differ from Marlin's are here too: the
temperatures wait for the motion queue and M109/M190 only for heating up, M114 has subcodes, the
SD card is /sd with lower-case names, M600/M601 suspend and resume, M500-M503 keep the settings
in /sd/config-override. `?` and ^X are acted on the moment they arrive (LineRules.realtime): the
status report and a halt.
"""

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

from fake_marlin.emulator.printer import heating, motion
from fake_marlin.emulator.printer.gcode import Command, parse
from fake_marlin.emulator.printer.sdcard import CardEntry, OpenFile, SdCard
from fake_marlin.emulator.printer.statements import Heat, Statement, state
from fake_marlin.emulator.printer.steps import Reply, Report, Sleep, reply

WAIT_REPORT = 1.0  # TemperatureControl::on_second_tick: the waiting heater's line each second
SUSPEND_LOOPS = 0.01  # s: Player's suspend_loops (10 passes of the main loop) before part 2
OVERRIDE = "config-override"  # THEKERNEL->config_override_filename(), on the card
_NO_OK = "no_ok"

# What these handlers state that the other sets do not, with sample values: the profiles with
# this set say each in their [messages] (printer/statements.py has the rest).
_HEAT = Heat("T0", 0, 150.3, 200.0, 127, 255)
STATEMENTS: dict[str, dict[str, object]] = {
    # GcodeDispatch: a line whose first character is no G-code letter (on its `ok` line)
    "ignored": {},
    # M109/M190 while they wait, for the waiting heater only
    "temperature_wait": {"designator": "T", "actual": 150.3, "target": 200.0, "pwm": 255},
    # resume's wait for the heaters a suspend turned off, one heater (several: `temperatures`)
    "resume_wait": {"designator": "T", "actual": 150.3, "target": 200.0, "pwm": 255},
    # M114.1 .. M114.5
    "position_detail": {"kind": "WCS", "x": 0.0, "y": 0.0, "z": 0.0, "e": 0.0},
    "position_machine": {"kind": "MCS", "x": 0.0, "y": 0.0, "z": 0.0},
    "endstops": {},  # M119
    # `?`: `feeds` and `sd` are the parts whose fields differ by state (Idle/Run, a file)
    "status_report": {"state": "Idle", "x": 0.0, "y": 0.0, "z": 0.0, "e": 0.0,
                      "feeds": "4000.0,100.0", "spindle": 0.0, "hotend": _HEAT, "bed": _HEAT,
                      "sd": ""},
    "ctrl_x_halt": {},  # ^X: the halt's reason
    "unlocked": {},  # $X while halted
    "gcode_state": {"motion": 0, "distance": 90, "feedrate": 4000.0},  # $G, $I
    "shell_unknown": {"word": "hello"},
    "shell_invalid": {},  # `$` and a letter it does not know
    "shell_not_found": {"word": "hello"},  # M1000 of a command the shell does not know
    "version": {},
    "help": {},
    "shell_echo": {"text": "hello"},
    "reboot": {},  # `reset`
    "dir_entry": {"name": "test.gcode", "size": 100},
    "dir_entry_sized": {"name": "test.gcode", "size": 100},
    "dir_entry_folder": {"name": "folder"},
    "dir_failed": {"name": "/nowhere"},
    # the SD card, beyond Marlin's words
    "print_aborted": {},
    "no_file_loaded": {},
    "not_playing": {},
    "suspended": {},
    "upload_open_failed": {"name": "test.gcode"},
    "playing": {"name": "test.gcode", "size": 100},
    "play_not_found": {"name": "test.gcode"},
    "currently_printing": {},
    "progress": {"name": "test.gcode", "percent": 0, "elapsed": "00:00:00"},
    "paused_at": {"position": 0, "size": 100},
    # Player::suspend_command / resume_command
    "suspending": {},
    "suspend_waiting": {},
    "suspend_saving": {},
    "suspend_done": {},
    "already_suspended": {},
    "not_suspended": {},
    "resuming": {},
    "resume_heating": {},
    "resume_restoring": {},
    "resume_done": {},
    # M500-M503: the settings in /sd/config-override
    "override_loading": {},
    "override_executed": {},
    "override_missing": {},
    "override_deleted": {},
    "override_present": {},
    "no_override": {},
}


@dataclass
class SmoothieState:
    """One boot's state of the Smoothieware commands."""

    boot: int
    suspended: bool = False
    was_playing: bool = False  # the suspend paused an SD print
    saved_targets: dict[str, float] = field(default_factory=dict)  # heater -> target
    sd_started: float | None = None  # when the card's print began (the `?` report's SD:)
    override: bool = False  # /sd/config-override exists (no card: kept here)
    override_text: str = ""


def smoothie_state(printer) -> SmoothieState:
    current = printer.extensions.get("smoothieware")
    if not isinstance(current, SmoothieState) or current.boot != printer.boots:
        current = SmoothieState(boot=printer.boots) if not isinstance(
            current, SmoothieState) else SmoothieState(  # the override is a file: it stays
            boot=printer.boots, override=current.override, override_text=current.override_text)
        printer.extensions["smoothieware"] = current
    return current


def _shell(*lines: Statement) -> Reply:
    """A console command's reply: what it says, and no `ok`."""
    return Reply(tuple(lines), effect=_NO_OK)


# -- the first look at every line ---------------------------------------------------------
def line_reader(printer, command: Command, now: float):
    """GcodeDispatch's and SimpleShell's reading of a line by its first character; None for a
    G-code line, which its code's handler runs."""
    text = command.text
    first = text[:1]
    if first in ("G", "M", "T", "S", "N"):
        if command.code == "M112":
            _abort_sd(printer)  # a halt aborts the card's print (Player::on_halt), silently
        return None
    if first == "$":
        return _dollar(printer, text, now)
    if first.islower():
        return _console(printer, text, now)
    if first in "XYZF":  # pycam: the last modal G0-G3 (the model's G0 is its G1)
        handler = printer.handlers.get("G1")
        return handler(printer, parse("G1 " + text), now) if handler else None
    return Reply(answer=state("ignored"))


def _abort_sd(printer) -> None:
    sd = printer.sd
    sd.printing = False
    sd.selected = None


def _dollar(printer, text: str, now: float):
    """SimpleShell's grbl commands: `$` and a letter."""
    letter = text[1:2]
    if not letter:
        return _shell(state("shell_unknown", word="$"))
    if letter == "X":
        if not printer.halted:
            return _shell()  # not halted: nothing at all, not even `ok`
        _clear(printer)
        return reply(state("unlocked"))
    if letter == "H":
        return _home_after_clear(printer, now)
    if letter in ("G", "I"):  # (the modal motion as at boot, G0: the model keeps no G0/G1 mode)
        distance = 91 if printer.motion.relative else 90
        gcode_state = state("gcode_state", motion=0, distance=distance,
                            feedrate=printer.motion.feedrate)
        return reply(gcode_state) if letter == "G" else _shell(gcode_state)
    if letter in ("S", "J", "#"):
        return _shell()  # switch, jog, the WCS list: not emulated (no words of theirs)
    return _shell(state("shell_invalid"))


def _clear(printer) -> None:
    printer.clear_halt()
    _abort_sd(printer)


def _home_after_clear(printer, now: float):
    """$H: the halt cleared, then G28 (not grbl mode), then `ok`."""
    if printer.halted:
        _clear(printer)
    home = printer.handlers.get("G28")
    if home is None:
        return reply()
    return home(printer, parse("G28"), now)


# SimpleShell::commands_table, in its order: a word runs the first whose name it starts with.
SHELL_COMMANDS = ("ls", "cd", "pwd", "cat", "echo", "rm", "mv", "mkdir", "upload", "reset", "dfu",
                  "break", "help", "?", "version", "mem", "get", "set_temp", "switch", "net",
                  "load", "save", "remount", "calc_thermistor", "thermistors", "md5sum", "test")
PLAYER_COMMANDS = ("play", "progress", "abort", "suspend", "resume")


def _console(printer, text: str, now: float):
    word, _, args = text.partition(" ")
    args = args.strip()
    if word in PLAYER_COMMANDS:
        if printer.halted:
            return _shell()  # Player ignores them while halted, without a word
        return _player(printer, word, args, now)
    if word.startswith("ok"):
        return _shell()  # an echo of its own `ok`: ignored
    lines = _run_shell(printer, word, args, now)
    if lines is None:
        return _shell(state("shell_unknown", word=word))
    return _shell(*lines)


def _run_shell(printer, word: str, args: str, now: float) -> list[Statement] | None:
    """SimpleShell::parse_command: the lines a table command says; None for no command."""
    name = next((name for name in SHELL_COMMANDS if word.lower().startswith(name)), None)
    if name is None:
        return None
    if name == "version":
        return [state("version")]
    if name in ("help", "?"):
        return [state("help")]
    if name == "echo":
        return [state("shell_echo", text=args)]
    if name == "ls":
        return _ls(printer, args)
    if name == "get" and args.split()[:1] == ["status"]:
        return [status_report(printer, now), state("verbatim", text="")]
    if name == "reset":
        return [state("reboot")]
    return []  # the others (mem, cat, net...): not emulated, they say nothing here


def _ls(printer, args: str) -> list[Statement]:
    sizes = False
    path = "/"
    words = args.split()
    while words and words[0].startswith("-"):
        sizes |= "-s" in words.pop(0)
    if words:
        path = " ".join(words)
    folder = _card_folder(printer, path)
    if folder is None:
        if path.strip("/") == "" and printer.sd.mounted:
            return [state("dir_entry_folder", name="sd")]  # the root holds the card's mount
        return [state("dir_failed", name=path if path.startswith("/") else "/" + path)]
    lines = []
    for entry in _listing(printer, folder):
        if entry.is_dir:
            lines.append(state("dir_entry_folder", name=entry.name.lower()))
        else:
            lines.append(state("dir_entry_sized" if sizes else "dir_entry", name=entry.name.lower(),
                               size=entry.size))
    return lines


def _card_folder(printer, path: str) -> Path | None:
    """A folder of the card, from `/sd/...` (or `sd/...`); None for anything else."""
    parts = [part for part in path.split("/") if part]
    if not parts or parts[0].lower() != "sd" or not printer.sd.mounted or printer.sd.root is None:
        return None
    found = _find(printer.sd, "/".join(parts[1:]))
    return found.path if found is not None and found.is_dir else None


def _listing(printer, folder: Path | None = None) -> list[CardEntry]:
    """A folder of the card (the card itself by default): not its hidden entries, by name
    without regard to case."""
    return sorted((entry for entry in printer.sd.listing(folder) or ()
                   if not entry.name.startswith(".")), key=lambda entry: entry.name.lower())


def _find(sd: SdCard, name: str) -> CardEntry | None:
    """`name` on the card as FAT finds it: each part matched without regard to case."""
    found = sd.stat(sd.root)
    for part in (part for part in name.strip().split("/") if part):
        if found is None or part in (".", ".."):
            return None
        exact = sd.stat(found.path / part)
        if exact is None:
            exact = next((entry for entry in sd.listing(found.path) or ()
                          if entry.name.lower() == part.lower()), None)
        found = exact
    return found


# -- the line rules' realtime characters --------------------------------------------------
def query(printer, command: Command, now: float):
    """`?`: Kernel::get_query_string(), at once, whatever the printer is doing."""
    return reply(status_report(printer, now))


def status_report(printer, now: float) -> Statement:
    planner = printer.planner
    running = not printer.halted and planner.drained_at(now) > now
    position = tuple(printer.motion.position)
    x, y, z, e = planner.stepper_position(now, position) if running else position
    feed, override = printer.motion.feedrate, printer.motion.feedrate_percent
    feeds = f"{feed:.1f},{feed:.1f},{override:.1f}" if running else f"{feed:.1f},{override:.1f}"
    temperatures = heating.heats(printer, now, 0)
    sd = printer.sd
    progress = ""
    if sd.selected is not None and sd.selected.position < len(sd.selected.data) or sd.printing:
        started = smoothie_state(printer).sd_started
        elapsed = 0 if started is None else int(now - started)
        size = len(sd.selected.data) if sd.selected is not None else 0
        done = sd.selected.position if sd.selected is not None else 0
        percent = round(done * 100 / size) if size else 0
        progress = f"|SD:{elapsed},{percent}"
    name = "Alarm" if printer.halted else "Run" if running else "Idle"
    return state("status_report", state=name, x=x, y=y, z=z, e=e, feeds=feeds, spindle=0.0,
                 hotend=temperatures["active"], bed=temperatures["bed"], sd=progress)


def ctrl_x(printer, command: Command, now: float):
    """^X: USBSerial::on_idle: ON_HALT, then the message to this port alone."""
    if printer.halted:
        return reply(state("ctrl_x_halt"))
    _abort_sd(printer)
    return reply(*printer.kill(state("ctrl_x_halt"), now))


# -- temperatures -------------------------------------------------------------------------
def designator(heater_index: int | None) -> str:
    """The stock config's designators: T (the first hotend), T1.., B (the bed)."""
    if heater_index is None:
        return "B"
    return "T" if heater_index == 0 else f"T{heater_index}"


def _heater(printer, command: Command, bed: bool):
    if bed:
        return printer.bed, None
    tool = printer.active_tool  # one extruder: no ToolManager, so T is ignored
    return printer.hotends[tool], tool


def set_temperature(printer, command: Command, now: float):
    """M104/M140/M109/M190 S: the motion queue empties first (wait_for_idle), then the target;
    M109/M190 wait for the heater to reach it (heating up only), reporting each second."""
    if not command.has("S"):
        return reply()
    now = yield from motion.synchronize(printer, now)
    heater, index = _heater(printer, command, command.code in ("M140", "M190"))
    target = command.value("S", 0.0)
    heater.set_target(now, target)
    if target <= 0 or command.code in ("M104", "M140"):
        return reply()
    next_report = now + WAIT_REPORT
    while not printer.halted and not _reached(heater, now):
        if now >= next_report:
            yield Report(_waiting(printer, heater, index, now))
            next_report += WAIT_REPORT
        now = yield Sleep(min(next_report, _reach_time(heater, now)))
    return reply()


def _reached(heater, now: float) -> bool:
    return heater.temperature(now) >= heater.target - 1e-9


def _reach_time(heater, now: float) -> float:
    """When the heater, heating at full power, reaches its target (inf if it never will)."""
    current, target, spec = heater.temperature(now), heater.target, heater.spec
    if heater.broken or target >= spec.saturation:
        return math.inf
    ratio = (spec.saturation - current) / (spec.saturation - target)
    return now + spec.heat_tau * math.log(ratio) + 1e-6


def _heat(printer, index: int | None, now: float) -> Heat:
    """Hotend `index`'s (None: the bed's) part of a temperature report."""
    return cast(Heat, heating.heats(printer, now, index or 0)["bed" if index is None else "active"])


def _waiting(printer, heater, index: int | None, now: float) -> Statement:
    heat = _heat(printer, index, now)
    return state("temperature_wait", designator=designator(index), actual=heat.actual,
                 target=heat.target, pwm=heat.pwm)


# -- position -----------------------------------------------------------------------------
def report_position(printer, command: Command, now: float):
    """M114 (on its `ok` line) and its subcodes, as Robot::print_position and the extruder."""
    subcode = _subcode(command)
    if subcode == 0:
        return Reply(answer=printer.position_report(now))
    position = tuple(printer.motion.position)
    x, y, z, e = (position if subcode in (4, 5) else
                  printer.planner.stepper_position(now, position))
    kind = {1: "WCS", 2: "MCS", 3: "APOS", 4: "MP", 5: "CMP"}.get(subcode)
    if kind is None:
        return Reply(answer=state("verbatim", text=""))  # nothing printed: a bare `ok `
    if subcode in (1, 3):
        return Reply(answer=state("position_detail", kind=kind, x=x, y=y, z=z, e=e))
    return Reply(answer=state("position_machine", kind=kind, x=x, y=y, z=z))


def _subcode(command: Command) -> int:
    word = command.text.split()[0] if command.text.split() else ""
    _, dot, digits = word.partition(".")
    return int(digits) if dot and digits.isdigit() else 0


def endstops(printer, command: Command, now: float):
    return reply(state("endstops"))


# -- the SD card --------------------------------------------------------------------------
def list_files(printer, command: Command, now: float):
    """M20: /sd's own entries (not its folders'), lower case, folders with `/`."""
    lines = [state("file_list_begin")]
    if printer.sd.mounted:
        for entry in _listing(printer):
            name = entry.name.lower() + ("/" if entry.is_dir else "")
            size = entry.size if entry.is_file else 0
            lines.append(state("file_entry", short=name, size=size, long=name, stamp=""))
    lines.append(state("file_list_end"))
    return reply(*lines)


def mount(printer, command: Command, now: float):
    """M21: remount, and `SD card ok` whatever came of it."""
    printer.sd.reset()
    return reply(state("sd_ok"))


def _open(printer, name: str) -> Path | None:
    found = _find(printer.sd, name) if printer.sd.mounted else None
    return found.path if found is not None and found.is_file else None


def _opened(printer, name: str) -> OpenFile | None:
    """The file `name` of the card, read to be played (shown as `name`); None if it is not
    there or cannot be read."""
    path = _open(printer, name)
    data = None if path is None else printer.sd.read(path)
    return None if path is None or data is None else OpenFile(path, name, data)


def select_file(printer, command: Command, now: float):
    """M23 name: /sd/<name>, as the host wrote it."""
    name = command.string_argument
    sd = printer.sd
    sd.printing = False
    sd.selected = _opened(printer, name)
    if sd.selected is None:
        return reply(state("open_failed", name=name))
    return reply(state("file_opened", name=name, size=len(sd.selected.data), long=name),
                 state("file_selected"))


def start_print(printer, command: Command, now: float):
    """M24: starts or resumes the print of the file selected; only `ok`."""
    sd = printer.sd
    if sd.selected is not None and sd.selected.position < len(sd.selected.data):
        if not sd.printing and sd.selected.position == 0:
            smoothie_state(printer).sd_started = now
        sd.printing = True
    return reply()


def pause_print(printer, command: Command, now: float):
    printer.sd.printing = False
    return reply()


def rewind(printer, command: Command, now: float):
    """M26: not Marlin's position, but abort and reopen the file (S is ignored)."""
    sd = printer.sd
    selected = sd.selected
    if selected is None or not (_is_open(printer) or sd.printing):
        return reply(state("no_file_loaded"))
    aborted = _abort(printer, now)
    sd.selected = OpenFile(selected.path, selected.short, selected.data)  # reopened
    return aborted


def _abort(printer, now: float) -> Reply:
    """Player::abort_command: the print stops, the file is closed, the queue flushed and the
    position taken from where the motors are."""
    sd = printer.sd
    sd.printing = False
    sd.selected = None
    motion.quickstop(printer, now)
    return reply(state("print_aborted"))


def _is_open(printer) -> bool:
    selected = printer.sd.selected
    return selected is not None and selected.position < len(selected.data)


def report_status(printer, command: Command, now: float):
    """M27: Player::progress_command("-b")."""
    sd = printer.sd
    if _is_open(printer) or sd.printing:
        assert sd.selected is not None
        if sd.printing and not sd.selected.data:
            return reply(state("sd_printing_byte", position=0, size=0))
        return reply(state("sd_printing_byte", position=sd.selected.position,
                           size=len(sd.selected.data)))
    return reply(state("suspended" if smoothie_state(printer).suspended else "not_playing"))


def begin_write(printer, command: Command, now: float):
    """M28 name: GcodeDispatch opens /sd/<name> for the lines that follow."""
    name = command.string_argument
    sd = printer.sd
    found = _find(sd, name) if sd.mounted else None
    path = found.path if found is not None else sd.path_on_card(name) if sd.mounted else None
    if path is None or not sd.create(path):
        return reply(state("upload_open_failed", name=name))
    sd.saving = path
    return reply(state("writing_to_file", name=name))


def delete_file(printer, command: Command, now: float):
    """M30 name: deleted without a word, or `Could not delete`."""
    name = command.string_argument
    if not name:
        return reply()
    path = _open(printer, name)
    if path is None or not printer.sd.delete(path):
        return reply(state("deletion_failed", name=name))
    if printer.sd.selected is not None and printer.sd.selected.path == path:
        _abort_sd(printer)
    return reply()


def select_and_start(printer, command: Command, now: float):
    """M32 name: select and start; only `ok`."""
    name = command.string_argument
    sd = printer.sd
    sd.printing = False
    sd.selected = _opened(printer, name)
    if sd.selected is None:
        return reply(state("open_failed", name=name))
    sd.printing = True
    smoothie_state(printer).sd_started = now
    return reply()


def _player(printer, word: str, args: str, now: float):
    """The Player's console commands (no `ok`)."""
    sd = printer.sd
    if word == "play":
        name = args.split(" -")[0].strip()
        if sd.printing or smoothie_state(printer).suspended:
            return _shell(state("currently_printing"))
        card = name[4:] if name.lower().startswith("/sd/") else name
        opened = _opened(printer, card)
        shown = name if name.startswith("/") else "/" + name
        if opened is None:
            return _shell(state("play_not_found", name=shown))
        sd.selected = opened
        sd.printing = True
        smoothie_state(printer).sd_started = now
        return _shell(state("playing", name=shown, size=len(sd.selected.data)))
    if word == "progress":
        return _shell(_progress(printer, now))
    if word == "abort":
        if not _is_open(printer) and not sd.printing:
            if smoothie_state(printer).suspended:
                smoothie_state(printer).suspended = False
                return _shell(state("verbatim", text="Suspend cleared"))
            return _shell(state("not_playing"))
        return Reply(_abort(printer, now).lines, effect=_NO_OK)
    if word == "suspend":
        return _no_ok((yield from _suspend(printer, now)))
    return _no_ok((yield from _resume(printer, now)))


def _no_ok(result: Reply) -> Reply:
    return Reply(result.lines, result.answer, effect=_NO_OK)


def _progress(printer, now: float) -> Statement:
    sd = printer.sd
    if _is_open(printer) and not sd.printing:
        assert sd.selected is not None
        return state("paused_at", position=sd.selected.position, size=len(sd.selected.data))
    if not sd.printing or sd.selected is None:
        return state("suspended" if smoothie_state(printer).suspended else "not_playing")
    size = len(sd.selected.data)
    started = smoothie_state(printer).sd_started
    elapsed = 0 if started is None else int(now - started)
    percent = round(sd.selected.position * 100 / size) if size else 0
    clock = f"{elapsed // 3600:02d}:{elapsed % 3600 // 60:02d}:{elapsed % 60:02d}"
    return state("progress", name="/sd/" + sd.selected.short, percent=percent, elapsed=clock)


# -- suspend and resume (M600, M601) ------------------------------------------------------
def suspend(printer, command: Command, now: float):
    """M600: Player::suspend_command; its `ok` goes out before the queue empties (the profile's
    ok_before_run), the rest of the suspend after it."""
    return (yield from _suspend(printer, now))


def _suspend(printer, now: float):
    own = smoothie_state(printer)
    if own.suspended:
        return reply(state("already_suspended"))
    yield Report(state("suspending"))
    own.suspended = True
    sd = printer.sd
    own.was_playing = sd.printing
    if sd.printing:
        sd.printing = False
    else:
        yield Report(state("action", action="pause"))
    now = yield Sleep(now + SUSPEND_LOOPS)  # the main loop's passes: the `ok` goes out
    yield Report(state("suspend_waiting"))
    now = yield from motion.synchronize(printer, now)
    yield Report(state("suspend_saving"))
    own.saved_targets = {}
    for name, heater in _heaters(printer):  # leave_heaters_on is false in the stock config
        if heater.target > 0:
            own.saved_targets[name] = heater.target
            heater.set_target(now, 0.0)
    yield Report(state("suspend_done"))
    return reply()


def _heaters(printer):
    yield from ((designator(index), heater) for index, heater in enumerate(printer.hotends))
    yield "B", printer.bed


def resume(printer, command: Command, now: float):
    """M601: Player::resume_command."""
    return (yield from _resume(printer, now))


def _resume(printer, now: float):
    own = smoothie_state(printer)
    if not own.suspended:
        return reply(state("not_suspended"))
    yield Report(state("resuming"))
    heaters = dict(_heaters(printer))
    saved = {name: heaters[name] for name in own.saved_targets if name in heaters}
    if saved:
        for name, heater in saved.items():
            heater.set_target(now, own.saved_targets[name])
        yield Report(state("resume_heating"))
        next_report = now + WAIT_REPORT
        while not printer.halted and not all(_reached(heater, now) for heater in saved.values()):
            if now >= next_report:
                yield Report(_resume_report(printer, saved, now))
                next_report += WAIT_REPORT
            wake = min([next_report, *(_reach_time(heater, now) for heater in saved.values()
                                       if not _reached(heater, now))])
            now = yield Sleep(wake)
    own.saved_targets = {}
    yield Report(state("resume_restoring"))
    yield Report(state("resume_done"))
    own.suspended = False
    if own.was_playing:
        own.was_playing = False
        printer.sd.printing = True
        return reply()
    return reply(state("action", action="resume"))


def _resume_report(printer, saved: dict, now: float) -> Statement:
    """Each saved heater's `T:.. /.. @n `, on one line: M105's words when both are."""
    temperatures = heating.heats(printer, now, 0)
    if len(saved) == 2 and "B" in saved and len(printer.hotends) == 1:
        return Statement("temperatures", temperatures)
    name = next(iter(saved))
    heat = _heat(printer, None if name == "B" else int(name[1:] or 0), now)
    return state("resume_wait", designator=name, actual=heat.actual, target=heat.target,
                 pwm=heat.pwm)


# -- settings (M500-M503) -----------------------------------------------------------------
def _override_file(printer) -> Path | None:
    sd = printer.sd
    return sd.root / OVERRIDE if sd.mounted and sd.root is not None else None


def _override_exists(printer) -> bool:
    path = _override_file(printer)
    return printer.sd.stat(path) is not None if path is not None else smoothie_state(
        printer).override


def _override_text(printer) -> str:
    """What M500 writes: Robot's settings, as M503 prints them (the model's limits)."""
    limits = printer.limits
    steps = "".join(f"{axis}{value:.5f} " for axis, value in zip("XYZ", limits.steps_per_mm))
    return (f"; DO NOT EDIT THIS FILE\n;Steps per unit:\nM92 {steps}\n"
            f";Acceleration mm/sec^2:\nM204 S{limits.acceleration:.5f} \n")


def store_settings(printer, command: Command, now: float):
    """M500: the settings written to /sd/config-override (the queue empty first)."""
    now = yield from motion.synchronize(printer, now)
    path = _override_file(printer)
    own = smoothie_state(printer)
    own.override_text = _override_text(printer)
    if path is not None:  # FileStream fails quietly: it says it stored them all the same
        printer.sd.create(path, own.override_text.encode("ascii"))
    own.override = True
    return reply(state("settings_stored", size=0, crc=0))


def load_settings(printer, command: Command, now: float):
    """M501: SimpleShell::load_command: each line of the override file said and run."""
    if not _override_exists(printer):
        return reply(state("override_missing"))
    path = _override_file(printer)
    if path is None:
        text = smoothie_state(printer).override_text
    elif (data := printer.sd.read(path)) is not None:
        text = data.decode("ascii", "replace")
    else:
        return reply(state("override_missing"))
    lines = [state("override_loading")]
    for line in text.splitlines():
        lines.append(state("verbatim", text="  " + line))  # the file's own line, as it is
        setting = parse(line)
        handler = printer.handlers.get(setting.code) if setting.code in ("M92", "M204") else None
        if handler is not None:
            handler(printer, setting, now)
    lines.append(state("override_executed"))
    return reply(*lines)


def delete_settings(printer, command: Command, now: float):
    """M502: the override file deleted (the settings stay until a reboot)."""
    path = _override_file(printer)
    if path is not None:
        printer.sd.delete(path)
    smoothie_state(printer).override = False
    return reply(state("override_deleted"))


def show_settings(printer, command: Command, now: float):
    """M503: whether there is an override, the live settings, then an empty line."""
    present = state("override_present" if _override_exists(printer) else "no_override")
    limits = printer.limits
    return reply(present, state("settings_report", steps=tuple(limits.steps_per_mm),
                                feedrates=tuple(limits.max_feedrate),
                                max_accelerations=tuple(limits.max_acceleration),
                                accelerations=(limits.acceleration, limits.retract_acceleration,
                                               limits.travel_acceleration),
                                home_offset=tuple(limits.home_offset), pid=tuple(limits.pid),
                                retract=(0.0, 0.0, 0.0), recover=(0.0, 0.0)),
                 state("verbatim", text=""))


# -- M1000 --------------------------------------------------------------------------------
def shell_command(printer, command: Command, now: float):
    """M1000 <command>: the console command, lower case, and then `ok`."""
    words = command.text.split(None, 1)
    text = words[1].strip().lower() if len(words) > 1 else "help"
    word, _, args = text.partition(" ")
    lines = _run_shell(printer, word, args.strip(), now)
    if lines is None:
        return reply(state("shell_not_found", word=word))
    return reply(*lines)


HANDLERS: dict = {
    "(line)": line_reader,  # model.LINE_READER
    "?": query,
    "\x18": ctrl_x,
    "M104": set_temperature,
    "M109": set_temperature,
    "M140": set_temperature,
    "M190": set_temperature,
    "M114": report_position,
    "M119": endstops,
    "M20": list_files,
    "M21": mount,
    "M23": select_file,
    "M24": start_print,
    "M25": pause_print,
    "M26": rewind,
    "M27": report_status,
    "M28": begin_write,
    "M30": delete_file,
    "M32": select_and_start,
    "M500": store_settings,
    "M501": load_settings,
    "M502": delete_settings,
    "M503": show_settings,
    "M600": suspend,
    "M601": resume,
    "M1000": shell_command,
}
