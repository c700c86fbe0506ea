"""The commands of reprapfirmware that Marlin does not have (its profile's command set "reprapfirmware").

Each handler is `handler(printer, command, now) -> Reply | Step`, as in the other modules: it
states what happened (printer/statements.py); the profile says it in the firmware's words.
"""

# What these handlers state that the other sets do not, with sample values: the profiles with
# this set say each in their [messages] (printer/statements.py has the rest).
STATEMENTS: dict[str, dict[str, object]] = {}

HANDLERS: dict = {}
