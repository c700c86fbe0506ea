"""What printer-model handlers yield and return (see model.Printer.execute)."""

from collections.abc import Generator
from dataclasses import dataclass

from fake_marlin.emulator.printer.statements import Statement


@dataclass(frozen=True)
class Sleep:
    until: float


@dataclass(frozen=True)
class Report:
    """A statement made while the command waits (M109's temperatures)."""

    statement: Statement


@dataclass(frozen=True)
class Reply:
    lines: tuple[Statement, ...] = ()
    # The command's answer where the firmware may put it on its `ok` line (M105's temperatures,
    # `ok T:21.00 /0.00 ...` in Marlin's words): the firmware's profile says where it goes.
    answer: Statement | None = None
    # What the command does to the firmware itself once its `ok` is out: "restart"
    # (Klipper's FIRMWARE_RESTART, RESTART); "no_ok": there is no `ok` (Smoothieware's
    # console commands); "reset": the board resets with no `ok` (RepRapFirmware's M999);
    # "halted": it halted the printer, and still has its `ok` (RepRapFirmware's M112);
    # "ok_first": its `ok` goes before what it printed (RepRapFirmware's M28).
    effect: str | None = None

    def response_data(self) -> tuple[Statement, ...]:
        """Everything the command stated (for protocols without `ok` lines)."""
        return self.lines + ((self.answer,) if self.answer is not None else ())


def reply(*lines: Statement) -> Reply:
    return Reply(tuple(lines))


Step = Generator[Sleep | Report, float, Reply]
