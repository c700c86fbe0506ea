"""The commands of prusa that Marlin does not have (its profile's command set "prusa").

Each handler is `handler(printer, command, now) -> Reply | Step`, as in the other modules: it
states what happened (printer/statements.py); the profile says it in the firmware's words.

Prusa-Firmware 3.14.1 on an MK3S (Einsy, 8-bit): Firmware/Marlin_main.cpp, Dcodes.cpp,
cardreader.cpp, ultralcd.cpp and eeprom.h of prusa3d/Prusa-Firmware (docs/firmwares.md). What
the board keeps across resets, its 4 KiB EEPROM (D3 reads and writes it: PrusaLink's job id,
the sheets, the statistics), is Printer.extensions["prusa"]; what one boot knows (M73's
progress, M72's state, the pause, the mesh, the print timer) starts afresh at each reset.
"""

import math
import re
import struct
from dataclasses import dataclass, field

from fake_marlin.emulator.printer import gcode, motion
from fake_marlin.emulator.printer.failures import HEATER_FAULT, thermal_error
from fake_marlin.emulator.printer.gcode import Command, parse
from fake_marlin.emulator.printer.heating import WATCH_TEMP_INCREASE, WATCH_TEMP_PERIOD
from fake_marlin.emulator.printer.sdcard import OpenFile, fat_stamp
from fake_marlin.emulator.printer.statements import Statement, state
from fake_marlin.emulator.printer.steps import Reply, Report, Sleep, reply

# -- the board ---------------------------------------------------------------------------------
EEPROM_SIZE = 0x1000  # EEPROM_TOP (eeprom.h)
# eeprom.h's addresses that this model reads or writes itself.
EEPROM_FIRMWARE_VERSION = 0x000A  # major, minor, revision: uint16 each
EEPROM_CUSTOM_MENDEL_NAME = 0x0C80  # char[17], M115's MACHINE_TYPE
EEPROM_JOB_ID = 0x0D05  # uint32, written by the host (PrusaLink: D3 Ax0D05 X%08x)
EEPROM_PRUSA_SN = 0x0D15  # char[20]
EEPROM_SHEETS_BASE = 0x0D49  # 8 x (name[7], int16 z_offset, uint8 bed, uint8 pinda), active
EEPROM_ACTIVE_SHEET = EEPROM_SHEETS_BASE + 88
EEPROM_CHECK_GCODE = 0x0DA2  # the M862 check modes: gcode, version, model, nozzle (at 0x0DA8)
EEPROM_NOZZLE_DIAMETER_UM = 0x0DA5  # uint16
EEPROM_NOZZLE_DIAMETER = 0x0DA7  # uint8 (40: 0.40 mm)
EEPROM_CHECK_MODE = 0x0DA8
EEPROM_UVLO = 0x0FA5  # a power panic pending: 0 none
EEPROM_FLASH_AIR = 0x0FBB  # bool
EEPROM_TOTALTIME = 0x0FED  # uint32 minutes
EEPROM_FILAMENTUSED = 0x0FF1  # uint32
EEPROM_SILENT = 0x0FFF  # 0 normal, 1 silent, 2 auto

SHEET_NAMES = ("Smooth1", "Smooth2", "Textur1", "Textur2", "Satin  ", "NylonPA", "Custom1",
               "Custom2")  # eeprom_default_sheet_name()
LIVE_Z = -350  # the first sheet's calibrated Live Z, in Z microsteps (-0.875 mm at 400/mm)

PRINTER_TYPE = 302  # printers.h PRINTER_MK3S (30302 with an MMU3, which this model has not)
PRINTER_MODEL = "MK3S"
GCODE_LEVEL = 1
MESH_POINTS = 7  # MESH_NUM_X_POINTS, MESH_NUM_Y_POINTS: M420 shows the mesh 7 by 7
MBL_POINT_SECONDS = 2.5  # G80: travel and two PINDA touches per measured point (3x3)
MBL_MEASURED = 9
HOTEND_FAN_ON = 50.0  # EXTRUDER_AUTO_FAN_TEMPERATURE
HOTEND_FAN_RPM = 5000  # a Noctua NF-A4x10 at full speed
PRINT_FAN_RPM = 7000  # the 5015 blower at full speed
# Prusa's wait_for_heater(): TEMP_RESIDENCY_TIME 3 s within TEMP_WINDOW 1 °C, restarted outside
# TEMP_HYSTERESIS 5 °C; a line each second; host_keepalive() says it is busy every 2 s.
TEMP_RESIDENCY_TIME = 3.0
TEMP_WINDOW = 1.0
TEMP_HYSTERESIS = 5.0
REPORT_INTERVAL = 1.0
KEEPALIVE = 2.0  # HOST_KEEPALIVE_INTERVAL (the command waits itself, so M113 does not change it)


