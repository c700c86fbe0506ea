"""The trio client for Marlin's ASCII protocol: the shared shell around the line sender
(fake_marlin.host.cores.marlin)."""

from fake_marlin.host.codecs import marlin
from fake_marlin.host.cores.marlin import MarlinCore
from fake_marlin.host.shell import ClientOptions, StreamingClient


class MarlinClient(StreamingClient):
    """Marlin's ASCII protocol: numbered lines, one in flight (see fake_marlin.host.cores.marlin)."""

    protocol = "marlin"
    # An ok means the line ran, but not every ok is the line's: a line can repeat an ok (a USB
    # adapter that sends a packet twice), and a line whose N was damaged runs bare and says ok
    # too. Either counts the line in flight done before it ran; both at once, two.
    acknowledged_ahead = 2
    check_command = staticmethod(marlin.check_command)
    _core: MarlinCore

    def _open(self, options: ClientOptions) -> None:
        self._core = MarlinCore(
            timeout=options.timeout,
            long_timeout=options.long_timeout,
            received_timeout=options.received_timeout,
            max_transmissions=options.max_transmissions,
        )

    async def wait_idle(self) -> None:
        """Also confirms the printer holds every line sent (one probe; see cores.marlin)."""
        self._core.request_verification()
        self._sender_wake.set()
        await super().wait_idle()
