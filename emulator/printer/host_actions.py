"""Marlin's host action commands and host prompts: M0/M1 (wait for the user), M600 (filament
change), M876 (the host's answer to a prompt), and what M24/M25 say to the host.

As Marlin 2.1.2.1's feature/host_actions.cpp and feature/pause.cpp do it on a board without a
display (HOST_ACTION_COMMANDS, HOST_PROMPT_SUPPORT, EMERGENCY_PARSER, ADVANCED_PAUSE_FEATURE):
a prompt is `prompt_end`, `prompt_begin <text>`, its buttons, `prompt_show`; the reason it was
opened for stays until the host answers with M876 S<n> (only that resets it), and while one is
pending the optional prompts ("Pause", "Resuming") are not shown. The waits end when the
emergency parser sees M108 or M876 (Printer.emergency): the model looks for that each
USER_POLL seconds of printer time. Which of these the firmware says at all is its
capabilities' (HOST_ACTION_COMMANDS for //action: lines, PROMPT_SUPPORT for prompts) and its
profile's words.
"""

from dataclasses import dataclass
from enum import IntEnum

from fake_marlin.emulator.printer.gcode import Command
from fake_marlin.emulator.printer.statements import Statement, state
from fake_marlin.emulator.printer.steps import Report, Sleep, reply

USER_POLL = 0.05  # s: how often a wait for the user looks whether M108/M876 came
UNLOAD_SECONDS = 100 / 10.0  # FILAMENT_CHANGE_UNLOAD_LENGTH at its feedrate
PURGE_SECONDS = 50 / 3.0  # ADVANCED_PAUSE_PURGE_LENGTH at ADVANCED_PAUSE_PURGE_FEEDRATE
PARK_SECONDS = 2.0  # retract, lift and travel to the park position


class PromptReason(IntEnum):
    """host_actions.h's PromptReason."""

    NOT_DEFINED = 0
    FILAMENT_RUNOUT = 1
    USER_CONTINUE = 2
    FILAMENT_RUNOUT_REHEAT = 3
    PAUSE_RESUME = 4
    INFO = 5


@dataclass
class HostPrompt:
    """The host-prompt state of one boot."""

    reason: PromptReason = PromptReason.NOT_DEFINED
    waiting_for_user: bool = False  # M0/M1, M600's "Nozzle Parked": M108 or M876 ends it
    purge_answer: int | None = None  # M600's "Paused" prompt: M876 S0 purges more, S1 resumes
    paused_for_user: bool = False  # what the busy line says: `paused for user`


def prompt(printer, reason: PromptReason, text: str, *buttons: str,
           only_if_none: bool = False) -> list[Statement]:
    """prompt_do(): what the firmware prints to show a prompt (nothing without PROMPT_SUPPORT,
    or, for prompt_open(), while another prompt's reason is pending)."""
    host = printer.host_prompt
    if not printer.config.capability("PROMPT_SUPPORT"):
        return []
    if only_if_none and host.reason is not PromptReason.NOT_DEFINED:
        return []
    host.reason = reason
    return [state("prompt_end"), state("prompt_begin", text=text),
            *(state("prompt_button", text=button) for button in buttons), state("prompt_show")]


def action(printer, name: str) -> list[Statement]:
    if not printer.config.capability("HOST_ACTION_COMMANDS"):
        return []
    return [state("action", action=name)]


def respond(printer, choice: int) -> None:
    """M876 S<choice>, from the emergency parser as it arrives (handle_response())."""
    host = printer.host_prompt
    reason, host.reason = host.reason, PromptReason.NOT_DEFINED
    if reason is PromptReason.USER_CONTINUE:
        host.waiting_for_user = False
    elif reason is PromptReason.FILAMENT_RUNOUT and choice in (0, 1):
        host.purge_answer = choice


def user_continues(printer) -> None:
    """M108, from the emergency parser: a wait for the user ends (not M600's purge question)."""
    printer.host_prompt.waiting_for_user = False


