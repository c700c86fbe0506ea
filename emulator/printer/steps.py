"""What printer-model handlers yield and return (see model.Printer.execute)."""

from collections.abc import Generator
from dataclasses import dataclass


@dataclass(frozen=True)
class Sleep:
    until: float


@dataclass(frozen=True)
class Report:
    text: str


@dataclass(frozen=True)
class Reply:
    lines: tuple[str, ...] = ()
    ok_suffix: str = ""  # text Marlin prints on the `ok` line itself (M105's temperatures)

    def response_data(self) -> tuple[str, ...]:
        """Everything the command printed, one line each (for protocols without `ok` lines)."""
        return self.lines + ((self.ok_suffix,) if self.ok_suffix else ())


def reply(*lines: str) -> Reply:
    return Reply(tuple(lines))


Step = Generator[Sleep | Report, float, Reply]
