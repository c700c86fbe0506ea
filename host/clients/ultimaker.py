"""The trio client for Ultimaker's binary protocol: the shared shell around the go-back-N window
(fake_marlin.host.cores.ultimaker)."""

import trio

from fake_marlin.host.codecs import marlin
from fake_marlin.host.codecs.ultimaker import (
    Ack,
    CorruptFrame,
    Event,
    FrameParser,
    LineKind,
    Reject,
    RoomInfo,
    check_command,
    encode_command,
)
from fake_marlin.host.cores.ultimaker import UltimakerCore
from fake_marlin.host.errors import PrinterHalted
from fake_marlin.host.shell import ClientOptions, StreamingClient


class UltimakerClient(StreamingClient):
    protocol = "ultimaker"
    check_command = staticmethod(check_command)

    def _open(self, options: ClientOptions) -> None:
        self._parser = FrameParser()
        self._core = self._window = UltimakerCore(
            window=options.window,
            timeout=options.timeout,
            long_timeout=options.long_timeout,
            received_timeout=options.received_timeout,
            max_transmissions=options.max_transmissions,
        )
        self._response: list[str] = []

    def _feed(self, data: bytes) -> None:
        self._parser.receive_data(data)
        while (event := self._parser.next_event()) is not None:
            self._handle(event)

    def _handle(self, event: Event) -> None:
        now = trio.current_time()
        if isinstance(event, Ack):
            done = self._window.on_ack(event.seq, event.room, tuple(self._response), now)
            self._response.clear()
            self.room = event.room
            self._completed(done)
        elif isinstance(event, Reject):
            self.room = event.room
            self._window.on_reject(event.seq, event.room, now)
            self._sender_wake.set()
        elif isinstance(event, RoomInfo):
            self.room = event.room
            self._window.heard(now, event.room)
            self._printer_seen.set()
            self._sender_wake.set()  # deadlines moved
        elif isinstance(event, CorruptFrame):
            self.corrupt_frames += 1
        else:
            self._window.heard(now)
            if event.kind is LineKind.RESPONSE:
                self._response.append(event.text)
            else:
                if event.kind is LineKind.LOG:
                    self._printer_seen.set()
                self._on_line(event)
                if event.kind is LineKind.ERROR and marlin.is_halt_message(event.text):
                    raise PrinterHalted(f"the printer halted: Error:{event.text}")

    def _poll(self, now: float) -> list[bytes]:
        data = [encode_command(t.seq, t.text) for t in self._window.poll(now)]
        self._completed(self._window.take_completed())
        return data
