"""Runs printer-model commands in trio time."""

from collections.abc import Callable

import trio

from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.printer.gcode import parse
from fake_marlin.emulator.printer.model import Printer, Reply, Report, Sleep
from fake_marlin.wire.gcode import strip_comment


async def run_command(
    printer: Printer, line: str, journal: Journal, on_report: Callable[[str], None]
) -> Reply:
    """Execute one command to completion, sleeping whenever the model waits for time.

    It goes into the journal once it has completed. A kill (M112 through the emergency parser,
    a thermal fault) can only land while the command waits, and then it never completes.
    """
    halted_before = printer.halted
    steps = printer.execute(line, trio.current_time())
    try:
        step = next(steps)
        while True:
            if isinstance(step, Sleep):
                await trio.sleep_until(step.until)
                if printer.halted and not halted_before:
                    steps.close()
                    return Reply()
            elif isinstance(step, Report):
                on_report(step.text)
            step = steps.send(trio.current_time())
    except StopIteration as finished:
        reply = finished.value
    executed = strip_comment(line)
    killed_while_running = printer.halted and not halted_before
    if executed and (not killed_while_running or parse(executed).code == "M112"):
        journal.record(executed)
    return reply


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
