"""What the printer states: what happened, in no firmware's words.

The model's handlers say what happened (a temperature report, a file opened, an unknown
command, a halt) as Statements; a firmware profile (emulator/firmware/) says each in that
firmware's words, from the templates of its profile file, or says nothing where that firmware
prints nothing. CATALOG is every statement the printer can make, with sample values: a
profile's templates are checked against it when the profile is loaded, so that a template that
names a value the statement does not have is an error in the profile, not at run time.
"""

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import NamedTuple


@dataclass(frozen=True, slots=True)
class Statement:
    """One thing the printer says: `key` names it (a key of CATALOG), `values` fill it in."""

    key: str
    values: Mapping[str, object] = field(default_factory=dict)


def state(key: str, **values: object) -> Statement:
    return Statement(key, values)


class Heat(NamedTuple):
    """One heater in a temperature report: `{active.actual:.2f}` in a template."""

    label: str  # T0.., B
    number: int  # the hotend's number (0 for the bed)
    actual: float
    target: float
    power: int  # 0..127, as Marlin's @: shows it
    pwm: int = 0  # the same power as a 0..255 duty (Smoothieware's @)


_HOTEND = Heat("T0", 0, 21.0, 0.0, 0)
_BED = Heat("B", 0, 21.0, 0.0, 0)
_TEMPERATURES: dict[str, object] = {
    "active": _HOTEND, "bed": _BED, "hotends": (_HOTEND,), "tool": 0,
}

