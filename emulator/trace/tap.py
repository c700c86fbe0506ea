"""Where the printer server's trace looks: the journal, the planner and the heaters.

The server hands a traced run a TracedJournal in place of its journal, and looks at the
printer (PrinterSampler.look) after each read it hands the session, and at each write outside
one: the planner's room when it changed, the heaters when a sample is due. It looks from inside
what happens anyway and starts no task of its own, so that a traced run is the same run,
scheduled the same way (a scenario gives the same wire digest traced or not).
"""

import trio

from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.printer.model import Printer
from fake_marlin.emulator.trace.writer import REJECTIONS, Trace, heater_readings


class PrinterSampler:
    def __init__(self, trace: Trace, printer: Printer) -> None:
        self.trace = trace
        self.printer = printer
        # While the session reads (the commands it runs there, their answers), looking waits
        # for the read's end: once per read, not once per record.
        self.reading = False

    def look(self) -> None:
        if self.reading:
            return
        now = trio.current_time()
        self.trace.room(self.printer.room(now))
        if self.trace.heaters_due(now, self._targets()):
            self.trace.heaters(now, heater_readings(self.printer, now))

    def _targets(self) -> tuple[float, ...]:
        return (*(heater.target for heater in self.printer.hotends), self.printer.bed.target)


class TracedJournal(Journal):
    """The journal, and the trace told of each command as it is recorded."""

    def __init__(self, journal: Journal, trace: Trace, sampler: PrinterSampler) -> None:
        super().__init__(None)
        self._journal = journal
        self._trace = trace
        self._sampler = sampler

    def record(self, command: str) -> None:
        self._journal.record(command)
        self._trace.command(command)  # its answer, a write, looks at the printer

    def close(self) -> None:
        self._journal.close()


def watch_rejects(session: object, trace: Trace) -> None:
    """Tell the trace of each refusal the session's protocol machine reports (a damaged line,
    a packet out of sequence): the sessions themselves need not know that a trace exists."""
    protocol = getattr(session, "protocol", None)
    if protocol is None:
        return
    next_event = protocol.next_event

    def next_event_watched() -> object:
        event = next_event()
        if type(event) in REJECTIONS:
            trace.reject(event)
        return event

    protocol.next_event = next_event_watched
