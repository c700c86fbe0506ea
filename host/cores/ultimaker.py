"""Go-back-N sending over Ultimaker sequence numbers, as a sans-IO state machine.

The printer checks every sequence number and never executes a packet twice, so nothing here can
make a command run twice; these rules only decide how fast a loss is repaired:
- `o` NN: packet NN was executed, and so was every packet before it (execution is in order).
- `r` NN: the printer expects NN next. Packets before NN reached it (their `o` is still to come);
  NN and after are sent again. One bad packet makes the printer answer `r` NN for each packet
  behind it too, so those echoes of an error already handled are ignored.
- `r` NN far outside the window before any answer: the printer counted from somewhere else
  before we connected, so the packets are renumbered from NN. After the first answer the same
  means the printer was reset; renumbering then could run a command twice, so it is an error.
- When the printer has been silent for `timeout` since a packet was sent, the packet is sent
  again with all after it. Silence is expected while the printer executes a long command
  (G28, M400, M109...), so then the wait is `long_timeout`: generous, because M400 behind a
  full planner of slow moves, or heating, takes minutes. It rarely costs anything: a packet
  lost behind a long command is still caught at once by the `r` its successor draws.
- A full planner is silent only until a move ends, and the room last heard may be stale (the
  `o` or `q` that said otherwise was damaged), so it is probed after three moves' time (at
  least three `received_timeout`), and given up on only after `long_timeout` of silence.
- A packet known to have arrived whose `o` never comes (lost on the way back) counts as done
  after `received_timeout` of silence.

With the ack variant (the protocol lab's, docs/protocols.md section 1.1) an `a` NN says packet
NN is in the printer's queue: it and those before it are RECEIVED at once, and a packet sent
gets only a round trip's time (measured, as TCP measures it) to draw its `a` or an `r`,
however busy the printer is: a lost packet is sent again after milliseconds, not seconds.
The other variants change only the bytes (host.codecs.ultimaker). The printer names its
variants at boot; a host that speaks others stops at once (VariantMismatch).

The core reads the printer's frames and lines itself (host.codecs.ultimaker): an `o`'s response
is the data lines before it; `q` and `LOG:` lines are the printer's greeting; an `Error:` that
says the firmware halted ends the session once the line has been shown.
"""

import math
from dataclasses import dataclass, field
from enum import Enum, auto

from fake_marlin.host.codecs import marlin
from fake_marlin.host.codecs.ultimaker import (
    Ack,
    CorruptFrame,
    FrameParser,
    Line,
    LineKind,
    Received,
    Reject,
    RoomInfo,
    encode_command,
)
from fake_marlin.host.cores.queue import CommandQueue, Ticket, is_long_command
from fake_marlin.host.errors import (
    PrinterHalted, PrinterNotResponding, PrinterReset, VariantMismatch,
)
from fake_marlin.wire.ultimaker_variants import BOOT_LINE, PLAIN, Variants, announced

PROBE_MOVES = 3  # a full planner is probed after this many moves' time (or received_timeouts)
# The ack variant's resend timer (RFC 6298's estimator): never below this, however fast the line.
ACK_TIMEOUT_MIN = 0.01
ACKLESS_ACKS = 10  # `o` frames with never an `a` before an ack host says the printer has none
ACK_BACKOFF_MAX = 64  # the ack timer doubles on each expiry (RFC 6298 5.5), up to this


class PacketState(Enum):
    SENT = auto()  # on its way or waiting in the printer, no answer yet
    RECEIVED = auto()  # an `r` frame showed the printer has it; its `o` is still to come


@dataclass(eq=False)
class _Packet:
    ticket: Ticket
    seq: int
    state: PacketState = PacketState.SENT
    since: float = 0.0  # when it was last sent, or found to have arrived
    sent_at: float = 0.0  # when it was last sent
    transmissions: int = 0
    needs_transmit: bool = True


@dataclass(frozen=True)
class Transmit:
    seq: int
    text: str
    resend: bool


