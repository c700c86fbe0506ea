"""One boot of a printer running Repetier-Firmware: its protocol, its words, its timers.

The printer model is Marlin's; what Repetier prints differently is said here: the boot lines,
M115 with `REPETIER_PROTOCOL:3`, temperatures as `T:20.00 /0 B:20.00 /0 B@:0 @:0` on a line of
their own (the `ok` went out when the command was queued), M114, `TargetExtr0:` and
`TargetBed:`, `busy:processing` and `busy:heating` keepalives, and `wait` when idle.
"""

import math
from collections.abc import Callable, Iterable

import trio

from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.printer.gcode import Command, parse
from fake_marlin.emulator.printer.model import Printer, Reply
from fake_marlin.emulator.protocols.base import CommandDone, CommandReceived, Output
from fake_marlin.emulator.protocols.repetier import EmergencyStop, RepetierProtocol
from fake_marlin.emulator.sessions.base import MachineClock
from fake_marlin.emulator.sessions.driver import hold_queue_full, run_command

VERSION = "1.0.4"
KEEP_ALIVE_INTERVAL = 2.0  # Repetier.h's KEEP_ALIVE_INTERVAL, 2000 ms
HEATING = frozenset({"M109", "M190"})


def temperatures(printer: Printer, now: float) -> str:
    """Commands::printTemperatures(): one line, with T<n> parts when there are several."""
    active = printer.hotends[printer.active_tool]
    line = (
        f"T:{active.temperature(now):.2f} /{active.target:.0f} "
        f"B:{printer.bed.temperature(now):.2f} /{printer.bed.target:.0f} "
        f"B@:{printer.bed.power(now)} @:{active.power(now)}"
    )
    if len(printer.hotends) > 1:
        for index, heater in enumerate(printer.hotends):
            line += f" T{index}:{heater.temperature(now):.2f} /{heater.target:.0f} @{index}:{heater.power(now)}"
    return line


def firmware_info(printer: Printer) -> list[str]:
    config = printer.config
    return [
        f"FIRMWARE_NAME:Repetier_{VERSION} FIRMWARE_URL:https://github.com/repetier/Repetier-Firmware/ "
        f"PROTOCOL_VERSION:1.0 MACHINE_TYPE:Mendel EXTRUDER_COUNT:{config.extruders} "
        "REPETIER_PROTOCOL:3",
        "Cap:PROGRESS:0",
        "Cap:AUTOREPORT_TEMP:1",
        f"Cap:EEPROM:{int(config.capability('EEPROM'))}",
        f"Cap:AUTOLEVEL:{int(config.capability('AUTOLEVEL'))}",
        f"Cap:Z_PROBE:{int(config.capability('Z_PROBE'))}",
        "Cap:SOFTWARE_POWER:0",
        "Cap:TOGGLE_LIGHTS:0",
        "Cap:PAUSESTOP:1",
        "Cap:PREHEAT:1",
        "PrinterMode:FFF",
    ]


class RepetierSession:
    def __init__(
        self,
        printer: Printer,
        journal: Journal,
        send: Callable[[bytes], None],
        reset_reason: str = "PowerUp",
        before_command: Callable[[str], None] = lambda text: None,
    ) -> None:
        self.printer = printer
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
        self.announce(["start", f"Info:{self.reset_reason}", "Free RAM:3412", "SelectExtruder:0"])

    def announce(self, lines: Iterable[str]) -> None:
        for line in lines:
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
        self.announce(self._words(command, reply))

    def _on_report(self, text: str) -> None:
        if self._running is not None and self._running.code in HEATING:
            text = temperatures(self.printer, trio.current_time())
        self.announce([text])

    def _words(self, command: Command, reply: Reply) -> list[str]:
        """What Repetier prints for a command, where it differs from Marlin."""
        printer, now = self.printer, trio.current_time()
        if printer.halted:
            return list(reply.response_data())
        if command.code == "M105":
            return [temperatures(printer, now)]
        if command.code == "M114":
            x, y, z, e = printer.motion.position
            return [f"X:{x:.2f} Y:{y:.2f} Z:{z:.3f} E:{e:.4f}"]
        if command.code == "M115":
            return firmware_info(printer)
        if command.code in ("M104", "M109") and command.has("S") and not reply.lines:
            tool = int(command.value("T", printer.active_tool))
            return [f"TargetExtr{tool}:{printer.hotends[tool].target:.0f}"]
        if command.code in ("M140", "M190") and command.has("S"):
            return [f"TargetBed:{printer.bed.target:.0f}"]
        return list(reply.response_data())

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
                if now >= last_signal + KEEP_ALIVE_INTERVAL:
                    kind = "heating" if running.code in HEATING else "processing"
                    self.announce([f"busy:{kind}"])
                    last_signal = now
                deadline = last_signal + KEEP_ALIVE_INTERVAL
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
                    self.announce([temperatures(self.printer, now)])
                    last = now
                deadline = last + interval
            with trio.move_on_at(deadline):
                await changed.wait()