def default_eeprom() -> bytearray:
    """A calibrated MK3S's EEPROM after eeprom_init(): erased (0xFF) but for what the firmware
    and its first-run wizard wrote."""
    data = bytearray(b"\xff" * EEPROM_SIZE)

    def put(address: int, raw: bytes) -> None:
        data[address:address + len(raw)] = raw

    put(EEPROM_FIRMWARE_VERSION, struct.pack("<HHH", 3, 14, 1))
    put(EEPROM_CUSTOM_MENDEL_NAME, b"Prusa i3 MK3S\x00")
    put(EEPROM_JOB_ID, bytes(4))
    for index, name in enumerate(SHEET_NAMES):
        z_offset = LIVE_Z & 0xFFFF if index == 0 else 0xFFFF  # 0xFFFF: not calibrated
        temps = bytes((60, 35)) if index == 0 else b"\xff\xff"
        put(EEPROM_SHEETS_BASE + 11 * index, name.encode() + struct.pack("<H", z_offset) + temps)
    put(EEPROM_ACTIVE_SHEET, b"\x00")
    put(EEPROM_CHECK_GCODE, bytes((1, 1, 1)))  # warn (ClCheckMode::_Warn)
    put(EEPROM_NOZZLE_DIAMETER_UM, struct.pack("<H", 400))
    put(EEPROM_NOZZLE_DIAMETER, bytes((40,)))
    put(EEPROM_CHECK_MODE, b"\x01")
    put(EEPROM_UVLO, b"\x00")
    put(EEPROM_FLASH_AIR, b"\x00")
    put(EEPROM_TOTALTIME, bytes(4))
    put(EEPROM_FILAMENTUSED, bytes(4))
    put(EEPROM_SILENT, b"\x00")
    return data


@dataclass
class PrintTimer:
    """print_job_timer: M75 starts (or resumes) it, M76 pauses it, M77 stops it."""

    started: float | None = None  # running since
    elapsed: float = 0.0  # before the last pause
    paused: bool = False

    def start(self, now: float) -> None:
        if self.started is None:
            if not self.paused:
                self.elapsed = 0.0
            self.started, self.paused = now, False

    def pause(self, now: float) -> None:
        if self.started is not None:
            self.elapsed += now - self.started
            self.started, self.paused = None, True

    def stop(self, now: float) -> float:
        """Stopped; the seconds it ran."""
        self.pause(now)
        self.paused = False
        seconds, self.elapsed = self.elapsed, 0.0
        return seconds

    def duration(self, now: float) -> float:
        return self.elapsed + (now - self.started if self.started is not None else 0.0)

    @property
    def running(self) -> bool:
        return self.started is not None


@dataclass
class Boot:
    """What one boot of the firmware knows: gone at a reset."""

    # M73: percent (uint8, shown as int8), minutes remaining and to a change (uint16, int16).
    progress: dict[str, int] = field(default_factory=lambda: {
        "P": 0xFF, "R": 0xFFFF, "C": 0xFFFF, "Q": 0xFF, "S": 0xFFFF, "D": 0xFFFF})
    printer_state: int = 0  # M72: 0 NotReady after boot
    mesh: bool = False  # mbl.active: G80 made a mesh
    paused: bool = False  # did_pause_print
    saved_sd: bool = False  # the paused print was the card's (not the host's)
    stopped: bool = False  # Stopped: a thermal error; commands are dropped until a reset
    feedrate_backup: float = 100.0  # M220 B / R
    report_period: int = 0  # M155 S (the autoreport timer)
    report_mask: int = 1  # M155 C: 1 temperatures, 2 fans, 4 position
    timer: PrintTimer = field(default_factory=PrintTimer)


@dataclass
class Board:
    """Printer.extensions["prusa"]: the EEPROM, which outlives resets, and the boot's state."""

    eeprom: bytearray = field(default_factory=default_eeprom)
    boot: int = -1  # the Printer.boots `state` belongs to
    state: Boot = field(default_factory=Boot)


def board(printer) -> Board:
    current = printer.extensions.get("prusa")
    if not isinstance(current, Board):
        current = printer.extensions["prusa"] = Board()
    if current.boot != printer.boots:
        current.boot, current.state = printer.boots, Boot()
    return current


def ram(printer) -> Boot:
    return board(printer).state


# -- what these handlers state -----------------------------------------------------------------
_PROGRESS: dict[str, object] = {"percent": -1, "remaining": -1, "change": -1}
_FANS: dict[str, object] = {"hotend_rpm": 0, "print_rpm": 0, "hotend_power": 0, "print_power": 0}

