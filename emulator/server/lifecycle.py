"""The printer's life on a link: power on, boot, and reboot whenever a host opens the port."""

import dataclasses
import functools
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import trio

from fake_marlin.emulator.faults.layer import FaultConfig, FaultLayer, Segment
from fake_marlin.emulator.firmware import Firmware, Quirks
from fake_marlin.emulator.faults.rules import LINK_KINDS, FaultKind, FaultRule, printer_failure
from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.link.base import HostOpened, Link
from fake_marlin.emulator.link.conditions import LinkConditions, Pipe
from fake_marlin.emulator.printer import failures
from fake_marlin.emulator.printer.model import Printer, handlers_for
from fake_marlin.emulator.printer.statements import Statement, state
from fake_marlin.emulator.protocols.avr_memory import BoardMemory
from fake_marlin.emulator.sessions.base import Session
from fake_marlin.emulator.sessions.commstack import CommStackSession
from fake_marlin.emulator.sessions.detect import Detected, DetectingSession
from fake_marlin.emulator.printer.g2core import Build
from fake_marlin.emulator.sessions.g2core import G2coreSession
from fake_marlin.emulator.sessions.marlin import MarlinSession
from fake_marlin.emulator.sessions.repetier import RepetierSession
from fake_marlin.emulator.sessions.stk500 import Stk500Session
from fake_marlin.emulator.sessions.ultimaker import UltimakerSession
from fake_marlin.emulator.trace.tap import PrinterSampler, TracedJournal, watch_rejects
from fake_marlin.emulator.trace.writer import Trace, reject_facts
from fake_marlin.wire.ultimaker_variants import PLAIN, Variants

SEVEN_BITS = bytes(byte & 0x7F for byte in range(256))  # what a 7-bit UART reads of a byte
PROTOCOLS = ("auto", "marlin", "ultimaker", "repetier", "commstack", "g2core")
# The protocol machines' one method each that refuses what the host sent (Marlin's, Repetier's,
# Ultimaker's): wrapped per session to count refusals, so the common path pays nothing.
REFUSALS = ("_line_error", "_request_resend", "_reject")
# Faults of the line, not of the printer: the live view counts them, but what it shows as an
# error is what the host then sees (a refusal), or a printer's own fault.
LINK_FAULTS_NOT_ERRORS = frozenset(
    {kind.value for kind in LINK_KINDS} | {"bit-errors", "drop-bytes", "corrupt-lines"})
EVENTS_KEPT = 200  # the live view's marks: resends, faults, resets, connects (the latest)
WIRE_CHUNKS = 1000  # reads and writes a watched printer keeps for the live view's wire tail
SAMPLES_KEPT = 900  # the live view's samples of a watched printer (about 15 minutes' worth)


class CountedJournal(Journal):
    """The journal, counting what it records (the live view's commands executed): one more
    call and an add per command, the only cost the live view puts on every printer."""

    def __init__(self, journal: Journal) -> None:
        super().__init__(None)
        self._record = journal.record
        self._journal = journal
        self.count = 0
        self.last = ""  # the last command executed

    def record(self, command: str) -> None:
        self.count += 1
        self.last = command
        self._record(command)

    def close(self) -> None:
        self._journal.close()


class Seen:
    """What the live view reads of a printer that happens rarely, noted as it happens. One
    slotted object: more attributes on the server itself would cost every printer 1.5 KB (past
    30 names an instance stops sharing its dictionary's keys)."""

    __slots__ = ("connects", "events", "faults_fired", "last_error", "powered_on", "refusals")

    def __init__(self) -> None:
        self.connects = 0
        self.refusals = 0  # the host's units refused (a resend or a retransmission asked)
        self.faults_fired: dict[str, int] = {}
        self.last_error: tuple[float, str, str] | None = None  # time, what, its kind of event
        self.events: list[tuple[float, str, str]] = []  # the latest EVENTS_KEPT (a list: a
        # deque's first block alone would cost every printer 600 bytes)
        self.powered_on = 0.0  # trio's time when the server's run() began


