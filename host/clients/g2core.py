"""The trio client for g2core's JSON protocol: the shared shell around the line-mode core
(fake_marlin.host.cores.g2core)."""

from fake_marlin.host.codecs import g2core
from fake_marlin.host.cores.g2core import G2coreCore
from fake_marlin.host.shell import ClientOptions, StreamingClient


class G2coreClient(StreamingClient):
    """g2core, exactly once: `N<k> ...*<xor>` lines, one at a time, a lost one or a lost answer
    found out and put right (see fake_marlin.host.cores.g2core); `window` is how many commands
    the caller may queue ahead. `send` and `print_commands` return once the board has also run
    what they sent. `feedhold`, `resume` and `cancel` write g2core's `!`, `~` and ^D."""

    protocol = "g2core"
    # A response means the line was planned, not run; but a g2core board (native USB) does not
    # reset when a port is opened: it runs what it planned, whoever is connected. What a host
    # that lost the port cannot know is the fate of the one line it had in flight.
    acknowledged_ahead = 0
    check_command = staticmethod(g2core.check_command)
    _core: G2coreCore

    def _open(self, options: ClientOptions) -> None:
        self._core = G2coreCore(
            window=options.window,
            timeout=options.timeout,
            max_transmissions=options.max_transmissions,
        )

    @property
    def firmware_build(self) -> float | None:
        """The board's `fb` (e.g. 101.03), once it has said it."""
        return self._core.firmware_build

    async def send(self, command: str) -> tuple[str, ...]:
        """Send one command; returns its response data (a JSON request's answer, without `n`)
        once the board has run it."""
        ticket = await self.submit(command)
        await self.wait_idle()
        return ticket.response

    async def wait_idle(self) -> None:
        """Until every command is answered and the board, out of its cycle with an empty
        planner, has run them all."""
        self._core.request_drained()
        self._sender_wake.set()
        await super().wait_idle()

    async def feedhold(self) -> None:
        """`!`: the board decelerates to a stop; 101.x boards read no more G-code until resume."""
        self._core.feedhold()
        self._sender_wake.set()

    async def resume(self) -> None:
        """`~`: the end of a feedhold (or of an M0 pause)."""
        self._core.resume()
        self._sender_wake.set()

    async def cancel(self) -> None:
        """Stop the job: what is not sent yet is dropped, the board kills the job (^D) and drops
        what it has queued; returns once the board is idle. Stop the task feeding commands first
        (print_commands would go on submitting)."""
        self._core.cancel()
        self._sender_wake.set()
        await self.wait_idle()