def _wait_for_user(printer, now: float):
    host = printer.host_prompt
    host.waiting_for_user = host.paused_for_user = True
    while host.waiting_for_user and not printer.halted:
        now = yield Sleep(now + USER_POLL)
    host.paused_for_user = False
    return now


def _say(lines: list[Statement]):
    for line in lines:
        yield Report(line)


def stop_for_user(printer, command: Command, now: float):
    """M0/M1 [S<seconds>|P<ms>] [message]: wait for the user, or for the time given."""
    if not printer.config.capability("EMERGENCY_PARSER"):
        # HAS_RESUME_CONTINUE: without a display or the emergency parser there is no M0.
        return reply(state("unknown_command", command=command.text, name=command.code))
    text = _message(command)
    timeout = command.value("S", 0.0) + command.value("P", 0.0) / 1000.0
    drained = printer.planner.drained_at(now)
    if drained > now:
        now = yield Sleep(drained)
    if text:
        yield Report(state("user_message", text=text))
    yield from _say(prompt(printer, PromptReason.USER_CONTINUE, text or f"{command.code} Stop",
                           "Continue"))
    if timeout > 0:
        host = printer.host_prompt
        host.waiting_for_user = host.paused_for_user = True
        end = now + timeout
        while host.waiting_for_user and now < end and not printer.halted:
            now = yield Sleep(min(end, now + USER_POLL))
        host.waiting_for_user = host.paused_for_user = False
    else:
        yield from _wait_for_user(printer, now)
    return reply()


def _message(command: Command) -> str:
    """M0's string: the text after its S and P numbers."""
    words = command.string_argument.split()
    while words and words[0][:1].upper() in ("S", "P") and words[0][1:].replace(".", "").isdigit():
        words.pop(0)
    return " ".join(words)


def filament_change(printer, command: Command, now: float):
    """M600, as pause_print(), wait_for_confirmation() and resume_print() run it headless."""
    if not printer.config.capability("EMERGENCY_PARSER"):
        return reply(state("unknown_command", command=command.text, name=command.code))
    host = printer.host_prompt
    drained = printer.planner.drained_at(now)
    if drained > now:
        now = yield Sleep(drained)
    yield from _say(action(printer, "paused"))
    yield from _say(prompt(printer, PromptReason.INFO, "Pause", "Dismiss", only_if_none=True))
    now = yield Sleep(now + PARK_SECONDS + UNLOAD_SECONDS)  # park and unload: busy processing
    yield Report(state("insert_filament"))
    yield from _say(prompt(printer, PromptReason.USER_CONTINUE, "Nozzle Parked", "Continue"))
    now = yield from _wait_for_user(printer, now)
    while not printer.halted:
        now = yield Sleep(now + PURGE_SECONDS)  # load and purge: busy processing
        if not printer.config.capability("PROMPT_SUPPORT"):
            break
        host.purge_answer = None
        yield from _say(prompt(printer, PromptReason.FILAMENT_RUNOUT, "Paused", "PurgeMore",
                               "Continue"))
        host.paused_for_user = True
        while host.purge_answer is None and not printer.halted:
            now = yield Sleep(now + USER_POLL)
        host.paused_for_user = False
        if host.purge_answer != 0:
            yield Report(state("prompt_end"))
            break
    yield from _say(action(printer, "resumed"))
    yield from _say(prompt(printer, PromptReason.INFO, "Resuming", "Dismiss", only_if_none=True))
    return reply()


def sd_resumed(printer) -> list[Statement]:
    """M24: the firmware tells the host (M24_M25.cpp)."""
    return [*action(printer, "resume"),
            *prompt(printer, PromptReason.INFO, "Resuming SD", "Dismiss", only_if_none=True)]


def sd_paused(printer) -> list[Statement]:
    """M25: a prompt to resume, then `//action:pause`."""
    return [*prompt(printer, PromptReason.PAUSE_RESUME, "Pause SD", "Resume", only_if_none=True),
            *action(printer, "pause")]


HANDLERS = {
    "M0": stop_for_user,
    "M1": stop_for_user,
    "M600": filament_change,
}
