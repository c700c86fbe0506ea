"""What every printer-side protocol machine is, and the events they share.

A machine is one wire format's printer side as a pure state machine (h11's shape): the host's
bytes in (`receive_data`), what happened out (`next_event`, drained after each receive), the
session's events in (`send`, which returns the bytes to write), and whatever the machine has
to say on its own (`data_to_send`). No trio, no sockets, no clock, no files.

A firmware with timers is a `TimedMachine`: time is one more input, `time_passed(now)`, and
`next_deadline()` says when the machine next wants to hear it. Whatever the machine read since
the last `time_passed` is taken to have happened at that call's `now` (a firmware reads its
clock after its serial buffer), so the session tells it the time once it has fed the bytes
and read the events, and again at each deadline; timers due by `now` fire then, their words in
`data_to_send()` and their events (if any) from `next_event()`.

The events every protocol with a command queue shares are defined here once: a command that
came (CommandReceived), a command that finished (CommandDone) and a line the firmware prints
(Output). What is particular to one wire format (a refusal and its reasons, a file packet, a
bootloader message) is defined in that machine's module.
"""

from dataclasses import dataclass
from typing import Protocol, TypeVar

EventOut = TypeVar("EventOut", covariant=True)
EventIn = TypeVar("EventIn", contravariant=True)


class ProtocolMachine(Protocol[EventOut, EventIn]):
    def receive_data(self, data: bytes) -> None:
        """Bytes from the host, as they came; read as next_event() is drained."""

    def next_event(self) -> EventOut | None:
        """What the host's bytes made happen, one event at a time; None once all are read."""

    def send(self, event: EventIn) -> bytes:
        """What the session says (a command done, a line of output...): the bytes to write,
        with anything the machine had waiting before it."""

    def data_to_send(self) -> bytes:
        """What the machine says on its own (answers to bad input, timers), to write now."""


class TimedMachine(ProtocolMachine[EventOut, EventIn], Protocol):
    def time_passed(self, now: float) -> None:
        """The clock input: it is `now`. What was read since the last call happened now;
        the timers due by now fire."""

    def next_deadline(self) -> float | None:
        """When a timer of the machine's runs out next (None: none runs)."""


# Events out, shared.
@dataclass(frozen=True, slots=True)  # slots: one is made per command, a quarter faster
class CommandReceived:
    """A command came whole and in order: the firmware queues it."""

    text: str  # the G-code, without line number, checksum or framing
    # Its line number (Marlin, Repetier: None for a line without one), or its packet's
    # sequence number (Ultimaker).
    number: int | None
    size: int = 0  # the bytes it came in, where the answer says them (g2core's footer)


# Events in, shared.
@dataclass(frozen=True, slots=True)
class CommandDone:
    """A queued command has finished: its queue slot is free, and the firmware says so in its
    words (Marlin's `ok`, Ultimaker's `o` frame, nothing at all in Repetier's, whose `ok` came
    when the command was queued)."""

    number: int | None = None  # the number it came with: Marlin's ADVANCED_OK N, Ultimaker's seq
    room: int | None = None  # the planner's free blocks now (ADVANCED_OK's P, the `o` frame's)
    response: tuple[str, ...] = ()  # its response data, where the answer carries it (Ultimaker)
    ok_suffix: str = ""  # Marlin: text on the `ok` line itself (M105's temperatures)
    quiet: bool = False  # the slot is free, but the firmware says nothing (a quirk's lost `ok`)


@dataclass(frozen=True, slots=True)
class Output:
    """A line the firmware prints (a command's output, a report, a message)."""

    text: str
