"""One boot of a printer speaking Marlin's ASCII protocol, in its firmware's words (Marlin's,
Prusa's, Klipper's...: the firmware's profile says them, and sets the protocol's rules)."""

import math
import re
from collections import deque
from collections.abc import Callable, Iterable

import trio

from fake_marlin.emulator.firmware import Firmware, Quirks
from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.printer.gcode import Command, parse, plain_move
from fake_marlin.emulator.printer.model import SELF_REPORTING, Printer, Reply
from fake_marlin.emulator.printer.statements import Statement, state
from fake_marlin.emulator.protocols.base import CommandDone, CommandReceived, Output
from fake_marlin.emulator.protocols.marlin import (
    EmergencyCommand,
    MarlinProtocol,
    RealtimeCommand,
)
from fake_marlin.emulator.sessions.driver import CommandRun, finish, hold_queue_full
from fake_marlin.emulator.sessions.marlin_binary import BinaryTransfer

PLAIN_OK = CommandDone()  # without ADVANCED_OK an `ok` says nothing of its line: one event does for all
QUIET_OK = CommandDone(quiet=True)  # the slot is free, the `ok` never sent (a quirk)


class MarlinSession:
    def __init__(
        self,
        printer: Printer,
        journal: Journal,
        send: Callable[[bytes], None],
        advanced_ok: bool = False,
        reset_reason: str = "PowerUp",
        before_command: Callable[[str], None] = lambda text: None,
        firmware: Firmware | None = None,
        restart: Callable[[str], None] = lambda reason: None,
    ) -> None:
        self.printer = printer
        self._restart_board = restart  # the server's: reset the board now, for this reason
        self._resetting = False  # a reset is asked for: this boot reads nothing more
        self.journal = journal
        self._send = send
        self.reset_reason = reset_reason
        self._before_command = before_command
        self.firmware = firmware = firmware or Firmware.make()
        self._words = firmware.words
        self.protocol = MarlinProtocol(advanced_ok, rules=firmware.line_rules())
        self._oks = 0  # sent or dropped, for the quirk that drops every Nth
        self._drop_ok_every = firmware.quirks.drop_ok_every
        self._backlog: deque[CommandReceived] = deque()  # received while a command waits
        self._ok_sent: CommandReceived | None = None  # its `ok` went before it ran (ok_before_run)
        self._waiting: tuple[CommandReceived, Command, CommandRun, float] | None = None
        self._executor_idle = False  # until the executor task runs
        # [halt] answers_all: the wait a halt cuts short, and whether what was queued before
        # the halt still owes its answers (what arrives meanwhile waits behind them).
        self._interrupt: trio.CancelScope | None = None
        self._pending_answers = False
        self._work = trio.Event()
        self._halt_changed = trio.Event()
        self._reports: tuple[object, ...] = ()
        quirks = firmware.quirks
        self.busy_interval = (firmware.profile.busy.interval if quirks.busy_interval is None
                              else quirks.busy_interval)
        self._busy = False
        self._busy_changed = trio.Event()
        self._reports_changed = trio.Event()
        self._binary = BinaryTransfer(printer, send, self._report)  # M28 B1's file transfer

    def boot(self) -> None:
        self.announce((state("greeting", reason=self.reset_reason, sd=self.printer.sd.mounted),))

    def _say(self, text: str) -> None:
        self._send(self.protocol.send(Output(text)))

    def announce(self, statements: Iterable[Statement]) -> None:
        """What the firmware says on its own (a fault, a kill), in its words."""
        for statement in statements:
            for line in self._words.say(statement):
                self._say(line)

    def _report(self, statement: Statement) -> None:
        self.announce((statement,))

    def block_queue(self, seconds: float, nursery: trio.Nursery) -> None:
        """The command queue stays full for a while: the firmware stops reading its input."""
        hold_queue_full(self.protocol, seconds, nursery, resume=lambda: self.feed(b""))

    def feed(self, data: bytes) -> None:
        if self._resetting:
            return  # the board is going down: what comes now is read by the next boot, or lost
        if self.printer.halted:
            halt = self.firmware.profile.halt
            if halt.answers_all and (self._pending_answers or self._owes_answers()):
                self._pending_answers = True
                self.protocol.receive_data(data)  # read once what came before is answered
                self._wake()
            elif halt.reads:
                self._feed_halted(data)
            return  # a killed Marlin reads nothing until it is reset
        binary = self._binary
        if binary.protocol is not None and binary.active:  # (None: no M28 B1 this boot)
            data = binary.feed(data)  # what follows is ASCII again, if anything
            if binary.active or not data:
                return
        self.protocol.receive_data(data)
        while (event := self.protocol.next_event()) is not None:
            if isinstance(event, CommandReceived):
                if self._executor_idle and not self._backlog:
                    self._run_here(event)  # the common case: no task hop on the way to `ok`
                else:
                    self._backlog.append(event)
                    self._work.set()
            elif isinstance(event, EmergencyCommand):
                self.announce(self.printer.emergency(event.text, trio.current_time()))
                if self.printer.halted:
                    self._wake()
                    if self.firmware.profile.halt.answers_all:
                        self._halted_reading_on()
                    break
            elif isinstance(event, RealtimeCommand) and self._realtime(event):
                break  # it halted the printer
        if rejections := self.protocol.data_to_send():  # a rejected line's Error and Resend
            self._send(rejections)
        if binary.protocol is not None and binary.active:
            self.feed(b"")  # what came with M28 B1 is the binary protocol's

    def _realtime(self, event: RealtimeCommand) -> bool:
        """A character the firmware acts on as it arrives (Smoothieware's `?`, ^X); True if it
        halted the printer, which then drops what it has not read yet (its RX buffer)."""
        halted = self.printer.halted
        self.announce(self.printer.realtime(event.text, trio.current_time()))
        if self.printer.halted and not halted:
            self.protocol.hand_over()
            self._wake()
            if self.firmware.profile.halt.answers_all:
                self._halted_reading_on()
            return True
        return False

    def _wake(self) -> None:
        self._busy_changed.set()
        self._reports_changed.set()
        self._work.set()
        self._halt_changed.set()

    # -- halted ------------------------------------------------------------------------
    def _owes_answers(self) -> bool:
        """A command cut short or queued when the halt came, whose `ok` is still to go."""
        return self._interrupt is not None or self._waiting is not None or bool(self._backlog)

    def _halted_reading_on(self) -> None:
        """answers_all, as the emergency parser halts the printer: the wait it cuts short ends
        now; what was queued is answered first (the executor), then what came with M112."""
        if self._interrupt is not None:
            self._interrupt.cancel()
        if self._owes_answers():
            self._pending_answers = True
        else:
            self._feed_halted(b"")

    def _answer_queued(self) -> bool:
        """answers_all: the executor answers what was queued when the halt came, in order,
        then reads on what came since. False if nothing was owed."""
        if not (self._pending_answers or self._owes_answers()):
            return False
        if self._waiting is not None:
            run = self._waiting[2]
            self._waiting = None
            run.abandon()
            self._send_done(PLAIN_OK)
        while self._backlog and self.printer.halted:
            self._answer_halted(self._backlog.popleft())
        self._pending_answers = False
        if self.printer.halted:
            self._feed_halted(b"")
        return True

    def _feed_halted(self, data: bytes) -> None:
        """A halted firmware that still reads (Klipper, Smoothieware): each command gets its
        refusal and `ok`, but for those its profile says it still runs, or that end the halt."""
        self.protocol.receive_data(data)
        while not self._resetting and (event := self.protocol.next_event()) is not None:
            if isinstance(event, RealtimeCommand):
                self._realtime(event)
            elif isinstance(event, CommandReceived):
                self._answer_halted(event)
                if not self.printer.halted:  # M999: what follows runs as usual
                    rest = self.protocol.data_to_send()
                    self._send(rest)
                    self.feed(b"")
                    return
        self._send(self.protocol.data_to_send())

    def _reset(self, reason: str) -> None:
        """Ask the server to reset the board, once: the lines behind a FIRMWARE_RESTART in the
        same read get no `ok` from a boot that is ending."""
        if not self._resetting:
            self._resetting = True
            self._restart_board(reason)

    def _answer_halted(self, received: CommandReceived) -> None:
        halt = self.firmware.profile.halt
        command = parse(received.text)
        if command.code in halt.revive:
            self.journal.record(received.text)
            self._send_done(PLAIN_OK)
            self.announce((state("restarting"),))
            self._reset(command.code)
        elif command.code in halt.clear:
            self.printer.clear_halt()
            self._wake()
            self.announce((state("halt_cleared"),))
            self._run_here(received)  # it runs, as the first command of the running printer
        elif command.code in halt.still_runs:
            run = self._run(received.text, command)
            until = run.advance()
            if not self.printer.halted:  # it ended the halt itself (Smoothieware's $X, $H)
                self._wake()
                if until is not None:  # and waits, as any command of a running printer
                    self._executor_idle = False
                    self._waiting = (received, command, run, until)
                    return
            if until is None:  # (a command that would wait does not, halted)
                self._say_done(received, command, run.reply)
            else:
                run.abandon()
                self._send_done(PLAIN_OK)
        else:
            self.announce((state("halted_refusal", command=received.text,
                                 name=command.code or received.text.upper()),))
            self._send_done(PLAIN_OK if halt.refusal_ok else QUIET_OK)

    async def _when_halted(self) -> None:
        """A firmware whose watchdog resets it a while after a kill (Prusa's M112)."""
        delay = self.firmware.profile.halt.reboot_after
        while delay > 0:
            changed = self._halt_changed = trio.Event()
            if self.printer.halted:
                await trio.sleep(delay)
                self._reset(" Watchdog Reset")
                return
            await changed.wait()

    async def run(self) -> None:
        async with trio.open_nursery() as nursery:
            nursery.start_soon(self._when_halted)
            nursery.start_soon(self._execute_commands)
            nursery.start_soon(self._keep_host_alive)
            nursery.start_soon(self._send_auto_reports)
            nursery.start_soon(self._binary.run)

    # -- executing ---------------------------------------------------------------------
    # A command runs where it arrives (in feed) until it has to wait for time; then this task
    # carries it on, and the commands behind it wait in the backlog, in order.
    async def _execute_commands(self) -> None:
        sd = self.printer.sd
        while True:
            if (self.printer.halted and self.firmware.profile.halt.answers_all
                    and self._answer_queued()):
                continue
            if self.printer.halted:
                # Until M999 clears it, where the firmware has one; else until the reset.
                self._waiting = None
                self._backlog.clear()
                self._executor_idle = True
                changed = self._halt_changed = trio.Event()
                await changed.wait()
            elif self._waiting is not None:
                received, command, run, until = self._waiting
                self._waiting = None
                await self._carry_on(received, command, run, until)
            elif self._backlog:
                received = self._backlog.popleft()
                self._executor_idle = False
                self._run_here(received)
            elif sd.printing:
                self._executor_idle = False
                await self._run_from_sd()
            else:
                self._executor_idle = True
                work = self._work = trio.Event()
                await work.wait()

    async def _run_from_sd(self) -> None:
        line = self.printer.sd.next_line()
        if line is None:
            self.printer.sd.printing = False
            self.announce((state("done_printing_file"),))
            return
        command = parse(line)
        run = self._start(line, command)
        if run is not None:
            reply = await self._finish_waiting(command, run, run.advance())
            if self.printer.halted:
                self.announce(reply.lines)

    def _run_here(self, received: CommandReceived) -> None:
        """Run a command from the host now; if it must wait, hand it to the executor task."""
        sd = self.printer.sd
        if sd.saving is not None and not re.match(r"M29(?!\d)", received.text):
            sd.write_line(received.text)  # M28 stores lines instead of running them
            self._send_done(CommandDone(received.number, room=self._room()) if
                            self.protocol.rules.ok_while_saving else QUIET_OK)
            return
        # ADVANCED_OK's `ok` says the planner's room after the move: it waits for the planning.
        move = None if self.protocol.advanced_ok else plain_move(received.text)
        self._before_command(received.text)  # the faults that fire on a command
        if self.printer.halted:
            return
        if move is not None and self.printer.move_at_once(move, trio.current_time()):
            self._moved_at_once(received)
            return
        command = parse(received.text)
        run = self._run(received.text, command)
        until = run.advance()
        if until is None:
            self._done(received, command, run.reply)
        else:
            if command.code in self.protocol.rules.ok_before_run:  # Smoothieware's G1
                run.record()  # (the journal before the `ok`, as ever)
                if not self._drops_this_ok():  # (its slot stays taken until it is done)
                    self._say(self.protocol.rules.ok)
                self._ok_sent = received
            self._executor_idle = False
            self._waiting = (received, command, run, until)
            self._work.set()

    def _moved_at_once(self, received: CommandReceived) -> None:
        """A straight move the planner had room for completes at once and prints nothing: the
        journal has it, then its `ok` goes out (the model plans it later, as of the time it
        arrived: Printer.move_at_once)."""
        self.printer.sd.binary_mode = False  # as for every command (see _run)
        self.journal.record(received.text)
        if self._drop_ok_every:
            self._send_done(PLAIN_OK)
        else:
            self._send(self.protocol.send(PLAIN_OK))  # (plain: not ADVANCED_OK)
        self.protocol.saving_to_sd = self.printer.sd.saving is not None
        self.printer.catch_up()

    async def _carry_on(
        self, received: CommandReceived, command: Command, run: CommandRun, until: float
    ) -> None:
        reply = await self._finish_waiting(command, run, until)
        if self.printer.halted:
            self.announce(reply.lines)
            if self.firmware.profile.halt.answers_all:
                held = received is self._ok_sent  # (its `ok` went before it ran)
                self._ok_sent = None
                self._send_done(QUIET_OK if held else PLAIN_OK)  # a wait the halt ended: `ok`
            return
        self._done(received, command, reply)

    def _start(self, text: str, command: Command) -> CommandRun | None:
        """The run of a command from the card, or None if the faults that fire on it halted
        the printer (_run_here does the same for the host's commands)."""
        self._before_command(text)
        if self.printer.halted:
            return None
        return self._run(text, command)

    def _run(self, text: str, command: Command) -> CommandRun:
        # Set by this command alone (M28 B1) and read when it is done: one from the card, which
        # never reaches _done, must not turn the host's next M28 into the binary switch.
        self.printer.sd.binary_mode = False
        self._reports = self._report_settings()
        return CommandRun(self.printer, text, self.journal, self._report, command)

    async def _finish_waiting(self, command: Command, run: CommandRun, until: float | None) -> Reply:
        self._set_busy(until is not None and (command.code not in SELF_REPORTING
                                              or self.firmware.profile.busy.while_heating))
        try:
            if not self.firmware.profile.halt.answers_all:
                return await finish(run, until)
            with trio.CancelScope() as self._interrupt:  # cancelled by a halt: cut short
                return await finish(run, until)
            run.abandon()
            return run.reply
        finally:
            self._interrupt = None
            self._set_busy(False)

    def _done(self, received: CommandReceived, command: Command, reply: Reply) -> None:
        if self.printer.halted and reply.effect != "halted":
            self.announce(reply.lines)
            self._send(self.protocol.send(QUIET_OK))  # its slot is free for what is read next
            self._wake()
            return
        if reply.effect == "reset":  # RepRapFirmware's M999: the board resets, no `ok`
            self.announce(reply.lines)
            self._reset(command.code)
            return
        self._protocol_effects(command)
        self._say_done(received, command, reply)
        if reply.effect == "halted":  # it halted the printer, and had its `ok` (RRF's M112)
            self._wake()
            if self.firmware.profile.halt.reads and not self._backlog:
                self._feed_halted(b"")  # what came after it is read as a halted printer reads
            return
        if reply.effect == "restart":  # FIRMWARE_RESTART, RESTART: its `ok` is out
            self.announce((state("restarting"),))
            self._reset(command.code)
            return
        self.protocol.saving_to_sd = self.printer.sd.saving is not None
        if self._report_settings() != self._reports:
            self._reports_changed.set()  # M155, M154, M27 S, or SD printing started
            self._work.set()  # M24: the executor prints from the card

    def _say_done(self, received: CommandReceived, command: Command, reply: Reply) -> None:
        """What the command printed and its `ok`, in the order and form the firmware has."""
        answer = "" if reply.answer is None else self._words.one_line(reply.answer)
        done = CommandDone(received.number, self._room(), ok_suffix=answer)
        quirks = self.firmware.quirks
        if quirks.broken_m29 and command.code == "M29":
            done = QUIET_OK  # `Done saving file.` and no `ok`
        held = received is self._ok_sent  # its `ok` went before it ran, its slot held since
        if reply.effect == "no_ok" or held:
            done = QUIET_OK  # (no_ok: a console command, Smoothieware's)
            self._ok_sent = None
        if quirks.ok_before_output or reply.effect == "ok_first":  # (RRF's M28)
            self._send_done(done)
            self.announce(reply.lines)
        else:
            self.announce(reply.lines)
            self._send_done(done)
        if self.protocol.unread:  # what came while the queue was full is read now
            self.feed(b"")

    def _send_done(self, done: CommandDone) -> None:
        """A command's `ok`, unless the quirk that drops every Nth drops this one."""
        if not done.quiet and self._drops_this_ok():
            done = QUIET_OK
        self._send(self.protocol.send(done))

    def _drops_this_ok(self) -> bool:
        """Whether the quirk that drops every Nth `ok` drops the one about to go."""
        if not self._drop_ok_every:
            return False
        self._oks += 1
        return self._oks % self._drop_ok_every == 0

    def quirks_changed(self, quirks: Quirks) -> None:
        """The firmware's quirks changed (the control channel): from the next line on."""
        if self.firmware.quirks is not quirks:
            self.firmware.switch(quirks)  # (the firmware of another protocol's words)
        self._words = self.firmware.words
        self.protocol.rules = self.firmware.line_rules()
        self._drop_ok_every = self.firmware.quirks.drop_ok_every
        if self.firmware.quirks.busy_interval is not None:
            self.busy_interval = self.firmware.quirks.busy_interval
            self._busy_changed.set()

    def _report_settings(self) -> tuple[object, ...]:
        reports = self.printer.auto_reports
        sd = self.printer.sd
        return (reports.temperature, reports.position, reports.sd_status, sd.selected, sd.printing)

    def _protocol_effects(self, command: Command) -> None:
        """M110, M113, M999 and M28 B1 act on the protocol, not on the printer."""
        if (command.code == "M110" and (number := command.value("N")) is not None
                and not self.protocol.rules.m110_takes_line_number):
            self.protocol.last_n = int(number)
        elif command.code == "M113" and self.firmware.profile.busy.adjustable:
            if command.has("S"):
                self.busy_interval = max(0.0, min(60.0, command.value("S", 0.0)))
            else:
                self.announce((state("keepalive_interval", seconds=self.busy_interval),))
        elif command.code == "M999" and "M999" in self.printer.handlers:  # (Klipper has none)
            self._say(self.protocol.rules.resend.format(line=self.protocol.last_n + 1))
            if self.protocol.rules.m999_ok:  # (Marlin 1.x: the resend's own, then M999's)
                self._say(self.protocol.rules.ok)
        elif command.code == "M28" and self.printer.sd.binary_mode:
            self.printer.sd.binary_mode = False
            self._binary.enter(self.protocol.hand_over())  # read once its `ok` is out

    def _room(self) -> int:
        if not self.protocol.advanced_ok:
            return 0  # only ADVANCED_OK's `ok` says it
        return self.printer.room(trio.current_time())

    # -- what the printer says on its own ----------------------------------------------
    def _set_busy(self, busy: bool) -> None:
        if busy != self._busy:
            self._busy = busy
            self._busy_changed.set()

    async def _keep_host_alive(self) -> None:
        """`echo:busy: processing` once a command has held the queue for the interval, then at
        each interval, as host_keepalive() does: its next signal moves on while not busy, so a
        command that waits less (a move for planner room) says nothing."""
        next_signal = -math.inf
        while True:
            changed = self._busy_changed = trio.Event()
            deadline = math.inf
            now = trio.current_time()
            if self._busy and self.busy_interval > 0 and not self.printer.halted:
                if now >= next_signal:
                    paused = self.printer.host_prompt.paused_for_user  # M0, M600's waits
                    self.announce((state("busy_paused_for_user" if paused else "busy_processing"),))
                    next_signal = now + self.busy_interval
                deadline = next_signal
            else:
                next_signal = now + self.busy_interval
            with trio.move_on_at(deadline):
                await changed.wait()

    async def _send_auto_reports(self) -> None:
        """M155 temperatures, M154 positions and M27 S SD status, each at its interval."""
        last = {"temperature": -math.inf, "position": -math.inf, "sd_status": -math.inf}
        while True:
            changed = self._reports_changed = trio.Event()
            now = trio.current_time()
            deadline = math.inf
            if not self.printer.halted:
                for kind in last:
                    interval = getattr(self.printer.auto_reports, kind)
                    if interval <= 0:
                        continue
                    if now >= last[kind] + interval:
                        self._auto_report(kind, now)
                        last[kind] = now
                    deadline = min(deadline, last[kind] + interval)
            with trio.move_on_at(deadline):
                await changed.wait()

    def _auto_report(self, kind: str, now: float) -> None:
        if kind == "temperature":
            self.announce((self.printer.temperature_report(now, "auto_temperatures"),))
        elif kind == "position":
            self.announce((self.printer.position_report(now, "auto_position"),))
        else:  # CardReader::report_status(), file or none: `Not SD printing` while idle
            self.announce((self.printer.sd.status(),))
