"""What every sans-IO sender shares: the caller's tickets, the backlog, and which commands keep a
printer silent for long."""

import re
from collections import deque
from dataclasses import dataclass

# Commands that keep the printer silent for long (OctoPrint's list, plus heat-and-wait).
LONG_COMMANDS = frozenset(
    {"G4", "G28", "G29", "G30", "G32", "M109", "M190", "M191", "M226", "M303", "M400", "M600"}
)
_COMMAND_WORD = re.compile(r"\s*([GMgm])0*(\d+)")


def is_long_command(text: str) -> bool:
    match = _COMMAND_WORD.match(text)
    return match is not None and f"{match[1].upper()}{match[2] or '0'}" in LONG_COMMANDS



@dataclass(eq=False)
class Ticket:
    """One submitted command, and what became of it."""

    text: str
    response: tuple[str, ...] = ()
    done: bool = False
    # False when the command completed without its own `o` (lost on the way back), so its
    # response data, if it had any, is unknown.
    confirmed: bool = False


class CommandQueue:
    """What every sender keeps for its caller: commands submitted and not yet taken on, and
    tickets completed inside poll() or an event handler, handed over by take_completed()."""

    def _open_queue(self) -> None:
        self._backlog: deque[Ticket] = deque()
        self._completed: list[Ticket] = []

    def submit(self, text: str) -> Ticket:
        ticket = Ticket(text)
        self._backlog.append(ticket)
        return ticket

    @property
    def backlog(self) -> int:
        return len(self._backlog)

    def take_completed(self) -> list[Ticket]:
        """Completed tickets, oldest first, each handed over once."""
        done, self._completed = self._completed, []
        return done