# key -> sample values. The specials (rendered from a table of their own by the profile, not a
# single [messages] template) are marked in SPECIAL.
CATALOG: dict[str, dict[str, object]] = {
    # -- identity and boot -------------------------------------------------------------
    "greeting": {"reason": "PowerUp", "sd": True},
    "firmware_info": {"extruders": 1},
    # -- reports -----------------------------------------------------------------------
    "temperatures": _TEMPERATURES,  # M105's answer
    "auto_temperatures": _TEMPERATURES,  # M155's
    "heating": {**_TEMPERATURES, "remaining": "?", "heater": "T0"},  # M109/M190 while waiting
    "position": {"x": 0.0, "y": 0.0, "z": 0.0, "e": 0.0,
                 "count_x": 0, "count_y": 0, "count_z": 0,
                 # the same counts in mm (Marlin 1.0's `Count X: 0.00`)
                 "stepper_x": 0.0, "stepper_y": 0.0, "stepper_z": 0.0, "stepper_e": 0.0},  # M114
    "auto_position": {"x": 0.0, "y": 0.0, "z": 0.0, "e": 0.0},  # M154
    # -- commands ------------------------------------------------------------------------
    "hotend_target": {"tool": 0, "target": 200.0},  # M104/M109 S set it
    "bed_target": {"target": 60.0},  # M140/M190 S
    # `name`: the command alone, upper case (Klipper's words); given where the model finds no
    # handler (Printer.execute)
    "unknown_command": {"command": "M9999", "name": "M9999"},
    "invalid_extruder": {"code": "M104", "tool": 3},
    "invalid_tool": {"tool": 3},
    "active_extruder": {"tool": 1},
    "debug_flags": {"flags": "OFF"},
    "serial_print": {"text": "hello"},
    "keepalive_interval": {"seconds": 2.0},  # M113 without S
    "feedrate_percent": {"percent": 100.0},
    "flow_percent": {"tool": 0, "percent": 100.0},
    "arc_bad_radius": {},
    "arc_bad_center": {},
    "home_first": {"axes": "XYZ"},
    "probe_point": {"x": 20.0, "y": 20.0, "z": 0.0},
    "bed_leveling_applied": {},
    # -- halts and faults ------------------------------------------------------------------
    "m112_shutdown": {},
    # heater: Marlin's Heater_ID (0.., bed); designator: as a RepRap-style report names it (T,
    # T1.., B); delta: how far it was from its target (degrees, + above).
    "thermal_runaway": {"heater": "0", "designator": "T", "delta": 15.0},
    "mintemp": {"heater": "0", "designator": "T", "delta": 15.0},
    "maxtemp": {"heater": "0", "designator": "T", "delta": 15.0},
    "heating_failed": {"heater": "0", "designator": "T", "delta": 15.0},
    "killed": {},  # after the reason: the printer is halted
    # a command a halted printer does not run; `name`: its code alone (RepRapFirmware's words)
    "halted_refusal": {"command": "G28 X", "name": "G28"},
    "halt_cleared": {},  # M999 (Smoothieware, Repetier): running again, without a reset
    "restarting": {},  # FIRMWARE_RESTART: said as the firmware goes down
    "connected": {},  # a host opened the port and the board did not reset (Smoothieware's hello)
    "action": {"action": "poweroff"},  # a host action command (Marlin's //action:)
    # -- host prompts (M0/M1, M600, M24/M25) and notifications ---------------------------
    "prompt_end": {},
    "prompt_begin": {"text": "Nozzle Parked"},
    "prompt_button": {"text": "Continue"},
    "prompt_show": {},
    "notification": {"text": "Settings Stored"},
    "user_message": {"text": "Change the nozzle"},  # M0's message
    "insert_filament": {},  # M600, once the filament is out
    # -- a locked printer (PASSWORD_FEATURE: M510-M512) -----------------------------------
    "printer_locked": {},
    "wrong_password": {},
    "password_set": {"password": "1234"},
    "password_too_long": {},
    "password_removed": {},
    "remember_to_save": {},
    # -- EEPROM settings (M500-M504) --------------------------------------------------------
    "settings_stored": {"size": 621, "crc": 47016},
    "settings_retrieved": {"size": 621, "crc": 47016},
    "settings_defaults": {},  # M502, or a load that found nothing stored
    "eeprom_disabled": {},
    "eeprom_ok": {},
    "settings_report": {"steps": (80.0, 80.0, 400.0, 500.0), "feedrates": (300.0, 300.0, 5.0, 25.0),
                        "max_accelerations": (3000.0, 3000.0, 100.0, 10000.0),
                        "accelerations": (3000.0, 3000.0, 3000.0), "home_offset": (0.0, 0.0, 0.0),
                        "pid": (22.2, 1.08, 114.0), "retract": (3.0, 45.0, 0.0),
                        "recover": (0.0, 8.0)},
    "firmware_error": {"text": "Something went wrong"},
    # -- the SD card -----------------------------------------------------------------------
    "sd_ok": {},
    "sd_init_fail": {},
    "sd_released": {},
    "no_media": {},
    "file_list_begin": {},
    "file_list_end": {},
    "file_entry": {"short": "TEST.GCO", "size": 100, "long": "test.gcode", "stamp": "0x5B2A0000"},
    "file_entry_long": {"short": "TEST.GCO", "size": 100, "long": "test.gcode",
                        "stamp": "0x5B2A0000"},
    "file_entry_time": {"short": "TEST.GCO", "size": 100, "long": "test.gcode",
                        "stamp": "0x5B2A0000"},
    "file_entry_long_time": {"short": "TEST.GCO", "size": 100, "long": "test.gcode",
                             "stamp": "0x5B2A0000"},
    "open_failed": {"name": "X.GCO"},
    "file_opened": {"name": "TEST.GCO", "size": 100, "long": "test.gcode"},
    "file_selected": {},
    "sd_printing_byte": {"position": 0, "size": 100},
    "not_sd_printing": {},
    "done_printing_file": {},
    "current_file": {"short": "TEST.GCO", "long": "test.gcode"},
    "no_current_file": {},
    "now_fresh_file": {"name": "TEST.GCO"},
    "writing_to_file": {"name": "TEST.GCO"},
    "done_saving": {},
    "deletion_failed": {"name": "X.GCO"},
    "file_deleted": {"name": "TEST.GCO"},
    "switching_to_binary": {},
    # -- the session's own lines -----------------------------------------------------------
    "busy_processing": {},
    "busy_heating": {},
    "busy_paused_for_user": {},
    # A line said as it is given (the control channel's `say`), in every firmware.
    "verbatim": {"text": "//action:pause"},
}

SPECIAL = frozenset({"greeting", "firmware_info", "temperatures", "auto_temperatures",
                     "heating", "position", "auto_position", "verbatim"})
