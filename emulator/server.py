"""The printer's life on a link: power on, boot, and reboot whenever a host opens the port."""

from dataclasses import dataclass

import trio

from emulator.faults import FaultConfig, FaultLayer
from emulator.journal import Journal
from emulator.link.pty import HostOpened, PtyLink
from emulator.printer.model import Printer
from emulator.sessions.detect import Detected, DetectingSession
from emulator.sessions.marlin import MarlinSession
from emulator.sessions.ultimaker import UltimakerSession

PROTOCOLS = ("auto", "marlin", "ultimaker")


@dataclass(frozen=True)
class ServerConfig:
    protocol: str = "auto"
    boot_delay: float = 0.0  # simulated seconds a reset takes before the printer answers
    ultimaker_queue_size: int = 8
    advanced_ok: bool = False
    faults: FaultConfig = FaultConfig()


class PrinterServer:
    def __init__(self, link: PtyLink, printer: Printer, journal: Journal, config: ServerConfig) -> None:
        self.link = link
        self.printer = printer
        self.journal = journal
        self.config = config
        self.boots = 0
        self.faults = FaultLayer(config.faults)
        self._session = None
        self._session_scope = trio.CancelScope()

    async def run(self, task_status=trio.TASK_STATUS_IGNORED) -> None:
        """Power on, then serve; started (for nursery.start) once the power-on greeting is out,
        so a host that opens the port as soon as it hears of it sees one boot, not two."""
        async with trio.open_nursery() as nursery:
            nursery.start_soon(self.link.run_writer)
            await nursery.start(self._boot)
            await self.link.drain()
            task_status.started()
            while True:
                item = await self.link.receive()
                if isinstance(item, HostOpened):
                    self._session_scope.cancel()
                    self.link.discard_output()
                    await nursery.start(self._boot)
                elif self._session is not None:
                    self._session.feed(self.faults.to_printer(item))
                # Bytes that arrive while the printer is still booting are lost, as on a real board.

    async def _boot(self, task_status=trio.TASK_STATUS_IGNORED) -> None:
        self._session = None
        with trio.CancelScope() as scope:
            self._session_scope = scope
            task_status.started()
            now = trio.current_time()
            self.printer.reset(now)
            if self.config.boot_delay > 0:
                await trio.sleep(self.config.boot_delay)
            reason = "PowerUp" if self.boots == 0 else " External Reset"
            session = self._make_session(self.config.protocol, reason)
            self.boots += 1
            session.boot()
            self._session = session
            await session.run()

    def _make_session(self, protocol: str | Detected, reason: str):
        protocol = protocol.value if isinstance(protocol, Detected) else protocol
        if protocol == "auto":
            return DetectingSession(lambda detected: self._make_session(detected, reason))
        if protocol == "marlin":
            return MarlinSession(
                self.printer, self.journal, self._send, self.config.advanced_ok, reason
            )
        if protocol == "ultimaker":
            return UltimakerSession(
                self.printer, self.journal, self._send, self.config.ultimaker_queue_size
            )
        raise ValueError(f"unknown protocol {protocol!r}")

    def _send(self, data: bytes) -> None:
        self.link.send(self.faults.to_host(data))