class Watch:
    """What the live view (emulator/web) records of a printer while someone watches its page:
    each read and write as it crosses the wire (time, "in" or "out", bytes), appended by the
    server, and the view's own samples of the printer (emulator/web/snapshot.py)."""

    def __init__(self) -> None:
        self.since = trio.current_time()
        self.until = self.since  # the lease: recording stops once trio's clock passes it
        self.wire: deque[tuple[float, str, bytes]] = deque(maxlen=WIRE_CHUNKS)
        self.samples: deque[dict[str, Any]] = deque(maxlen=SAMPLES_KEPT)
        self.deliver: Callable[[bytes], None] = lambda data: None  # the server's, unwatched


@dataclass(frozen=True)
class ServerConfig:
    protocol: str = "auto"
    boot_delay: float = 0.0  # simulated seconds a reset takes before the printer answers
    ultimaker_queue_size: int = 8
    advanced_ok: bool = False
    faults: FaultConfig = FaultConfig()
    conditions: LinkConditions = LinkConditions()
    baud_from_host: bool = False  # pace at the baud rate the host set on the port
    # The protocol lab's variants of Ultimaker's protocol (wire/ultimaker_variants.py); only
    # with protocol "ultimaker": auto-detection never guesses one.
    variants: Variants = PLAIN

    def __post_init__(self) -> None:
        if not self.variants.plain and self.protocol != "ultimaker":
            raise ValueError(f"protocol variants ({self.variants}) are Ultimaker's: they need "
                             f"protocol ultimaker, not {self.protocol}")


