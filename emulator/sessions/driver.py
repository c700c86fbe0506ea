"""Runs printer-model commands in trio time."""

from collections.abc import Callable

import trio

from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.printer.gcode import Command, parse
from fake_marlin.emulator.printer.model import Printer, Reply, Report, Sleep
from fake_marlin.emulator.printer.statements import Statement
from fake_marlin.wire.gcode import strip_comment


class CommandRun:
    """One command on its way through the printer model, run for as long as it needs no time:
    `advance()` runs it until it must wait (it returns until when) or it is done (None). A
    session runs most commands (a move the planner has room for, M105) straight through,
    inside the read that brought them, and only the ones that wait in a task of their own.

    It goes into the journal once it has completed. A kill (M112 through the emergency parser,
    a thermal fault) can only land while the command waits, and then it never completes.
    """

    def __init__(
        self,
        printer: Printer,
        line: str,
        journal: Journal,
        on_report: Callable[[Statement], None],
        command: Command | None = None,
        recorded: str | None = None,
    ) -> None:
        self.printer = printer
        self.line = line
        # What the journal says it ran, where the model runs it in other words (g2core's G28.2
        # is the model's G28): the host's line.
        self._recorded_line = line if recorded is None else recorded
        self.journal = journal
        self.on_report = on_report
        self.reply = Reply()
        self._halted_before = printer.halted
        self.started_at = trio.current_time()  # the model's `now` for it, however late it runs
        self._steps = printer.execute(line, self.started_at, command)
        self._started = False
        self._recorded = False

    def advance(self) -> float | None:
        """Run on until the model waits (return when it may go on) or the command is done."""
        try:
            step = next(self._steps) if not self._started else self._steps.send(
                trio.current_time()
            )
            self._started = True
            while True:
                if isinstance(step, Sleep):
                    return step.until
                if isinstance(step, Report):
                    self.on_report(step.statement)
                step = self._steps.send(trio.current_time())
        except StopIteration as finished:
            self.reply = finished.value
        if self.reply.effect != "refused":
            self.record()
        return None

    @property
    def killed(self) -> bool:
        """Halted while it waited: it never completes (and never reaches the journal)."""
        return self.printer.halted and not self._halted_before

    def abandon(self) -> None:
        self._steps.close()
        self.reply = Reply()

    def record(self) -> None:
        """Into the journal, once: when it completes, or before it runs for a command that is
        sure to complete at once (a move the planner has room for), so that its `ok`, which
        must follow the journal, can go out before the model does the work."""
        if self._recorded:
            return
        self._recorded = True
        executed = strip_comment(self._recorded_line)
        if executed and (not self.killed or parse(executed).code == "M112"):
            self.journal.record(executed)


async def finish(run: CommandRun, until: float | None) -> Reply:
    """Carry a command that waits to its end in trio time (`until`: what advance() said)."""
    while until is not None:
        await trio.sleep_until(until)
        if run.killed:
            run.abandon()
            return run.reply
        until = run.advance()
    return run.reply


async def run_command(
    printer: Printer, line: str, journal: Journal, on_report: Callable[[Statement], None]
) -> Reply:
    """Execute one command to completion, sleeping whenever the model waits for time."""
    run = CommandRun(printer, line, journal, on_report)
    return await finish(run, run.advance())


def hold_queue_full(protocol, seconds: float, nursery: trio.Nursery, resume=lambda: None) -> None:
    """The printer's command queue takes nothing for `seconds` (a queue-full fault), then the
    protocol reads on (`resume`)."""
    size = protocol.queue_size
    protocol.queue_size = 0

    async def reopen() -> None:
        await trio.sleep(seconds)
        protocol.queue_size = size
        resume()

    nursery.start_soon(reopen)
