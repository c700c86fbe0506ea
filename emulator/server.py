"""The printer's life on a link: power on, boot, and reboot whenever a host opens the port."""

from dataclasses import dataclass

import trio

from emulator.journal import Journal
from emulator.link.pty import HostOpened, PtyLink
from emulator.printer.model import Printer
from emulator.sessions.ultimaker import UltimakerSession


@dataclass(frozen=True)
class ServerConfig:
    protocol: str = "ultimaker"
    boot_delay: float = 0.0  # simulated seconds a reset takes before the printer answers
    queue_size: int = 8


class PrinterServer:
    def __init__(self, link: PtyLink, printer: Printer, journal: Journal, config: ServerConfig) -> None:
        self.link = link
        self.printer = printer
        self.journal = journal
        self.config = config
        self.boots = 0
        self._session: UltimakerSession | None = None
        self._session_scope = trio.CancelScope()

    async def run(self) -> None:
        async with trio.open_nursery() as nursery:
            nursery.start_soon(self.link.run_writer)
            await nursery.start(self._boot)
            while True:
                item = await self.link.receive()
                if isinstance(item, HostOpened):
                    self._session_scope.cancel()
                    self.link.discard_output()
                    await nursery.start(self._boot)
                elif self._session is not None:
                    self._session.feed(item)
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
            session = UltimakerSession(self.printer, self.journal, self.link.send, self.config.queue_size)
            self.boots += 1
            session.boot()
            self._session = session
            await session.run()
