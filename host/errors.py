"""Errors split by whose fault they are: the printer/link (remote) or the caller (usage)."""


class HostError(Exception):
    """Anything the host client reports to its user."""


class RemoteError(HostError):
    """The printer or the link misbehaved."""


class PortError(RemoteError):
    """The serial port could not be opened."""


class ConnectionLost(RemoteError):
    """The port went away while in use."""


class PrinterNotResponding(RemoteError):
    """A packet went unanswered through every retry."""


class PrinterReset(RemoteError):
    """The printer restarted mid-session; what it had queued is gone."""


class PrinterHalted(RemoteError):
    """The firmware stopped itself (kill(): M112, thermal runaway, ...) until it is reset."""


class VariantMismatch(RemoteError):
    """The printer speaks other protocol variants (the lab's, Ultimaker's) than this host:
    neither side could understand the other, so the session stops before anything is sent."""


class PrinterLocked(RemoteError):
    """The printer refuses every command until it is unlocked (M511 P<password>)."""


class CommandFailed(RemoteError):
    """The printer refused a command or could not run it (g2core: a status other than OK in the
    footer of its response): the job stops there. `status`: the printer's code, where it has one."""

    def __init__(self, message: str, status: int | None = None) -> None:
        super().__init__(message)
        self.status = status


class UsageError(HostError):
    """The caller asked for something that cannot be done."""


class CommandError(UsageError):
    """A command cannot be sent as given (too long, not ASCII)."""


class UploadFailed(RemoteError):
    """A file could not be stored on the printer intact, or the printer would not print it."""
