"""One boot of a printer speaking Ultimaker's binary protocol."""

import math
from collections import deque
from collections.abc import Callable, Iterable

import trio

from fake_marlin.emulator.firmware import Firmware
from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.printer.gcode import plain_move
from fake_marlin.emulator.printer.model import Printer, Reply
from fake_marlin.emulator.printer.statements import Statement
from fake_marlin.emulator.protocols.base import CommandDone, CommandReceived, Output
from fake_marlin.emulator.protocols.ultimaker import (
    OutOfBand,
    OutOfBandKind,
    RoomChanged,
    UltimakerProtocol,
)
from fake_marlin.wire.ultimaker_variants import PLAIN, Variants, boot_line
from fake_marlin.emulator.sessions.driver import CommandRun, finish, hold_queue_full


class UltimakerSession:
    def __init__(
        self,
        printer: Printer,
        journal: Journal,
        send: Callable[[bytes], None],
        queue_size: int = 8,
        before_command: Callable[[str], None] = lambda text: None,
        firmware: Firmware | None = None,
        variants: Variants = PLAIN,
    ) -> None:
        self.printer = printer
        self._words = (firmware or Firmware.make()).words
        self.journal = journal
        self._send = send
        self._before_command = before_command
        self.protocol = UltimakerProtocol(queue_size, variants)
        self._backlog: deque[CommandReceived] = deque()  # received while a command waits
        self._waiting: tuple[CommandReceived, CommandRun, float] | None = None
        self._executor_idle = False  # until the executor task runs
        self._work = trio.Event()
        self._room_may_change = trio.Event()

    def boot(self) -> None:
        # The lab's variants say so in the boot line, so that a host without them knows why
        # it cannot be understood (docs/protocols.md section 1.1).
        self._send(self.protocol.send(
            OutOfBand(OutOfBandKind.LOG, boot_line(self.protocol.variants))))
        self._update_room()

    def feed(self, data: bytes) -> None:
        if self.printer.halted:
            return  # a killed printer reads nothing until it is reset
        # The receiver answers bad packets with the planner room as it is now.
        self._update_room()
        self.protocol.receive_data(data)
        while (event := self.protocol.next_event()) is not None:
            if isinstance(event, CommandReceived):
                if self._executor_idle and not self._backlog:
                    self._run_here(event)  # the common case: no task hop on the way to `o`
                else:
                    self._backlog.append(event)
                    self._work.set()
        self._send(self.protocol.data_to_send())

    async def run(self) -> None:
        async with trio.open_nursery() as nursery:
            nursery.start_soon(self._execute_commands)
            nursery.start_soon(self._report_room)

    def announce(self, statements: Iterable[Statement]) -> None:
        """What the firmware says on its own: errors out of band as `Error:`, the rest as LOG."""
        for line in self._words.lines(statements):
            if line.startswith("Error:"):
                self._send(self.protocol.send(OutOfBand(OutOfBandKind.ERROR, line[len("Error:"):])))
            else:
                self._send(self.protocol.send(OutOfBand(OutOfBandKind.LOG, line)))

    def block_queue(self, seconds: float, nursery: trio.Nursery) -> None:
        """The command queue stays full for a while: packets are refused with `buffer full`."""
        hold_queue_full(self.protocol, seconds, nursery)

    # A command runs where it arrives (in feed) until it has to wait for time (a full
    # planner, a dwell, heating); then this task carries it on, and the packets behind it wait
    # in the backlog, in order, as in the firmware's command queue.
    async def _execute_commands(self) -> None:
        while not self.printer.halted:
            if self._waiting is not None:
                received, run, until = self._waiting
                self._waiting = None
                reply = await finish(run, until)
                self._done(received, reply)
            elif self._backlog:
                self._executor_idle = False
                self._run_here(self._backlog.popleft())
            else:
                self._executor_idle = True
                work = self._work = trio.Event()
                await work.wait()
        await trio.sleep_forever()

    def _run_here(self, received: CommandReceived) -> None:
        if not self.printer.halted:
            self._before_command(received.text)
        if self.printer.halted:
            self._executor_idle = False  # it runs nothing more until the printer is reset
            return
        move = plain_move(received.text)
        if move is not None and self.printer.move_at_once(move, trio.current_time()):
            self.journal.record(received.text)  # the common case: as CommandRun would, at once
            self._done(received, Reply())
            return
        run = CommandRun(self.printer, received.text, self.journal, self._respond)
        until = run.advance()
        if until is None:
            self._done(received, run.reply)
        else:
            self._executor_idle = False
            self._waiting = (received, run, until)
            self._work.set()

    def _done(self, received: CommandReceived, reply: Reply) -> None:
        if self.printer.halted:
            self.announce(reply.response_data())
            self._backlog.clear()
            return
        room = self.printer.room(trio.current_time())
        response = tuple(self._words.lines(reply.response_data()))
        self._send(self.protocol.send(CommandDone(received.number, room, response)))
        if self.protocol.reported_room == 0:
            self._room_may_change.set()  # the room reporter times the `q` for when it opens

    def _respond(self, statement: Statement) -> None:
        for text in self._words.say(statement):
            if text.startswith("Error:"):
                self._send(self.protocol.send(OutOfBand(OutOfBandKind.ERROR, text[len("Error:"):])))
            else:
                self._send(self.protocol.send(Output(text)))

    def _update_room(self) -> None:
        self._send(self.protocol.send(RoomChanged(self.printer.room(trio.current_time()))))

    async def _report_room(self) -> None:
        """Send `q` when room the host last saw as 0 opens up, as the firmware's loop() does."""
        while True:
            self._update_room()
            wake = self._room_may_change = trio.Event()
            deadline = math.inf
            if self.protocol.reported_room == 0:
                deadline = self.printer.next_room_change(trio.current_time()) or math.inf
            with trio.move_on_at(deadline):
                await wake.wait()
