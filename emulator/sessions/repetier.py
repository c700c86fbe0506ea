"""One boot of a printer running Repetier-Firmware: its protocol, its words, its timers.

The words are the repetier profile's (firmware/profiles/repetier.toml): the boot lines, M115
with `REPETIER_PROTOCOL:3`, temperatures as `T:20.00 /0 B:20.00 /0 B@:0 @:0` on a line of
their own (the `ok` went out when the command was queued), M114, `TargetExtr0:` and
`TargetBed:`, `busy:processing` and `busy:heating` keepalives; the protocol's machine says
`ok N`, `Resend:`, `skip` and `wait`.
"""

import math
from collections.abc import Callable, Iterable

import trio

from fake_marlin.emulator.firmware import Firmware
from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.printer.gcode import Command, parse
from fake_marlin.emulator.printer.model import Printer
from fake_marlin.emulator.printer.statements import Statement, state
from fake_marlin.emulator.protocols.base import CommandDone, CommandReceived, Output
from fake_marlin.emulator.protocols.repetier import EmergencyStop, RepetierProtocol
from fake_marlin.emulator.sessions.base import MachineClock
from fake_marlin.emulator.sessions.driver import hold_queue_full, run_command

HEATING = frozenset({"M109", "M190"})


class RepetierSession:
    def __init__(
        self,
        printer: Printer,
        journal: Journal,
        send: Callable[[bytes], None],
        reset_reason: str = "PowerUp",
        before_command: Callable[[str], None] = lambda text: None,
        firmware: Firmware | None = None,
    ) -> None:
        self.printer = printer
        self.firmware = firmware = firmware or Firmware.make("repetier")
        self._words = firmware.words
        self._keep_alive_interval = (firmware.profile.busy.interval if firmware.quirks.busy_interval
                                     is None else firmware.quirks.busy_interval)
        self.journal = journal
        self._send = send
        self.reset_reason = reset_reason.strip()
        self._before_command = before_command
        self.protocol = RepetierProtocol()
        self._queue_in, self._queue_out = trio.open_memory_channel[CommandReceived](math.inf)
        self._running: Command | None = None
        self._changed = {"busy": trio.Event(), "reports": trio.Event()}
        # A half-read command or an awaited resend meets silence: the firmware asks again
        # (200 ms); idle, it says `wait` every second.
        self._clock = MachineClock(
            self.protocol,
            after=lambda: self._send(self.protocol.data_to_send()),
            running=lambda: not self.printer.halted,
        )

    def boot(self) -> None:
        self._clock.tell()  # the quiet counts from the boot
        self.announce((state("greeting", reason=self.reset_reason, sd=self.printer.sd.mounted),))

    def announce(self, statements: Iterable[Statement]) -> None:
        for line in self._words.lines(statements):
            self._send(self.protocol.send(Output(line)))

    def block_queue(self, seconds: float, nursery: trio.Nursery) -> None:
        hold_queue_full(self.protocol, seconds, nursery, resume=lambda: self.feed(b""))

    def feed(self, data: bytes) -> None:
        if self.printer.halted:
            return
        self.protocol.receive_data(data)
        while (event := self.protocol.next_event()) is not None:
            if isinstance(event, CommandReceived):
                self._queue_in.send_nowait(event)
            elif isinstance(event, EmergencyStop):
                self.announce(self.printer.emergency("M112", trio.current_time()))
                self.journal.record(event.text)
                break
        self._send(self.protocol.data_to_send())
        # timeOfLastDataPacket: the firmware's timers count from the last byte it read. Bytes
        # that arrive while its command buffer is full wait unread, so a command found damaged
        # once the buffer frees draws one Resend now and the next only after 200 ms more of
        # quiet, not a second one at once.
        self._clock.tell()
        self._wake()

    def _wake(self) -> None:
        for event in self._changed.values():
            event.set()
        self._clock.changed()

    def _changes(self, task: str) -> trio.Event:
        event = self._changed[task] = trio.Event()
        return event

    async def run(self) -> None:
        async with trio.open_nursery() as nursery:
            nursery.start_soon(self._execute_commands)
            nursery.start_soon(self._clock.run)
            nursery.start_soon(self._keep_host_alive)
            nursery.start_soon(self._report_temperatures)

    # -- executing ---------------------------------------------------------------------
    async def _execute_commands(self) -> None:
        while not self.printer.halted:
            received = await self._queue_out.receive()
            await self._run(received.text)
            if self.printer.halted:
                break
            self._send(self.protocol.send(CommandDone()))
            self.feed(b"")  # the buffer has room again: read on
        await trio.sleep_forever()

    async def _run(self, text: str) -> None:
        sd = self.printer.sd
        command = parse(text)
        if sd.saving is not None and command.code != "M29":
            sd.write_line(text)  # between M28 and M29 lines are stored, not run
            return
        self._before_command(text)
        if self.printer.halted:
            return
        self._running = command
        self._wake()
        try:
            reply = await run_command(self.printer, text, self.journal, self._on_report)
        finally:
            self._running = None
            self._wake()
        # The `ok` went out when the command was queued: all it says comes after.
        self.announce(reply.response_data())

    def _on_report(self, statement: Statement) -> None:
        self.announce((statement,))

    # -- what the printer says on its own ----------------------------------------------
    async def _keep_host_alive(self) -> None:
        """GCode::keepAlive: `busy:` every KEEP_ALIVE_INTERVAL while the buffer is full."""
        last_signal = -math.inf
        while True:
            changed = self._changes("busy")
            deadline = math.inf
            running = self._running
            if running is not None and not self.protocol.reading and not self.printer.halted:
                now = trio.current_time()
                interval = self._keep_alive_interval
                if interval > 0 and now >= last_signal + interval:
                    kind = "busy_heating" if running.code in HEATING else "busy_processing"
                    self.announce((state(kind),))
                    last_signal = now
                deadline = last_signal + interval if interval > 0 else math.inf
            with trio.move_on_at(deadline):
                await changed.wait()

    async def _report_temperatures(self) -> None:
        """M155 S<n>: the M105 line every n seconds."""
        last = -math.inf
        while True:
            changed = self._changes("reports")
            interval = self.printer.auto_reports.temperature
            now = trio.current_time()
            deadline = math.inf
            if interval > 0 and not self.printer.halted:
                if now >= last + interval:
                    self.announce((self.printer.temperature_report(now, "auto_temperatures"),))
                    last = now
                deadline = last + interval
            with trio.move_on_at(deadline):
                await changed.wait()
