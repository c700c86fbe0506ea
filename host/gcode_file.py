"""Reading a G-code job: the commands a host sends, with the line each came from."""

from collections.abc import Callable
from dataclasses import dataclass

from fake_marlin.host.errors import CommandError, UsageError
from fake_marlin.wire.gcode import strip_comment


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


def checked_job(path: str, check: Callable[[str], object]) -> list[JobCommand]:
    """Read a job and check every command can be sent, before any is."""
    job = read_job(path)
    for command in job:
        try:
            check(command.text)
        except CommandError as error:
            raise CommandError(f"{path}:{command.line_number}: {error}") from None
    return job