@dataclass
class UltimakerStats:
    packets_sent: int = 0
    resends: int = 0
    timeouts: int = 0
    rejects: int = 0
    unconfirmed: int = 0


@dataclass
class UltimakerCore(CommandQueue):
    window: int = 3
    timeout: float = 2.0
    long_timeout: float = 300.0
    received_timeout: float = 10.0
    max_transmissions: int = 8
    first_seq: int = 0
    variants: Variants = PLAIN
    stats: UltimakerStats = field(default_factory=UltimakerStats)

    def __post_init__(self) -> None:
        if not 1 <= self.window <= 32:
            raise ValueError("window must be 1 to 32 packets")
        self._open_queue()
        self._packet_format = self.variants.packet
        self._in_flight: list[_Packet] = []
        self._next_seq = self.first_seq
        self._echo_seq: int | None = None  # the `r` NN whose echoes we expect
        self._echoes_left = 0
        self._synchronised = False  # has the printer answered with a sequence number of ours?
        self._refusals = 0  # rejects of the same packet in a row, with no progress between
        self._refused_seq: int | None = None
        self._hold_until = -math.inf  # no (re)transmission before this
        self._last_heard = -math.inf
        self._printer_room: int | None = None
        self._last_ack_at: float | None = None
        self._ack_interval = 0.0  # between the last two `o` frames: how long a move takes
        # The quickest `o` yet to a packet sent once: what no answer to a copy can beat. And until when each copy still on its way may draw an `r`.
        self._least_round_trip: float | None = None
        self._strays: list[float] = []
        # The ack variant's round-trip estimate: smoothed, and its variation (None: no sample).
        self._round_trip: float | None = None
        self._round_trip_variation = 0.0
        self._received_frames = 0  # `a` frames heard
        self._boot_heard = False  # a whole boot line, naming what the printer speaks
        self._acks_without_received = 0
        # Reading the printer (receive_data, next_event).
        self._parser = FrameParser(self.variants)
        self._backoff = 1  # the ack timer's multiplier: doubled by each expiry
        self._received_at = -math.inf
        self._response: list[str] = []  # data lines since the last `o`
        self._halted: str | None = None  # why the session ends, once the line is shown
        self.room: int | None = None
        self.greeted = False
        self.corrupt_frames = 0

    # -- what the caller asks -----------------------------------------------------------
    @property
    def idle(self) -> bool:
        return not self._backlog and not self._in_flight

    def next_deadline(self) -> float | None:
        deadlines = [self._due(packet) for packet in self._timed_packets()]
        waiting = any(packet.needs_transmit for packet in self._in_flight) or (
            self._backlog and len(self._in_flight) < self.window
        )
        if waiting:
            deadlines.append(self._hold_until)  # held back: send when the hold ends
        deadline = min(deadlines, default=None)
        return None if deadline is None or deadline == -math.inf else deadline

    def _timed_packets(self) -> list["_Packet"]:
        timed = [p for p in self._in_flight if p.state is PacketState.SENT and not p.needs_transmit]
        if self._in_flight and self._in_flight[0].state is PacketState.RECEIVED:
            timed.append(self._in_flight[0])  # they complete in order: only the head matters
        return timed

    def _long_running(self) -> bool:
        return bool(self._in_flight) and is_long_command(self._in_flight[0].ticket.text)

    def _due(self, packet: "_Packet") -> float:
        if self.variants.ack and packet.state is PacketState.SENT:
            # Its `a` (or an `r`) comes a round trip after it was sent, whatever the printer
            # is doing: silence past that means it was lost.
            return packet.since + self._ack_timeout()
        if self._long_running():
            patience = self.long_timeout
        elif self._printer_room == 0:
            # A full planner is silent until a move ends (then `q` or an `o`): about as long as
            # moves have been taking. The room we last saw may be stale, the `o` or `q` that
            # said otherwise damaged on the way; sending again is safe (the printer never runs
            # a packet twice), so look well before `long_timeout`.
            patience = PROBE_MOVES * max(self.received_timeout, self._ack_interval)
        else:
            patience = self.timeout
        if packet.state is PacketState.RECEIVED:
            patience = max(patience, self.received_timeout)
        return max(packet.since, self._last_heard) + patience

    def _ack_timeout(self) -> float:
        if self._round_trip is None:
            return self.timeout
        # RFC 6298's SRTT + 4 RTTVAR, and a round trip more: on a steady line the variation
        # falls to nothing, and a packet sent behind others, or an `a` behind an `o`'s
        # response, would time out only for being a little later than the rest.
        estimate = 2 * self._round_trip + 4 * self._round_trip_variation
        return min(self.timeout, max(ACK_TIMEOUT_MIN, estimate) * self._backoff)

    def _sample_round_trip(self, sample: float) -> None:
        """RFC 6298 section 2, from packets sent once only (Karn)."""
        self._backoff = 1
        if self._round_trip is None:
            self._round_trip, self._round_trip_variation = sample, sample / 2
            return
        self._round_trip_variation += (abs(self._round_trip - sample)
                                       - self._round_trip_variation) / 4
        self._round_trip += (sample - self._round_trip) / 8

    def _may_give_up(self, now: float) -> bool:
        """A printer with a full planner may be silent for a slow move's length: give up on
        it only after `long_timeout` of silence, however many probes went unanswered."""
        if self.variants.ack:
            # Its receiver answers at once, however busy: silence is silence.
            return now - self._last_heard >= self.timeout * self.max_transmissions
        if self._printer_room == 0 and not self._long_running():
            return now - self._last_heard >= self.long_timeout
        return True

    def heard(self, now: float, room: int | None = None) -> None:
        """The printer said something (any valid line or frame); `room` if it told its room."""
        self._last_heard = max(self._last_heard, now)
        if room is not None:
            self._printer_room = room

    # -- time and transmission -----------------------------------------------------------
    def poll(self, now: float) -> list[bytes]:
        """Handle expired timers, then return the packets to write now, in order."""
        return [encode_command(t.seq, t.text, self._packet_format) for t in self.transmits(now)]

    def transmits(self, now: float) -> list[Transmit]:
        """poll(), before the packets are encoded."""
        self._expire(now)
        if now < self._hold_until:
            return []
        while len(self._in_flight) < self.window and self._backlog:
            self._in_flight.append(_Packet(self._backlog.popleft(), self._next_seq))
            self._next_seq = self._packet_format.next_seq(self._next_seq)
        transmits = []
        for packet in self._in_flight:
            if not packet.needs_transmit:
                continue
            resend = packet.transmissions > 0
            packet.needs_transmit = False
            packet.transmissions += 1
            packet.state = PacketState.SENT
            packet.since = packet.sent_at = now
            self.stats.packets_sent += 1
            self.stats.resends += resend
            transmits.append(Transmit(packet.seq, packet.ticket.text, resend))
        return transmits

    def _expire(self, now: float) -> None:
        while self._in_flight:
            head = self._in_flight[0]
            if head.state is PacketState.RECEIVED and self._due(head) <= now:
                self._completed += self._complete(1, (), confirmed=False)  # by a timer
                continue
            break
        for index, packet in enumerate(self._in_flight):
            if packet.state is PacketState.SENT and not packet.needs_transmit and self._due(packet) <= now:
                if packet.transmissions >= self.max_transmissions and self._may_give_up(now):
                    speaking = "this protocol" if self.variants.plain else (
                        f"this protocol with variants {self.variants}")
                    raise PrinterNotResponding(
                        f"no answer to {packet.ticket.text!r} after {packet.transmissions} tries; "
                        f"is a printer speaking {speaking} on the port?"
                    )
                self.stats.timeouts += 1
                if self.variants.ack:
                    # A line that stalls, or a printer gone quiet: wait longer each time, as
                    # TCP does, rather than fill the line with copies.
                    self._backoff = min(ACK_BACKOFF_MAX, self._backoff * 2)
                self._go_back(index)
                break

    def _go_back(self, index: int) -> None:
        for packet in self._in_flight[index:]:
            packet.needs_transmit = True

    # -- what the printer says -----------------------------------------------------------
    def receive_data(self, data: bytes, now: float) -> None:
        self._parser.receive_data(data)
        self._received_at = now

    def next_event(self) -> Line | None:
        if self._halted is not None:
            raise PrinterHalted(self._halted)
        now = self._received_at
        while (event := self._parser.next_event()) is not None:
            if isinstance(event, Ack):
                self.room = event.room
                if self.variants.ack and not self._received_frames and not self._boot_heard:
                    self._acks_without_received += 1
                    if self._acks_without_received >= ACKLESS_ACKS:
                        self._mismatch(None, "it executes packets but never says it received "
                                       "one (no `a` frames): it lacks variant ack")
                self._completed += self.on_ack(event.seq, event.room, tuple(self._response), now)
                self._response.clear()
            elif isinstance(event, Received):
                self.room = event.room
                if not self.variants.ack:
                    self._mismatch(None, "it acknowledges receipt with `a` frames (variant ack)")
                self._received_frames += 1
                self.on_received(event.seq, event.room, now)
            elif isinstance(event, Reject):
                self.room = event.room
                self.on_reject(event.seq, event.room, now)
            elif isinstance(event, RoomInfo):
                self.room = event.room
                self.heard(now, event.room)
                self.greeted = True
            elif isinstance(event, CorruptFrame):
                self.corrupt_frames += 1
            else:
                self.heard(now)
                if event.kind is LineKind.RESPONSE:
                    self._response.append(event.text)
                    continue
                if event.kind is LineKind.LOG:
                    self.greeted = True
                    self._read_greeting(event.text)
                elif event.kind is LineKind.ERROR and marlin.is_halt_message(event.text):
                    self._halted = f"the printer halted: Error:{event.text}"
                return event
        return None

    def _read_greeting(self, text: str) -> None:
        """The boot line says what the printer speaks; one damaged on the way says nothing."""
        variants = announced(text)
        if variants is None and not text.startswith(BOOT_LINE):
            return
        self._boot_heard = variants is not None  # it said what it speaks: no guessing
        if self._synchronised:  # (its list of variants may be damaged: it is a boot all the same)
            raise PrinterReset("the printer started again (its boot line came): it was reset, "
                               "and commands it had queued may be lost")
        if variants is not None and variants != self.variants:
            self._mismatch(variants)

    def _mismatch(self, printer: Variants | None, how: str = "") -> None:
        theirs = how or ("it speaks plain v3" if printer is None or printer.plain
                         else f"it speaks variants {printer}")
        ours = "plain v3" if self.variants.plain else f"variants {self.variants}"
        raise VariantMismatch(
            f"the printer does not speak this host's protocol ({ours}): {theirs}; give both "
            "sides the same --variant")

    def on_received(self, seq: int, room: int, now: float) -> None:
        """An `a` frame (the ack variant): the packet `seq` and those before it are queued."""
        self.heard(now, room)
        position = self._position(seq)
        if position is None or position >= len(self._in_flight):
            return  # an echo of something already settled
        self._synchronised = True
        self._mark_received(position + 1, now, answered=True)

    def _mark_received(self, count: int, now: float, answered: bool = False) -> None:
        """The first `count` packets reached the printer; `answered`: this is their own answer
        (an `a`), a round trip to measure for those sent once."""
        for packet in self._in_flight[:count]:
            if packet.state is PacketState.SENT:
                if answered and packet.transmissions == 1 and not packet.needs_transmit:
                    self._sample_round_trip(now - packet.since)
                packet.state = PacketState.RECEIVED
                packet.needs_transmit = False
                packet.since = now

    def on_ack(self, seq: int, room: int, response: tuple[str, ...], now: float) -> list[Ticket]:
        """An `o` frame; returns the tickets it completes, oldest first."""
        self.heard(now, room)
        if self._last_ack_at is not None:
            self._ack_interval = now - self._last_ack_at
        self._last_ack_at = now
        position = self._position(seq)
        if position is None or position >= len(self._in_flight):
            return []  # an echo of something already settled
        self._synchronised = True
        self._refusals, self._refused_seq = 0, None
        echo_position = None if self._echo_seq is None else self._position(self._echo_seq)
        if echo_position is not None and echo_position <= position:
            # The resent packet got through, so no echo of its rejection can follow.
            self._echo_seq, self._echoes_left = None, 0
        self._note_strays(position + 1, now)
        done = self._complete(position, (), confirmed=True)
        done += self._complete(1, response, confirmed=True)
        return done

    def _note_strays(self, count: int, now: float) -> None:
        """The first `count` packets are done. One sent again too recently for the `o` to
        answer the copy (an `r` that noise drew, its packet then read all the same) has its
        copy still on the way: the printer, expecting a later packet, will answer it with an
        `r`. Resending for that `r` would send the next packets twice, whose copies draw
        `r`s again: a window sent twice, over and over, for as long as the job lasts."""
        for packet in self._in_flight[:count]:
            took = now - packet.sent_at
            if packet.transmissions == 1:
                least = self._least_round_trip
                self._least_round_trip = took if least is None else min(least, took)
            elif self._least_round_trip is not None and took < self._least_round_trip:
                self._strays.append(packet.sent_at + 2 * self._least_round_trip)

    def on_reject(self, seq: int, room: int, now: float) -> None:
        """An `r` frame: the printer expects `seq` next."""
        self.heard(now, room)
        self.stats.rejects += 1
        if seq == self._echo_seq and self._echoes_left > 0:
            self._echoes_left -= 1
            return
        self._strays = [until for until in self._strays if until > now]
        if self._strays:
            # The answer to a stray copy (_note_strays); were it a refusal of its own, the
            # packets behind will draw theirs.
            del self._strays[0]
            return
        position = self._position(seq)
        if position is None:
            if 0 < self._packet_format.seq_distance(seq, self._base()) <= 2 * self.window:
                return  # about packets already settled
            if self._synchronised:
                raise PrinterReset(
                    f"the printer now expects sequence number {seq}: it was reset, "
                    "and commands it had queued may be lost"
                )
            self._renumber(seq)
            return
        self._synchronised = True
        self._mark_received(position, now)
        if position == len(self._in_flight):
            return  # it expects what we have not sent yet: it has all we sent, refuses none
        if seq == self._refused_seq:
            self._refusals += 1
            if self._refusals >= self.max_transmissions * 4:
                raise PrinterNotResponding(
                    f"the printer refused sequence number {seq} {self._refusals} times in a row"
                )
            self._hold_until = now + min(self.timeout, 0.01 * 2 ** min(self._refusals, 16))
        else:
            self._refusals, self._refused_seq = 0, seq
        behind = self._in_flight[position:]
        # Each packet sent after `seq` that reaches the printer is rejected with `r` seq again.
        self._echo_seq = seq
        self._echoes_left = sum(1 for packet in behind[1:] if packet.transmissions > 0)
        self._go_back(position)

    def _renumber(self, seq: int) -> None:
        self._next_seq = seq
        for packet in self._in_flight:
            packet.seq = self._next_seq
            packet.state = PacketState.SENT
            packet.needs_transmit = True
            self._next_seq = self._packet_format.next_seq(self._next_seq)
        self._echo_seq, self._echoes_left = None, 0

    def _position(self, seq: int) -> int | None:
        """Where `seq` stands in the window: 0..in_flight (in_flight = the next one to send)."""
        distance = self._packet_format.seq_distance(self._base(), seq)
        return distance if distance <= len(self._in_flight) else None

    def _base(self) -> int:
        return self._in_flight[0].seq if self._in_flight else self._next_seq

    def _complete(self, count: int, response: tuple[str, ...], confirmed: bool) -> list[Ticket]:
        done = []
        for packet in self._in_flight[:count]:
            ticket = packet.ticket
            ticket.done = True
            ticket.confirmed = confirmed
            ticket.response = response
            self.stats.unconfirmed += not confirmed
            done.append(ticket)
        del self._in_flight[:count]
        return done
