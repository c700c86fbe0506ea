"""The trio client for Repetier-Firmware: the shared shell (fake_marlin.host.shell) around
the Repetier sender (fake_marlin.host.cores.repetier)."""

import trio

from fake_marlin.host.codecs import repetier
from fake_marlin.host.cores.queue import Ticket
from fake_marlin.host.cores.repetier import RepetierCore
from fake_marlin.host.shell import ClientOptions, StreamingClient


class RepetierClient(StreamingClient):
    """Repetier's protocol: binary commands where they fit, `ok <N>` when queued."""

    protocol = "repetier"
    # `ok N` comes when N is queued: one command waits in the firmware's buffer, one runs.
    acknowledged_ahead = 2
    check_command = staticmethod(repetier.check_command)

    def _open(self, options: ClientOptions) -> None:
        self._parser = repetier.LineParser()
        self._core = self._sender = RepetierCore(
            timeout=options.timeout,
            long_timeout=options.long_timeout,
            max_transmissions=options.max_transmissions,
        )
        self._answering: Ticket | None = None  # whose output is arriving: the last one queued

    def _feed(self, data: bytes) -> None:
        now = trio.current_time()
        self._parser.receive_data(data)
        while (event := self._parser.next_event()) is not None:
            self._printer_seen.set()
            self._sender.on_event(event, now)
            self._completed(self._sender.take_completed())
            if isinstance(event, repetier.Identity):
                event = repetier.Line(repetier.LineKind.DATA, event.text)
            if isinstance(event, repetier.Line):
                self._show(event)
        self.corrupt_frames = self._parser.garbled
        self._sender_wake.set()

    def _show(self, line: repetier.Line) -> None:
        # Repetier acknowledges a command when it queues it, so what it prints comes after
        # the ok: the output of the command queued last.
        ticket = self._answering
        if line.kind in (repetier.LineKind.DATA, repetier.LineKind.REPORT) and ticket is not None:
            ticket.response += (line.text,)
        else:
            self._on_line(line)

    def _completed(self, tickets: list[Ticket]) -> None:
        if tickets:
            self._answering = tickets[-1]
        super()._completed(tickets)

    def _poll(self, now: float) -> list[bytes]:
        data = self._sender.poll(now)
        self._completed(self._sender.take_completed())
        return data

    async def send(self, command: str) -> tuple[str, ...]:
        """Send one command; returns what it printed once the printer has run it (its `wait`)."""
        ticket = await self.submit(command)
        await self.wait_idle()
        return ticket.response

    async def wait_idle(self) -> None:
        """Until every command is queued and the printer, idle, has said `wait`: it ran them."""
        self._sender.request_drained()
        self._sender_wake.set()
        await super().wait_idle()
