"""Reading a G-code job: the commands a host sends, with the line each came from."""

from dataclasses import dataclass

from host.errors import UsageError
from wire.gcode import strip_comment


@dataclass(frozen=True)
class JobCommand:
    line_number: int
    text: str


def read_job(path: str) -> list[JobCommand]:
    """Every command of a G-code file, comments and blank lines stripped."""
    try:
        with open(path, "rb") as job:
            raw = job.read()
    except OSError as error:
        raise UsageError(f"cannot read {path}: {error.strerror}") from None
    text = raw.decode("utf-8", "replace")
    return [
        JobCommand(number, command)
        for number, line in enumerate(text.splitlines(), start=1)
        if (command := strip_comment(line))
    ]
