"""The commands of smoothieware that Marlin does not have (its profile's command set "smoothieware").

Each handler is `handler(printer, command, now) -> Reply | Step`, as in the other modules: it
states what happened (printer/statements.py); the profile says it in the firmware's words.
"""

HANDLERS: dict = {}