# What these handlers state that the other sets do not, with sample values: the profiles with
# this set say each in their [messages] (printer/statements.py has the rest).
STATEMENTS: dict[str, dict[str, object]] = {
    "firmware_version_full": {},  # PRUSA Fir (FW_VERSION_FULL)
    "firmware_version": {},  # M115 V, M862.4 Q (FW_VERSION)
    "serial_number": {},  # PRUSA SN
    "board_revision": {},  # PRUSA Rev
    "nozzle_diameter": {"diameter": 0.4},  # M862.1 Q, PRUSA nozzle
    "printer_type": {"code": PRINTER_TYPE},  # M862.2 Q
    "printer_model": {"model": PRINTER_MODEL},  # M862.3 Q
    "gcode_level": {"level": GCODE_LEVEL},  # M862.5 Q
    "progress_normal": _PROGRESS,  # M73
    "progress_silent": _PROGRESS,
    "printer_state": {"state": 0},  # M72
    "eeprom_header": {},  # D3
    "eeprom_written": {"count": 4, "address": EEPROM_JOB_ID},
    "eeprom_dump": {"address": EEPROM_JOB_ID, "data": "00 00 00 00"},
    "lcd_status_changed": {},
    "fans": _FANS,  # M123, M155 C2
    "fan_speeds": _FANS,  # PRUSA FAN
    "heating_hotend": {"actual": 21.0, "tool": 0, "remaining": "?"},  # M109 waits
    "heating_bed": {"hotend": 21.0, "bed": 21.0},  # M190 waits
    "position_report": {"x": 0.0, "y": 0.0, "z": 0.0, "e": 0.0, "count_x": 0.0,
                        "count_y": 0.0, "count_z": 0.0, "count_e": 0.0},  # M114
    "mesh_inactive": {},  # M420, G81
    "mesh_header": {"points_x": MESH_POINTS, "points_y": MESH_POINTS},
    "mesh_row": {"row": "  0.00000  0.00000"},
    "print_saved": {},  # M27 of a paused host print
    "sd_print_paused": {},  # M27 of a paused SD print
    "sd_printing_file": {"name": "test.gcode"},  # M27: the file being printed
    "print_time": {"hours": 0, "minutes": 5},  # M27: the print timer
    "now_doing_file": {"name": "test.gco"},  # M23 with a file already open
    "dir_enter": {"path": "/DIR/", "long": "dir"},  # M20 L
    "dir_exit": {},
    "invalid_m_code": {"command": "Mfoo"},
    "unknown_word": {"command": "FOO"},  # not a G, M, T or D code
    "invalid_extruder_code": {"code": 49},  # T1 on a single extruder: '0' + 1
    "statistics": {"minutes": 0, "filament": 0},  # M78
    # ThermalStop()'s reason, as the hotend's or the bed's
    "thermal_mintemp": {}, "thermal_mintemp_bed": {}, "thermal_maxtemp": {},
    "thermal_maxtemp_bed": {}, "thermal_runaway": {}, "thermal_runaway_bed": {},
    "thermal_preheat": {}, "thermal_preheat_bed": {},
    "printer_stopped": {},  # Error:Printer stopped due to errors...
    "file_list_entry": {"path": "TEST~1.GCO", "size": 100, "stamp": "0x58a1b2c3",
                        "long": "test.gcode"},  # M20 (without L or T)
    "file_list_entry_long": {"path": "TEST~1.GCO", "size": 100, "stamp": "0x58a1b2c3",
                             "long": "test.gcode"},
    "file_list_entry_time": {"path": "TEST~1.GCO", "size": 100, "stamp": "0x58a1b2c3",
                             "long": "test.gcode"},
    "file_list_entry_long_time": {"path": "TEST~1.GCO", "size": 100, "stamp": "0x58a1b2c3",
                                  "long": "test.gcode"},
}


# -- identity and print checking ----------------------------------------------------------------
def nozzle_um(printer) -> int:
    (value,) = struct.unpack_from("<H", board(printer).eeprom, EEPROM_NOZZLE_DIAMETER_UM)
    return value


_SUBCODE = re.compile(r"M862\.(\d)")


def print_checking(printer, command: Command, now: float):
    """M862.1-M862.5 Q: the nozzle, type, model, firmware and G-code level; with P the check,
    which says nothing when it passes (a mismatch's LCD dialog is not modelled)."""
    match = _SUBCODE.match(command.text)
    sub = int(match[1]) if match else 0
    text = command.text
    if "P" in text or "Q" not in text:
        return reply()
    if sub == 1:
        return reply(state("nozzle_diameter", diameter=nozzle_um(printer) / 1000.0))
    if sub == 2:
        return reply(state("printer_type", code=PRINTER_TYPE))
    if sub == 3:
        return reply(state("printer_model", model=PRINTER_MODEL))
    if sub == 4:
        return reply(state("firmware_version"))
    if sub == 5:
        return reply(state("gcode_level", level=GCODE_LEVEL))
    return reply()


def firmware_info(printer, command: Command, now: float):
    """M115: V the version, U<version> the upgrade check (LCD only), else the report."""
    text = command.text
    if "V" in text:
        return reply(state("firmware_version"))
    if "U" in text:
        return reply()
    return reply(state("firmware_info", extruders=printer.config.extruders))


def prusa_word(printer, command: Command, now: float):
    """`PRUSA <word>`: matched as the firmware does, by a substring of the whole command, in
    its order (Marlin_main.cpp)."""
    text = command.text
    for word in ("FANPINTST", "FAN", "uvlo", "MMURES", "RESET", "SN", "Fir", "Rev", "Lang",
                 "Lz", "FR", "MBL", "nozzle"):
        if word in text:
            break
    else:
        return reply()
    if word == "FAN":
        return reply(state("fan_speeds", **fans(printer, now)))
    if word == "RESET":
        return _soft_reset(printer, now)
    if word == "SN":
        return reply(state("serial_number"))
    if word == "Fir":
        return reply(state("firmware_version_full"))
    if word == "Rev":
        return reply(state("board_revision"))
    if word == "Lz":  # the active sheet's Live Z to 0
        eeprom = board(printer).eeprom
        sheet = eeprom[EEPROM_ACTIVE_SHEET]
        if sheet < len(SHEET_NAMES):
            struct.pack_into("<h", eeprom, EEPROM_SHEETS_BASE + 11 * sheet + 7, 0)
        return reply()
    if word == "nozzle" and text.rstrip().endswith("nozzle"):
        return reply(state("nozzle_diameter", diameter=nozzle_um(printer) / 1000.0))
    return reply()  # FANPINTST, uvlo, MMURES, Lang, FR, MBL, nozzle D/set: nothing said


def _soft_reset(printer, now: float) -> Reply:
    """softReset(): the watchdog resets the board at once, before any `ok`. The model halts,
    and the profile's [halt] reboot_after brings the new boot (` Watchdog Reset`)."""
    printer.planner.clear()
    for heater in (*printer.hotends, printer.bed):
        heater.set_target(now, 0.0)
    printer.halted = True
    return reply()


# -- progress, state, statistics ----------------------------------------------------------------
def _int8(value: int) -> int:
    return value - 0x100 if value & 0x80 else value


def _int16(value: int) -> int:
    return value - 0x10000 if value & 0x8000 else value


# avr-libc's strtod(): a decimal number with its exponent, or INF, INFINITY, NAN.
_STRTOD = re.compile(r"\s*([-+]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|inf(?:inity)?|nan))",
                     re.IGNORECASE)
