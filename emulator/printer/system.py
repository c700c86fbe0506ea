"""System G-codes: identity (M115), messages (M117/M118), debug, halt and host prompts."""

from fake_marlin.emulator.printer import gcode
from fake_marlin.emulator.printer.gcode import Command
from fake_marlin.emulator.printer.statements import state
from fake_marlin.emulator.printer.steps import reply

DEBUG_FLAGS = ("ECHO", "INFO", "ERRORS", "DRYRUN", "COMMUNICATION", "LEVELING")


def firmware_info(printer, command: Command, now: float):
    # Its capability lines are the firmware's to say (its profile's, as --capability set them).
    return reply(state("firmware_info", extruders=printer.config.extruders))


def debug_level(printer, command: Command, now: float):
    if command.has("S"):
        printer.debug_flags = gcode.whole(command.value("S", 0.0)) & 0xFF
    names = [name for bit, name in enumerate(DEBUG_FLAGS) if printer.debug_flags & (1 << bit)]
    return reply(state("debug_flags", flags=",".join(names) if names else "OFF"))


def lcd_message(printer, command: Command, now: float):
    printer.lcd_message = command.string_argument
    return reply()


def serial_print(printer, command: Command, now: float):
    """M118 [A1] [E1] [Pn] text: A1 prefixes `//` (an action), E1 prefixes `echo:`."""
    text, action, echo = command.string_argument, False, False
    for _ in range(3):
        head = text[:2].upper()
        if head in ("A1", "E1") or (head[:1] == "P" and head[1:2].isdigit()):
            action |= head == "A1"
            echo |= head == "E1"
            text = text[2:].lstrip(" ")
    return reply(state("serial_print", text=("echo:" if echo else "") + ("//" if action else "") + text))


def halt(printer, command: Command, now: float):
    # Normally the emergency parser has killed the printer before this copy is dequeued.
    if printer.halted:
        return reply()
    return reply(*printer.kill(state("m112_shutdown"), now))


def auto_report_position(printer, command: Command, now: float):
    printer.auto_reports.position = max(0.0, min(60.0, command.value("S", 0.0)))
    return reply()


def nothing(printer, command: Command, now: float):
    """Commands whose effect lives in the protocol layer (M110, M113, M999) or in the emergency
    parser (M410, M876): the model only acknowledges them."""
    return reply()


HANDLERS = {
    "M110": nothing,
    "M111": debug_level,
    "M112": halt,
    "M113": nothing,
    "M115": firmware_info,
    "M117": lcd_message,
    "M118": serial_print,
    "M154": auto_report_position,
    "M410": nothing,
    "M876": nothing,
    "M999": nothing,
}
