"""The trio client for Marlin's ASCII protocol: the shared shell around the line sender
(fake_marlin.host.cores.marlin)."""

import trio

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

    def _open(self, options: ClientOptions) -> None:
        self._parser = marlin.LineParser()
        self._core = self._sender = MarlinCore(
            timeout=options.timeout,
            long_timeout=options.long_timeout,
            received_timeout=options.received_timeout,
            max_transmissions=options.max_transmissions,
        )
        self._response: list[str] = []  # data lines since the last ok

    def _feed(self, data: bytes) -> None:
        now = trio.current_time()
        self._parser.receive_data(data)
        while (event := self._parser.next_event()) is not None:
            self._printer_seen.set()
            self._handle(event, now)
        self.corrupt_frames = self._parser.garbled
        self._completed(self._sender.take_completed())
        self._sender_wake.set()  # deadlines moved, or there is something to send

    def _handle(self, event: marlin.Event, now: float) -> None:
        sender = self._sender
        if isinstance(event, marlin.Ok):
            response = (*self._response, event.text) if event.text else tuple(self._response)
            self._response.clear()
            if event.planner_free is not None:
                self.room = event.planner_free
            sender.on_ok(event, response, now)
        elif isinstance(event, marlin.LineError):
            sender.on_line_error(event.last_line, now)
        elif isinstance(event, marlin.ResendRequest):
            sender.on_resend(event.line, now)
        else:
            sender.on_line(event.kind, event.text, now)
            if event.kind in (marlin.LineKind.DATA, marlin.LineKind.ECHO) and sender.expecting_response:
                self._response.append(event.text)
            else:
                self._on_line(event)

    def _poll(self, now: float) -> list[bytes]:
        data = self._sender.poll(now)
        self._completed(self._sender.take_completed())
        return data

    async def wait_idle(self) -> None:
        """Also confirms the printer holds every line sent (one probe; see cores.marlin)."""
        self._sender.request_verification()
        self._sender_wake.set()
        await super().wait_idle()