_STRTOL = re.compile(r"\s*([-+]?\d+)")


def _number(text: str, letter: str) -> float | None:
    """code_seen(letter) then code_value(): the first `letter` anywhere in the command, and
    the number after it (strtod: 0 where there is none; `1e999`, `inf` and `nan` are what
    they say: the callers that want an integer take it through _to_integer())."""
    at = text.find(letter)
    if at < 0:
        return None
    match = _STRTOD.match(text, at + 1)
    return float(match[1]) if match else 0.0


def _long(text: str, letter: str) -> int | None:
    """code_seen(letter) then code_value_long() (and code_value_uint8() and
    code_value_short(), which cut it down): strtol, the digits after the letter up to the
    first that is not one (`S1e999` is 1), 0 where there are none, LONG_MAX or LONG_MIN for a
    number too large (cmdqueue.h:85-87)."""
    at = text.find(letter)
    if at < 0:
        return None
    return _strtol(text[at + 1:], 10)


def _to_integer(value: float) -> int:
    """A float code_value() read, cast to an integer as avr-gcc does it (__fixunssfsi, the
    fraction dropped): NaN, the infinities and what 32 bits cannot hold are 0. The caller keeps
    the bits its type has."""
    if not math.isfinite(value) or abs(value) >= 2.0 ** 32:
        return 0
    return int(value)


def progress(printer, command: Command, now: float):
    """M73 [P R Q S C D]: sets what it is given, then says both modes' lines (-1: unset)."""
    values = ram(printer).progress
    text = command.text[3:]
    for letter in "PRQSCD":
        value = _number(text, letter)
        if value is None:
            continue
        if letter in "PQ":
            values[letter] = (_long(text, letter) or 0) & 0xFF  # code_value_uint8()
        elif letter in "CD":  # (NaN is not <= 0: it is cast, to 0)
            values[letter] = 0xFFFF if value <= 0 else _to_integer(value) & 0xFFFF
        else:
            values[letter] = _to_integer(value) & 0xFFFF
    return reply(
        state("progress_normal", percent=_int8(values["P"]), remaining=_int16(values["R"]),
              change=_int16(values["C"])),
        state("progress_silent", percent=_int8(values["Q"]), remaining=_int16(values["S"]),
              change=_int16(values["D"])),
    )


def printer_state(printer, command: Command, now: float):
    """M72 [S0|S1]: set NotReady / IsReady; without S, say the state."""
    boot = ram(printer)
    value = _long(command.text[3:], "S")  # code_value_uint8()
    if value is None:
        return reply(state("printer_state", state=boot.printer_state))
    if value & 0xFF in (0, 1):
        boot.printer_state = value & 0xFF
    return reply()


def print_timer(printer, command: Command, now: float):
    """M75 start, M76 pause, M77 stop (adding the print's minutes to the EEPROM's total)."""
    timer = ram(printer).timer
    if command.code == "M75":
        timer.start(now)
    elif command.code == "M76":
        timer.pause(now)
    else:
        _stop_timer(printer, now)
    return reply()


