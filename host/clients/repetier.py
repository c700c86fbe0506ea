"""The trio client for Repetier-Firmware: the shared shell (fake_marlin.host.shell) around
the Repetier core (fake_marlin.host.cores.repetier)."""

from fake_marlin.host.codecs import repetier
from fake_marlin.host.cores.repetier import RepetierCore
from fake_marlin.host.shell import ClientOptions, StreamingClient


class RepetierClient(StreamingClient):
    """Repetier's protocol: binary commands where they fit, `ok <N>` when queued."""

    protocol = "repetier"
    # `ok N` comes when N is queued: one command waits in the firmware's buffer, one runs.
    acknowledged_ahead = 2
    check_command = staticmethod(repetier.check_command)
    _core: RepetierCore

    def _open(self, options: ClientOptions) -> None:
        self._core = RepetierCore(
            timeout=options.timeout,
            long_timeout=options.long_timeout,
            max_transmissions=options.max_transmissions,
        )

    async def send(self, command: str) -> tuple[str, ...]:
        """Send one command; returns what it printed once the printer has run it (its `wait`)."""
        ticket = await self.submit(command)
        await self.wait_idle()
        return ticket.response

    async def wait_idle(self) -> None:
        """Until every command is queued and the printer, idle, has said `wait`: it ran them."""
        self._core.request_drained()
        self._sender_wake.set()
        await super().wait_idle()