class PrinterServer:
    def __init__(
        self, link: Link, printer: Printer, journal: Journal, config: ServerConfig,
        memory: BoardMemory | None = None, flash_changed: Callable[[], None] | None = None,
        trace: Trace | None = None, firmware: Firmware | None = None,
    ) -> None:
        self.link = link
        # Without a firmware of its own: Marlin's, saying the capabilities the model has.
        self.firmware = firmware or dataclasses.replace(
            Firmware.make(), capabilities=printer.config.capabilities)
        # A link that can wait for the host's bytes without trio (PtyLink.receive_now): None
        # from it, or a link without it, means awaiting receive().
        self._receive_now: Callable[[], bytes | None] = getattr(link, "receive_now",
                                                                lambda: None)
        self.printer = printer
        # The board's flash and EEPROM outlive every reset, as the printer does; the bootloader
        # calls flash_changed (--flash-file's save) when it has written flash.
        self._memory = memory
        self._flash_changed = flash_changed or (lambda: None)
        self.journal = journal
        self.config = config
        self.boots = 0
        self.faults = FaultLayer(config.faults)
        # Traced, the bytes each way are told to the trace as they cross (after faults); not,
        # they go straight on, and the trace costs nothing.
        self.trace = trace
        self._sampler: PrinterSampler | None = None
        self._deliver: Callable[[bytes], None] = link.send
        if trace is not None:
            self._sampler = PrinterSampler(trace, printer)
            self.journal = TracedJournal(journal, trace, self._sampler)
            self._deliver = self._traced_deliver
        self.faults.on_fault = self._fault_fired  # called only as a fault fires
        # What the live view reads (emulator/web/snapshot.py), kept where it costs nothing on
        # the way to an `ok`: counted commands, and what happens rarely (refusals, faults,
        # resets, connections) as it happens.
        self.journal = self._counted = CountedJournal(self.journal)
        self.seen = Seen()
        # Recording the wire, only while the live view's page of this printer is open.
        self.watching: Watch | None = None
        # A 7-bit line (the 7bit variant): 9 bit times a character, and the printer's UART
        # keeps 7 bits of each.
        conditions = dataclasses.replace(config.conditions, data_bits=config.variants.data_bits)
        self._seven_bit = config.variants.data_bits == 7
        self._to_printer = Pipe(self._feed_session, conditions, config.faults.seed)
        self._to_host = Pipe(self._deliver_later, conditions, config.faults.seed + 1)
        self._restarts_in, self._restarts = trio.open_memory_channel[str](16)
        self._restart_pending = False  # a reset asked for that has not begun
        self._nursery: trio.Nursery | None = None
        self._session: Session | DetectingSession | None = None
        self._session_scope = trio.CancelScope()

    # -- what the live view reads and switches (emulator/web) --------------------------------
    @property
    def commands(self) -> int:
        """Commands executed since power-on (what the journal recorded)."""
        return self._counted.count

    @property
    def last_command(self) -> str:
        return self._counted.last

    @property
    def booted(self) -> bool:
        """False while the board resets (boot_delay), before its session answers."""
        return self._session is not None

    @property
    def host_connected(self) -> bool:
        """Whether a host has the port. A TCP link knows (it holds the host's socket); a pty
        cannot tell a port still open from one closed after use, so there: opened since
        power-on, and the line up."""
        if not getattr(self.link, "connected", True):
            return False
        has_host = getattr(self.link, "has_host", None)  # TcpLink's and Rfc2217Link's
        return self.seen.connects > 0 if has_host is None else bool(has_host)

    @property
    def speaking(self) -> str | None:
        """The protocol spoken now: protocol_name's, g2core, or stk500 (the bootloader); None
        while the board boots or the detector waits for the host's first bytes."""
        session = self._active_session()
        if isinstance(session, G2coreSession):
            return "g2core"
        if isinstance(session, Stk500Session):
            return "stk500"
        return self.protocol_name

    def watch(self, seconds: float) -> Watch:
        """Record the wire for the live view for `seconds` more of trio's time (its page asks
        again while open). Recording starts here and stops by itself once the lease runs out;
        while it runs, each read and write costs one deque append."""
        now = trio.current_time()
        watch = self.watching
        if watch is None:
            watch = Watch()
            self._tasks.start_soon(self._unwatch, watch)
            self.watching = watch
            watch.deliver = self._deliver
            self._deliver = self._watched_deliver
        watch.until = max(watch.until, now + seconds)
        return watch

    async def _unwatch(self, watch: Watch) -> None:
        try:
            while trio.current_time() < watch.until:
                await trio.sleep_until(watch.until)
        finally:
            self.watching = None
            self._deliver = watch.deliver

    def _watched_deliver(self, data: bytes) -> None:
        watch = self.watching
        if watch is not None:
            watch.deliver(data)
            if data:
                watch.wire.append((trio.current_time(), "out", data))

    def _deliver_later(self, data: bytes) -> None:
        """The pipe's way to the link: whatever delivers now (plain, traced or watched)."""
        self._deliver(data)

    def _event(self, kind: str, label: str, error: bool = False) -> None:
        now = trio.current_time()
        events = self.seen.events
        if len(events) >= EVENTS_KEPT:
            del events[0]
        events.append((now, kind, label))
        if error:
            self.seen.last_error = (now, label, kind)

    def _fault_fired(self, kind: str, direction: str | None, count: int | None = None,
                     unit: bytes | None = None) -> None:
        fired = self.seen.faults_fired
        fired[kind] = fired.get(kind, 0) + (count or 1)
        self._event("fault", kind if direction is None else f"{kind} {direction}",
                    error=kind not in LINK_FAULTS_NOT_ERRORS)
        if self.trace is not None:
            self.trace.fault(kind, direction, count, unit)

    def _count_refusals(self, session: Session) -> None:
        protocol = getattr(session, "protocol", None)
        for name in REFUSALS:
            refuse = getattr(protocol, name, None)
            if refuse is not None:
                setattr(protocol, name, functools.partial(self._refused, refuse))
                return

    def _refused(self, refuse: Callable[..., object], *args: object, **named: object) -> object:
        """A protocol machine's refusal (REFUSALS), counted: only ever on the way to a resend."""
        event = refuse(*args, **named)
        self.seen.refusals += 1
        facts = reject_facts(event)
        if facts is not None:
            reason, number = facts
            self._event("resend", f"refused ({reason})" if number is None
                        else f"refused ({reason}), resend {number}", error=True)
        return event

    @property
    def memory(self) -> BoardMemory:
        """Made when the bootloader first needs it: 260 KB that a farm's printers mostly never
        touch (200 of them would hold 52 MB of erased flash)."""
        if self._memory is None:
            self._memory = BoardMemory()
        return self._memory

    @property
    def _tasks(self) -> trio.Nursery:
        """Where the server starts its tasks, while it runs."""
        if self._nursery is None:
            raise RuntimeError("the printer server is not running")
        return self._nursery

    async def run(self, task_status=trio.TASK_STATUS_IGNORED) -> None:
        """Power on, then serve; started (for nursery.start) once the power-on greeting is out,
        so a host that opens the port as soon as it hears of it sees one boot, not two."""
        self.seen.powered_on = trio.current_time()
        async with trio.open_nursery() as nursery:
            self._nursery = nursery
            if self.trace is not None:
                self.trace.begin()
            nursery.start_soon(self.link.run_writer)
            nursery.start_soon(self._to_printer.run)
            nursery.start_soon(self._to_host.run)
            await nursery.start(self._boot)
            await self.link.drain()
            task_status.started()
            nursery.start_soon(self._receive)
            nursery.start_soon(self._fire_timed_faults, trio.current_time())
            async for reason in self._restarts:
                await self._restart(reason)

    def _request_restart(self, reason: str) -> None:
        """Reset the board soon (a session's FIRMWARE_RESTART, a reboot fault): one at a time,
        since a reset already coming ends whatever would ask for another."""
        if not self._restart_pending:
            self._restart_pending = True
            self._restarts_in.send_nowait(reason)

    async def _restart(self, reason: str) -> None:
        self._restart_pending = False
        self._session_scope.cancel()
        await self._tasks.start(self._boot, reason)

    async def _receive(self) -> None:
        while True:
            item = await self.link.receive()
            if isinstance(item, HostOpened):
                self._new_connection()
                if self.firmware.profile.reset_on_open:
                    # The host's open resets the board, as DTR does on a real one; what the
                    # host sends next is read by the new boot.
                    await self._restart(" External Reset")
                else:  # native USB, Klipper's pty: the firmware runs on
                    self.announce((state("connected"),))
            elif self.faults.quiet_to_printer and self._to_printer.passes_through:
                self._feed_session(item)  # the common case: straight to the session
                # ...and while trio has nothing else due, the host's next bytes too, read here
                # without a round through receive()'s awaits.
                while (self.faults.quiet_to_printer and self._to_printer.passes_through
                       and (data := self._receive_now()) is not None):
                    self._feed_session(data)
            elif self.faults.quiet_to_printer:
                self._to_printer.put(item)
            else:
                self._carry(self.faults.to_printer(item), self._to_printer)

    async def _boot(self, reason: str = "PowerUp", task_status=trio.TASK_STATUS_IGNORED) -> None:
        self._session = None
        with trio.CancelScope() as scope:
            self._session_scope = scope
            task_status.started()
            now = trio.current_time()
            if self.trace is not None:
                self.trace.reset(reason)
            self.printer.reset(now)
            self._event("reset", reason.strip())
            if self.config.boot_delay > 0:
                await trio.sleep(self.config.boot_delay)
            session = self._make_session(self.config.protocol, reason)
            self.boots += 1
            session.boot()
            self._session = session
            await session.run()

    def _make_session(self, protocol: str, reason: str) -> Session | DetectingSession:
        profile = self.firmware.profile
        if protocol == "auto" and len(profile.protocols) == 1 and not profile.bootloader:
            protocol = profile.protocols[0]  # nothing to tell apart: it speaks at once
        if protocol == "auto":
            return self._detecting_session(reason, profile.bootloader)
        return self._protocol_session(protocol, reason)

    def _detecting_session(self, reason: str, bootloader: bool = True,
                           only: tuple[str, ...] | None = None) -> DetectingSession:
        self.faults.set_protocol(None)  # until detection decides, no framer of its own
        protocols = frozenset(Detected(name) for name in only or self.firmware.profile.protocols)
        return DetectingSession(
            lambda detected: self._protocol_session(detected.value, reason), bootloader=bootloader,
            protocols=protocols,
        )

    def _protocol_session(self, protocol: str, reason: str) -> Session:
        session = self._new_protocol_session(protocol, reason)
        if self.trace is not None:
            watch_rejects(session, self.trace)
        self._count_refusals(session)
        return session

    def _new_protocol_session(self, protocol: str, reason: str) -> Session:
        # Unit faults act on this protocol's units from now on, both ways.
        self.faults.set_protocol(
            protocol, self.config.variants if protocol == "ultimaker" else PLAIN)
        if protocol == "stk500":
            # LEAVE starts the firmware, whose protocol the bytes after it choose (on a g2core
            # board, Marlin's: a host that probed the bootloader is a Marlin host).
            only = ("marlin",) if "g2core" in self.firmware.profile.protocols else None
            return Stk500Session(
                self._send, lambda: self._detecting_session(reason, bootloader=False, only=only),
                self.memory, self._flash_changed,
            )
        firmware = self.firmware.speaking(protocol)
        if protocol == "marlin":
            return self._marlin_session(reason, firmware)
        if protocol == "ultimaker":
            return UltimakerSession(
                self.printer, self.journal, self._send, self.config.ultimaker_queue_size,
                self._before_command, firmware, self.config.variants,
            )
        if protocol == "repetier":
            return RepetierSession(
                self.printer, self.journal, self._send, reason, self._before_command, firmware
            )
        if protocol == "g2core":
            digits = firmware.identity.uuid.replace("-", "")[:16]
            # The board's `id` (Motate's unique id, xxxx-xxxx-xxxx-xxxx): the printer's own,
            # which its Marlin side says as M115's UUID.
            board_id = "-".join(digits[at:at + 4] for at in range(0, 16, 4))
            marlin = self.firmware.speaking("marlin").with_uuid(board_id)
            return G2coreSession(
                self.printer, self.journal, self._send, self._before_command, firmware,
                self._request_restart, build=Build(id=board_id),
                marlin=lambda: self._marlin_session(reason, marlin),
            )
        if protocol == "commstack":
            return CommStackSession(self.printer, self.journal, self._send, self._before_command,
                                    firmware)
        raise ValueError(f"unknown protocol {protocol!r}")

    def _marlin_session(self, reason: str, firmware: Firmware) -> MarlinSession:
        return MarlinSession(
            self.printer, self.journal, self._send, self.config.advanced_ok, reason,
            self._before_command, firmware, self._request_restart,
        )

    def _send(self, data: bytes) -> None:
        if not data:
            return
        if self.faults.quiet_to_host and self._to_host.passes_through:
            self._deliver(data)  # the common case: straight to the link
        elif self.faults.quiet_to_host:
            self._to_host.put(data)
        else:
            self._carry(self.faults.to_host(data), self._to_host)

    def _carry(self, segments: list[Segment], pipe: Pipe) -> None:
        for segment in segments:
            pipe.put(segment.data, segment.pause)
            if segment.hang_up is not None:
                self._tasks.start_soon(self._hang_up, segment.hang_up)

    async def _hang_up(self, seconds: float) -> None:
        """The line is dead for `seconds`; the printer itself runs on, talking to nobody."""
        if self.trace is not None:
            self.trace.disconnect(seconds)
        self._event("disconnect", f"the line is dead for {seconds:g} s")
        self.link.hang_up()
        self._forget_the_line()
        await trio.sleep(seconds)
        self.link.reconnect()

    def _feed_session(self, data: bytes) -> None:
        if self.watching is not None and data:  # the live view's printer page is open
            self.watching.wire.append((trio.current_time(), "in", data))
        # Bytes that arrive while the printer is still booting are lost, as on a real board.
        if self._session is not None and data:
            if self._seven_bit:
                data = data.translate(SEVEN_BITS)
            if self._sampler is not None:
                self._sampler.trace.bytes_in(data)
                self._sampler.reading = True
                try:
                    self._session.feed(data)
                finally:
                    self._sampler.reading = False
                self._sampler.look()
                self._sampler.trace.write_queued()  # the answer is out: the host is busy
                return
            self._session.feed(data)

    def _traced_deliver(self, data: bytes) -> None:
        self.link.send(data)
        if self._sampler is not None and data:
            self._sampler.trace.bytes_out(data)
            self._sampler.look()
            if not self._sampler.reading:  # said on its own: write it now it has gone
                self._sampler.trace.write_queued()

    def _new_connection(self) -> None:
        if self.trace is not None:
            self.trace.connect()
        self.seen.connects += 1
        self._event("connect", "a host opened the port")
        self.link.discard_output()
        self._forget_the_line()
        if self.config.baud_from_host:
            baud = self.link.host_baud()
            self._to_printer.baud = self._to_host.baud = baud

    def _forget_the_line(self) -> None:
        """Bytes on the wire and half-read units belong to a connection that is gone."""
        self._to_printer.clear()
        self._to_host.clear()
        self.faults.new_connection()

    # -- faults that fire on a command or at a moment ------------------------------------
    def _before_command(self, text: str) -> None:
        plan = self.faults.plan
        if not plan.rules:
            return  # the usual printer: nothing to look for on its way to the `ok`
        for index, rule in plan.printer_rules():
            if plan.fires(index, text):
                self._printer_fault(rule)

    def _printer_fault(self, rule: FaultRule) -> None:
        self._fault_fired(rule.kind.value, None)
        session = self._active_session()
        if rule.kind is FaultKind.REBOOT:
            self._request_restart(" Watchdog Reset")
        elif rule.kind is FaultKind.QUEUE_FULL:
            if session is not None:
                session.block_queue(rule.seconds, self._tasks)
        else:
            lines = failures.apply(self.printer, printer_failure(rule), trio.current_time())
            if session is not None:
                session.announce(lines)

    def fire_printer_fault(self, rule: FaultRule) -> None:
        """A printer fault now, from outside (the control channel)."""
        self._printer_fault(rule)

    def announce(self, lines: Iterable[Statement | str]) -> None:
        """What the printer says now: statements in its firmware's words, text as it is."""
        session = self._active_session()
        if session is not None:
            session.announce([line if isinstance(line, Statement) else
                              Statement("verbatim", {"text": line}) for line in lines])

    def set_quirks(self, quirks: Quirks) -> None:
        """Switch the firmware's quirks (the control channel): the session on now takes them
        from its next line, a new boot from its start."""
        self.firmware.switch(quirks)
        printer = self.printer
        printer.config = self.firmware.configure(printer.config)
        printer.handlers = handlers_for(printer.config)
        if printer.config.password_feature and printer.password != quirks.password:
            printer.password = quirks.password
        if quirks.locked and printer.config.password_feature:
            printer.locked = True
        elif not printer.config.password_feature:
            printer.locked = False  # no M511 left to unlock it with
        session = self._active_session()
        changed = getattr(session, "quirks_changed", None)
        if changed is not None:
            changed(quirks)

    @property
    def protocol_name(self) -> str | None:
        session = self._active_session()
        if isinstance(session, MarlinSession):
            return "marlin"
        if isinstance(session, UltimakerSession):
            return "ultimaker"
        if isinstance(session, RepetierSession):
            return "repetier"
        if isinstance(session, CommStackSession):
            return "commstack"
        return None

    def _active_session(self) -> Session | None:
        session = self._session
        return session.active if isinstance(session, DetectingSession) else session

    async def _fire_timed_faults(self, powered_on: float) -> None:
        for at, index, rule in self.faults.plan.timed_rules():
            await trio.sleep_until(powered_on + at)
            if rule.kind not in LINK_KINDS:
                self._printer_fault(rule)
                continue
            self._fault_fired(rule.kind.value, rule.direction)
            if rule.kind is FaultKind.GARBAGE:
                noise = self.faults.plan.garbage(index)
                if rule.direction == "to-printer":
                    self._to_printer.put(noise)
                else:
                    self._to_host.put(noise)
            elif rule.kind is FaultKind.STALL:
                pipe = self._to_printer if rule.direction == "to-printer" else self._to_host
                pipe.put(b"", rule.seconds)
            elif rule.kind is FaultKind.DISCONNECT:
                self._tasks.start_soon(self._hang_up, rule.seconds)