def _stop_timer(printer, now: float) -> None:
    seconds = ram(printer).timer.stop(now)
    if seconds > 0:  # save_statistics()
        eeprom = board(printer).eeprom
        (total,) = struct.unpack_from("<I", eeprom, EEPROM_TOTALTIME)
        struct.pack_into("<I", eeprom, EEPROM_TOTALTIME, (total + int(seconds // 60)) & 0xFFFFFFFF)


def statistics(printer, command: Command, now: float):
    eeprom = board(printer).eeprom
    minutes, filament = struct.unpack_from("<I", eeprom, EEPROM_TOTALTIME)[0], \
        struct.unpack_from("<I", eeprom, EEPROM_FILAMENTUSED)[0]
    return reply(state("statistics", minutes=minutes, filament=filament))


def host_present(printer, command: Command, now: float):
    """M79 [S"XY"]: the host is there (a 30 s timer for the LCD's host menu); only `ok`."""
    return reply()


def accepted(printer, command: Command, now: float):
    """Commands of the firmware whose effect the model does not keep: only `ok`."""
    return reply()


# -- D3: the EEPROM -----------------------------------------------------------------------------
_HEX_DIGITS = re.compile(r"\s*([-+]?)(?:0[xX])?([0-9a-fA-F]*)")


def _strtol(text: str, base: int) -> int:
    """strtol(text, base), base 10 or 16 (avr-libc's: LONG_MAX or LONG_MIN for a number
    too large for its 32 bits)."""
    if base == 16:
        match = _HEX_DIGITS.match(text)
        assert match is not None
        digits = match[2]
        value = int(digits, 16) if digits else 0
        value = -value if match[1] == "-" else value
    else:
        found = _STRTOL.match(text)
        value = int(found[1]) if found else 0
    return max(gcode.LONG_MIN, min(gcode.LONG_MAX, value))


def _parse_hex(text: str, limit: int) -> tuple[bytes, bool]:
    """parse_hex(): lower-case pairs, spaces between them skipped; (the bytes, whether every
    character was one it takes)."""
    data = bytearray()
    position = 0
    while position < len(text) and len(data) < limit:
        char = text[position]
        position += 1
        if char == " ":
            continue
        if char == "\n":
            break
        pair = char + text[position:position + 1]
        position += 1
        if len(pair) < 2 or any(c not in "0123456789abcdef" for c in pair):
            return bytes(data), False
        data.append(int(pair, 16))
    return bytes(data), True


def eeprom_code(printer, command: Command, now: float):
    """D3 [A<address>] [C<count>] [X<hex data>]: dcode_core() on the EEPROM. A is hex after a
    lower-case x (`Ax0d05`), else decimal; C is decimal (default: to the end); X writes up to
    16 bytes of lower-case hex, and what was written is shown."""
    eeprom = board(printer).eeprom
    text = command.text
    mask = 0xFFFFFFFF
    start, end = 0, EEPROM_SIZE
    count = mask  # daddr_t count = -1: the whole space
    if (at := text.find("A")) >= 0:
        if text[at + 1:at + 2] == "x":
            start = _strtol(text[at + 2:], 16) & mask
        else:
            start = _to_integer(_number(text, "A") or 0.0) & mask  # (int)code_value()
    if (at := text.find("C")) >= 0:
        count = _strtol(text[at + 1:], 10) & mask
    if start > end:
        start = end
    if start + count > end:  # (the firmware's overflow test is this, in 32 bits)
        count = end - start
    lines = [state("eeprom_header")]
    if (at := text.find("X")) >= 0:
        data, _ = _parse_hex(text[at + 1:], 16)
        # (A character that is not lower-case hex makes the firmware write garbage over the
        # EEPROM; the model writes the bytes before it.)
        writable = data[:max(0, EEPROM_SIZE - start)]
        eeprom[start:start + len(writable)] = writable
        count = len(data)
        lines.append(state("eeprom_written", count=count, address=start))
    for offset in range(0, count, 16):
        address = start + offset
        chunk = bytes(eeprom[a] if a < EEPROM_SIZE else 0xFF
                      for a in range(address, address + min(16, count - offset)))
        text = " ".join(f"{byte:02x}" for byte in chunk)
        lines.append(state("eeprom_dump", address=address, data=text))
    return reply(*lines)


# -- reports ------------------------------------------------------------------------------------
def fans(printer, now: float) -> dict[str, int]:
    """The hotend fan (on above 50 °C) and the print fan (M106), as M123 says them."""
    hotend_on = printer.hotends[0].temperature(now) >= HOTEND_FAN_ON
    power = printer.fans[0] if printer.fans else 0
    return {"hotend_rpm": HOTEND_FAN_RPM if hotend_on else 0,
            "hotend_power": 255 if hotend_on else 0,
            "print_rpm": round(PRINT_FAN_RPM * power / 255), "print_power": power}


def fan_report(printer, command: Command, now: float):
    return reply(state("fans", **fans(printer, now)))


def position_report(printer, now: float) -> Statement:
    """gcode_M114(): the planned position, then where the steppers are, in mm, E included."""
    position = printer.motion.position
    stepper = printer.planner.stepper_position(now, tuple(position))
    counts = {f"count_{axis}": value for axis, value in zip("xyze", stepper)}
    return state("position_report", x=position[0], y=position[1], z=position[2], e=position[3],
                 **counts)


def report_position(printer, command: Command, now: float):
    return reply(position_report(printer, now))


def auto_report(printer, command: Command, now: float):
    """M155 [S<seconds>] [C<mask>]: without C the mask is 1 (temperatures only). Bit 2, the
    position, rides the model's position report; bit 1, the fans, has no report of its own in
    the model and is not sent (docs/firmwares.md)."""
    boot = ram(printer)
    text = command.text[4:]
    if (period := _long(text, "S")) is not None:  # code_value_uint8()
        boot.report_period = period & 0xFF
    mask = _long(text, "C")
    boot.report_mask = 1 if mask is None else mask & 0xFF
    reports = printer.auto_reports
    reports.temperature = float(boot.report_period) if boot.report_mask & 1 else 0.0
    reports.position = float(boot.report_period) if boot.report_mask & 4 else 0.0
    return reply()


def speed_factor(printer, command: Command, now: float):
    """M220 [B] [S<percent>] [R]: B backs the factor up, R restores it; none says it."""
    boot, motion_state = ram(printer), printer.motion
    text = command.text[4:]
    seen = False
    if "B" in text:
        boot.feedrate_backup, seen = motion_state.feedrate_percent, True
    if (value := _long(text, "S")) is not None:  # feedmultiply = code_value_short()
        # (at least 1%: the model's planner divides by it, where the firmware would crawl)
        motion_state.feedrate_percent, seen = max(1.0, float(_int16(value & 0xFFFF))), True
    if "R" in text:
        motion_state.feedrate_percent, seen = boot.feedrate_backup, True
    if not seen:
        return reply(state("feedrate_percent", percent=motion_state.feedrate_percent))
    return reply()


def lcd_message(printer, command: Command, now: float):
    printer.lcd_message = command.string_argument
    return reply(state("lcd_status_changed"))


def dwell(printer, command: Command, now: float):
    yield Report(state("lcd_status_changed"))  # "Sleep..."
    return (yield from motion.dwell(printer, command, now))


# -- mesh bed leveling ----------------------------------------------------------------------------
def mesh_status(printer, command: Command, now: float):
    """M420 and G81: the mesh, or that there is none."""
    if not ram(printer).mesh:
        return reply(state("mesh_inactive"))
    row = "".join(f"  {0.0:.5f}" for _ in range(MESH_POINTS))
    return reply(state("mesh_header", points_x=MESH_POINTS, points_y=MESH_POINTS),
                 *(state("mesh_row", row=row) for _ in range(MESH_POINTS)))


def mesh_leveling(printer, command: Command, now: float):
    """G80: home first if need be, then PINDA measures 3 x 3 points; the bed is flat."""
    if not {"X", "Y", "Z"} <= printer.motion.homed:
        yield from motion.home(printer, parse("G28"), now)
        now = yield Sleep(now)  # (the time now, after the homing)
    now = yield from motion.synchronize(printer, now)
    yield Sleep(now + MBL_MEASURED * MBL_POINT_SECONDS)
    ram(printer).mesh = True
    return reply()


# -- heating --------------------------------------------------------------------------------------
def wait_hotend(printer, command: Command, now: float):
    """M109 [S|R]: wait_for_heater(), heating or cooling: `T:<t> E:0 W:?` each second, then
    the residency's seconds left (3 s within 1 °C)."""
    heater = printer.hotends[0]
    value = command.value("S", command.value("R"))
    if value is not None:
        heater.set_target(now, value)
    yield Report(state("lcd_status_changed"))  # "Heating"
    if heater.target > 0:
        heating = heater.temperature(now) < heater.target
        residency: float | None = None
        next_report, next_busy = now + REPORT_INTERVAL, now + KEEPALIVE
        watch_end = now + WATCH_TEMP_PERIOD["hotend"]
        watch_goal = heater.temperature(now) + WATCH_TEMP_INCREASE["hotend"]
        printer.heating_cancelled = False
        while not printer.halted and not printer.heating_cancelled and not ram(printer).stopped:
            temperature = heater.temperature(now)
            if residency is None and heating and now >= watch_end:
                if temperature < watch_goal and temperature < heater.target - TEMP_WINDOW:
                    for line in thermal_error(printer, "heating_failed", "T0", now):
                        yield Report(line)
                    return reply()
                watch_end = now + WATCH_TEMP_PERIOD["hotend"]
                watch_goal = temperature + WATCH_TEMP_INCREASE["hotend"]
            if ((residency is None and heating and temperature >= heater.target - TEMP_WINDOW)
                    or (residency is None and not heating
                        and temperature <= heater.target + TEMP_WINDOW)
                    or (residency is not None
                        and abs(temperature - heater.target) > TEMP_HYSTERESIS)):
                residency = now
            if residency is not None and now - residency >= TEMP_RESIDENCY_TIME - 1e-9:
                break
            if now >= next_report - 1e-9:
                left = ("?" if residency is None
                        else str(int(TEMP_RESIDENCY_TIME - (now - residency))))
                yield Report(state("heating_hotend", actual=temperature, tool=0, remaining=left))
                next_report = now + REPORT_INTERVAL
            if now >= next_busy - 1e-9:
                yield Report(state("busy_processing"))
                next_busy = now + KEEPALIVE
            wake = min(next_report, next_busy,
                       watch_end if heating and residency is None else math.inf)
            if residency is not None:
                wake = min(wake, residency + TEMP_RESIDENCY_TIME)
            elif heating:
                wake = min(wake, max(heater.reached_at(now), now + 0.01))
            now = yield Sleep(max(wake, now + 1e-6))
    yield Report(state("lcd_status_changed"))  # "Heating done."
    return reply()


def wait_bed(printer, command: Command, now: float):
    """M190 [S|R]: while the bed heats (or, with R, cools) `T:<t.tt> E:0 B:<b.b>` each second."""
    bed = printer.bed
    cooling_allowed = not command.has("S")
    value = command.value("S", command.value("R"))
    if value is not None:
        bed.set_target(now, value)
    yield Report(state("lcd_status_changed"))  # "Bed Heating"
    heating = bed.temperature(now) < bed.target
    next_report, next_busy = now + REPORT_INTERVAL, now + KEEPALIVE
    watch_end = now + WATCH_TEMP_PERIOD["bed"]
    watch_goal = bed.temperature(now) + WATCH_TEMP_INCREASE["bed"]
    printer.heating_cancelled = False
    while not printer.halted and not printer.heating_cancelled and not ram(printer).stopped:
        temperature = bed.temperature(now)
        if heating and temperature >= bed.target:
            break
        if not heating and (not cooling_allowed or temperature <= bed.target):
            break
        if heating and now >= watch_end:
            if temperature < watch_goal:
                for line in thermal_error(printer, "heating_failed", "B", now):
                    yield Report(line)
                return reply()
            watch_end = now + WATCH_TEMP_PERIOD["bed"]
            watch_goal = temperature + WATCH_TEMP_INCREASE["bed"]
        if now >= next_report - 1e-9:
            yield Report(state("heating_bed", hotend=printer.hotends[0].temperature(now),
                               bed=temperature))
            next_report = now + REPORT_INTERVAL
        if now >= next_busy - 1e-9:
            yield Report(state("busy_processing"))
            next_busy = now + KEEPALIVE
        wake = min(next_report, next_busy, watch_end if heating else math.inf)
        if heating:
            wake = min(wake, max(bed.reached_at(now), now + 0.01))
        elif cooling_allowed:
            wake = min(wake, now + 0.5)
        now = yield Sleep(max(wake, now + 1e-6))
    yield Report(state("lcd_status_changed"))  # "Bed done"
    return reply()


def heater_fault(printer, reason: str, heater_name: str, now: float) -> tuple[Statement, ...]:
    """ThermalStop(): a thermal error does not kill a Prusa. The heaters go off, the print
    stops (`//action:cancel`) and the firmware is Stopped: it drops every command but M112
    and M310 without an answer until it is reset (a DTR reset: a host opening the port)."""
    boot = ram(printer)
    if boot.stopped or printer.halted:
        return ()
    boot.stopped = True
    bed = heater_name.upper().startswith("B")
    for heater in (*printer.hotends, printer.bed):
        heater.set_target(now, 0.0)
    lines = [state("lcd_status_changed")]
    key = {"mintemp": "thermal_mintemp", "maxtemp": "thermal_maxtemp",
           "thermal_runaway": "thermal_runaway"}.get(reason, "thermal_preheat")
    lines.append(state(key + ("_bed" if bed else "")))
    return (*lines, *_print_stop(printer, now), state("printer_stopped"))


# -- pause, resume, stop --------------------------------------------------------------------------
def pause(printer, command: Command, now: float):
    """M601 (M25, M125): park and pause whatever prints, SD or host; S sets the park position
    without pausing. The firmware says `ok` before `//action:paused`; the model says it after."""
    boot = ram(printer)
    if _number(command.text[4:], "S") is not None:
        return reply()
    if boot.paused or boot.timer.paused:
        return reply()
    now = yield from motion.synchronize(printer, now)
    boot.saved_sd = printer.sd.printing
    printer.sd.printing = False
    boot.paused = True
    boot.timer.pause(now)
    return reply(state("action", action="paused"), state("lcd_status_changed"))


def resume(printer, command: Command, now: float):
    """M602 (and M24 on a paused print): lcd_resume_print()."""
    boot = ram(printer)
    if not (boot.paused or boot.timer.paused):
        return reply()
    boot.paused = False
    if boot.timer.paused:
        boot.timer.start(now)
    if boot.saved_sd and printer.sd.selected is not None:
        printer.sd.printing = True
    boot.saved_sd = False
    return reply(state("lcd_status_changed"), state("action", action="resumed"))


def stop(printer, command: Command, now: float):
    """M603: print_stop()."""
    return reply(*_print_stop(printer, now))


def _print_stop(printer, now: float) -> list[Statement]:
    boot = ram(printer)
    printer.planner.clear()
    lines = []
    if printer.sd.selected is not None:
        printer.sd.printing = False
        printer.sd.selected = None
    else:
        lines.append(state("action", action="cancel"))
    boot.mesh = False
    boot.printer_state = 0
    boot.paused = boot.saved_sd = False
    _stop_timer(printer, now)
    for heater in (*printer.hotends, printer.bed):
        heater.set_target(now, 0.0)
    printer.fans = [0] * len(printer.fans)
    return lines


# -- the SD card ----------------------------------------------------------------------------------
def _gcode(short_path: str) -> bool:
    """lsDive()'s filter: the 8.3 extension starts with G and its second character is no ~."""
    name = short_path.rsplit("/", 1)[-1]
    _, dot, extension = name.rpartition(".")
    return bool(dot) and extension[:1] == "G" and extension[1:2] != "~"


def _fat_stamp(mtime: float) -> str:
    """The directory entry's date and time, as lsDive() prints them (in UTC: sdcard.fat_stamp)."""
    date, clock = fat_stamp(mtime)
    value = (date << 16) | clock
    return f"{value:#x}" if value else "0"  # printf's %#lx


def list_files(printer, command: Command, now: float):
    """M20 [L] [T]: root files without a slash, a subdirectory's as /DIR/NAME.GCO; L adds the
    long name and DIR_ENTER/DIR_EXIT around each directory, T the FAT time stamp."""
    text = command.text[3:]
    with_long, with_time = "L" in text, "T" in text
    key = "file_list_entry" + ("_long" if with_long else "") + ("_time" if with_time else "")
    lines = [state("file_list_begin")]
    current: list[tuple[str, str]] = []  # the directories we are in: (8.3 name, long name)
    for short, long, path in printer.sd.entries() if printer.sd.mounted else ():
        if not _gcode(short):
            continue
        short_dirs, long_dirs = short.split("/")[:-1], long.split("/")[:-1]
        wanted = list(zip(short_dirs, long_dirs))
        common = 0
        while common < min(len(current), len(wanted)) and current[common] == wanted[common]:
            common += 1
        while len(current) > common:
            current.pop()
            if with_long:
                lines.append(state("dir_exit"))
        while len(current) < len(wanted):
            current.append(wanted[len(current)])
            if with_long:
                lines.append(state("dir_enter", path="/" + "".join(s + "/" for s, _ in current),
                                   long=current[-1][1]))
        prefix = "/" + "".join(s + "/" for s in short_dirs) if short_dirs else ""
        info = printer.sd.stat(path)
        if info is None:  # gone since the listing
            continue
        lines.append(state(key, path=prefix + short.rsplit("/", 1)[-1],
                           size=info.size, stamp=_fat_stamp(info.mtime),
                           long=long.rsplit("/", 1)[-1]))
    if with_long:
        lines.extend(state("dir_exit") for _ in current)
    lines.append(state("file_list_end"))
    return reply(*lines)


def _find(printer, name: str):
    """(8.3 path, long path, file) of a G-code file on the card, by either name."""
    wanted = name.strip().lstrip("/")
    for short, long, path in printer.sd.entries():
        if wanted in (short, long) or wanted.upper() == short:
            return short, long, path
    return None


def select_file(printer, command: Command, now: float):
    """M23 <name>: openFileReadFilteredGcode(); nothing at all without a card."""
    sd = printer.sd
    if not sd.mounted:
        return reply()
    name = command.string_argument
    lines = [state("now_doing_file" if sd.selected is not None else "now_fresh_file", name=name)]
    sd.printing = False
    sd.selected = None
    found = _find(printer, name)
    if found is None or not _gcode(found[0]):
        return reply(*lines, state("open_failed", name=name.strip().rsplit("/", 1)[-1]))
    short, long, path = found
    data = sd.read(path)
    if data is None:
        return reply(*lines, state("open_failed", name=name.strip().rsplit("/", 1)[-1]))
    sd.selected = OpenFile(path, short.rsplit("/", 1)[-1], data)
    shown = "/" + "".join(d + "/" for d in short.split("/")[:-1]) + long.rsplit("/", 1)[-1]
    return reply(*lines, state("file_opened", name=shown, size=len(sd.selected.data), long=long),
                 state("file_selected"), state("lcd_status_changed"))


def start_print(printer, command: Command, now: float):
    """M24: resume a paused print, else start the selected file (and the print timer)."""
    boot = ram(printer)
    if boot.paused or boot.timer.paused:
        return resume(printer, command, now)
    if printer.sd.selected is not None:
        printer.sd.printing = True
        boot.timer.start(now)
    return reply()


def print_status(printer, command: Command, now: float):
    """M27 [P]: paused, printing (the file, its byte and the timer's h:m), or not."""
    boot, sd = ram(printer), printer.sd
    if boot.paused or boot.timer.paused:
        return reply(state("sd_print_paused" if boot.saved_sd else "print_saved"))
    if sd.printing and sd.selected is not None:
        selected = sd.selected
        found = next(((s, lng) for s, lng, p in sd.entries() if p == selected.path), None)
        short, long = found if found else (selected.short, selected.path.name)
        name = long.rsplit("/", 1)[-1]
        if "P" in command.text[3:]:
            name = "/" + "".join(d + "/" for d in short.split("/")[:-1]) + name
        minutes = int(boot.timer.duration(now) // 60)
        return reply(state("sd_printing_file", name=name),
                     state("sd_printing_byte", position=selected.position, size=len(selected.data)),
                     state("print_time", hours=minutes // 60, minutes=minutes % 60))
    return reply(state("not_sd_printing"))


# -- tools, the user, filament --------------------------------------------------------------------
def select_tool(printer, command: Command, now: float):
    """T<n> without an MMU: `Active Extruder: 0` for T0 (the firmware has no newline after it,
    so its `ok` follows on the same line; the model's line has one), else `T<'0'+n>` and
    `Invalid extruder`."""
    tool = int(command.code[1:]) if command.code[1:].isdigit() else -1
    if tool == 0:
        return reply(state("active_extruder", tool=0))
    return reply(state("invalid_extruder_code", code=tool + ord("0")))


def wait_for_user(printer, command: Command, now: float):
    """M0/M1 [S<s>|P<ms>]: an LCD message; the wait ends with the time given, or a click on the
    knob, which no host can give (`echo:busy: paused for user` until a reset)."""
    timeout = command.value("S", 0.0) + command.value("P", 0.0) / 1000.0
    now = yield from motion.synchronize(printer, now)
    host = printer.host_prompt
    host.paused_for_user = True
    try:
        end = now + timeout if timeout > 0 else math.inf
        while now < end and not printer.halted:
            now = yield Sleep(min(end, now + 60.0))
    finally:
        host.paused_for_user = False
    return reply()


def filament_change(printer, command: Command, now: float):
    """M600: park and unload, then the LCD waits for the user to load (for ever, headless)."""
    now = yield from motion.synchronize(printer, now)
    yield Report(state("lcd_status_changed"))
    now = yield Sleep(now + 15.0)  # park and unload: busy processing
    yield Report(state("lcd_status_changed"))
    return (yield from wait_for_user(printer, parse("M0"), now))


# -- every line first -----------------------------------------------------------------------------
_KNOWN_WORDS = ("PRUSA", "CRASH_", "TMC_")


def read_line(printer, command: Command, now: float):
    """process_commands()'s first look: a Stopped firmware drops everything but M112 and M310;
    a line that is no G, M, T or D code (lower case `m105` too) is `Unknown command`, and
    `M` without a number an invalid M code."""
    text = command.text
    if ram(printer).stopped:
        if command.code in ("M112", "M310"):
            return None
        return Reply(effect="no_ok")
    if text.startswith(_KNOWN_WORDS):
        return None if text.startswith("PRUSA") else reply()
    first = text[:1]
    if first not in "GMTD" or not first:
        return reply(state("unknown_word", command=text))
    if first == "M" and not text[1:2].isdigit():
        return reply(state("invalid_m_code", command=text))
    return None


# Commands the firmware has and the model keeps nothing of (Marlin_main.cpp's cases).
_ACCEPTED = ("G21", "M46", "M86", "M119", "M205", "M214", "M300", "M302", "M310", "M350",
             "M351", "M552", "M702", "M704", "M705", "M706", "M707", "M708", "M709", "M850",
             "M860", "M861", "M900", "M907", "M908", "M910", "M911", "M912", "M913", "M914",
             "M915", "M916", "M917", "M918")

HANDLERS: dict = {
    "(line)": read_line,  # model.LINE_READER
    HEATER_FAULT: heater_fault,
    "PRUSA": prusa_word,
    "D3": eeprom_code,
    "G4": dwell,
    "G80": mesh_leveling,
    "G81": mesh_status,
    "M0": wait_for_user,
    "M1": wait_for_user,
    "M20": list_files,
    "M23": select_file,
    "M24": start_print,
    "M25": pause,
    "M27": print_status,
    "M72": printer_state,
    "M73": progress,
    "M75": print_timer,
    "M76": print_timer,
    "M77": print_timer,
    "M78": statistics,
    "M79": host_present,
    "M109": wait_hotend,
    "M114": report_position,
    "M115": firmware_info,
    "M117": lcd_message,
    "M123": fan_report,
    "M125": pause,
    "M155": auto_report,
    "M190": wait_bed,
    "M220": speed_factor,
    "M420": mesh_status,
    "M600": filament_change,
    "M601": pause,
    "M602": resume,
    "M603": stop,
    "M862": print_checking,
    **{f"T{n}": select_tool for n in range(10)},
    **{code: accepted for code in _ACCEPTED},
}
