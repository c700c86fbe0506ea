"""The printer side of Ultimaker's serial protocol, as a sans-IO state machine.

Bytes from the host go in through receive_data(); next_event() yields the commands they carry.
What the printer says goes out through send(event) (frames, response data, out-of-band lines)
and data_to_send() (the automatic ProtoError + `r` answers to bad packets).
Mirrors UltimakerMarlin's SerialProtocol::readCommand byte for byte; with `variants` (the
protocol lab's, wire/ultimaker_variants.py) it reads and says what docs/protocols.md section 1.1
lays down instead, and plain v3 stays as it was.
"""

from dataclasses import dataclass
from typing import TYPE_CHECKING
from enum import Enum, auto

from fake_marlin.emulator.protocols.base import CommandDone, CommandReceived, Output
from fake_marlin.wire import ultimaker as wire
from fake_marlin.wire import ultimaker_variants as lab
from fake_marlin.wire.ultimaker_variants import PLAIN, Variants


class ReceiverState(Enum):
    WAIT_FOR_HEADER_BYTE = auto()
    WAIT_FOR_SECOND_HEADER_BYTE = auto()
    WAIT_FOR_SEQUENCE_NUMBER = auto()
    WAIT_FOR_PAYLOAD_SIZE = auto()
    WAIT_FOR_PAYLOAD = auto()
    WAIT_FOR_CRC_HIGH = auto()
    WAIT_FOR_CRC_LOW = auto()
    WAIT_FOR_CHECK = auto()  # a variant's check, one or more bytes


class RejectReason(Enum):
    UNEXPECTED_SEQUENCE = auto()
    BAD_LENGTH = auto()
    ILLEGAL_BYTE = auto()
    CHECKSUM_MISMATCH = auto()
    QUEUE_FULL = auto()


# Events out of the protocol (and CommandReceived, its `number` the packet's sequence number:
# protocols.base).
@dataclass(frozen=True)
class PacketRejected:
    reason: RejectReason
    message: str
    expected: int


Event = CommandReceived | PacketRejected


# Events into the protocol (and CommandDone, Output: protocols.base; EventIn below).
@dataclass(frozen=True)
class RoomChanged:
    """The planner's free room is now `room`; sends a `q` frame if the host last saw 0."""

    room: int


class OutOfBandKind(Enum):
    LOG = "LOG:"
    ERROR = "\nError:"
    WARNING = "WARNING:"


@dataclass(frozen=True)
class OutOfBand:
    kind: OutOfBandKind
    text: str


EventIn = CommandDone | RoomChanged | OutOfBand | Output


_COMPACT = {  # compact-oob's prefixes for each out-of-band kind
    OutOfBandKind.LOG: lab.COMPACT_PREFIXES["LOG"],
    OutOfBandKind.ERROR: lab.COMPACT_PREFIXES["Error"],
    OutOfBandKind.WARNING: lab.COMPACT_PREFIXES["WARNING"],
}


class UltimakerProtocol:
    def __init__(self, queue_size: int = 8, variants: Variants = PLAIN) -> None:
        self.queue_size = queue_size
        self.variants = variants
        self.format = variants.packet
        self._v3 = self.format.is_v3
        self._check = bytearray()
        self.expected_seq = 0
        self.state = ReceiverState.WAIT_FOR_HEADER_BYTE
        self.room = wire.PLANNER_ROOM_MAX
        # The firmware starts with 0 "reported", which is what makes it send q at boot.
        self.reported_room = 0
        self._queued = 0
        self._input = bytearray()
        self._output = bytearray()
        self._seq = 0
        self._length = 0
        self._payload = bytearray()
        self._crc = 0

    # -- receiving ---------------------------------------------------------------------
    def receive_data(self, data: bytes) -> None:
        self._input += data

    def next_event(self) -> Event | None:
        """The next event the received bytes make, or None when more bytes are needed."""
        position = 0
        try:
            while position < len(self._input):
                if (self._v3 and self.state is ReceiverState.WAIT_FOR_HEADER_BYTE
                        and (whole := self._whole_packet(position)) is not None):
                    position, received = whole
                    return received
                byte = self._input[position]
                position += 1
                event = self._step(byte) if self._v3 else self._step_variant(byte)
                if event is not None:
                    if isinstance(event, PacketRejected):
                        # requestResend(): the firmware flushes whatever is still in its RX buffer.
                        position = len(self._input)
                    return event
            return None
        finally:
            del self._input[:position]

    def _whole_packet(self, start: int) -> tuple[int, CommandReceived] | None:
        """The usual packet, whole at `start`, numbered as expected, of printable ASCII, with a
        correct CRC and room in the queue: read at once as _step() reads it byte by byte; None
        for anything else, which _step() reads. Only for a receiver waiting for a packet's
        header (next_event() asks only then)."""
        data = self._input
        end = start + 6 + data[start + 3] if len(data) >= start + 4 else len(data) + 1
        if (end > len(data) or data[start] != wire.HEADER_BYTE or data[start + 1] != wire.HEADER_BYTE
                or data[start + 2] != self.expected_seq or self._queued >= self.queue_size):
            return None
        payload = bytes(data[start + 4:end - 2])
        if (not 1 <= len(payload) <= wire.MAX_PAYLOAD or wire.PRINTABLE.fullmatch(payload) is None
                or int.from_bytes(data[end - 2:end], "big")
                != wire.packet_crc(self.expected_seq, payload)):
            return None
        self._queued += 1
        seq, self.expected_seq = self.expected_seq, wire.next_seq(self.expected_seq)
        if self.variants.ack:
            self._output += self._frame(lab.ACK_KIND, seq)
        return end, CommandReceived(payload.decode("ascii"), seq)

    def _step(self, byte: int) -> Event | None:
        state = self.state
        S = ReceiverState
        if state is S.WAIT_FOR_HEADER_BYTE:
            if byte == wire.HEADER_BYTE:
                self.state = S.WAIT_FOR_SECOND_HEADER_BYTE
            return None
        if state is S.WAIT_FOR_SECOND_HEADER_BYTE:
            self.state = (
                S.WAIT_FOR_SEQUENCE_NUMBER if byte == wire.HEADER_BYTE else S.WAIT_FOR_HEADER_BYTE
            )
            return None
        if state is S.WAIT_FOR_SEQUENCE_NUMBER and byte == wire.HEADER_BYTE:
            # SerialProtocol::readCommand ignores header bytes after the first two, so it
            # syncs on any run of them: a lone 0xFF left by a cut packet does not desync it.
            return None
        if state in (S.WAIT_FOR_PAYLOAD_SIZE, S.WAIT_FOR_PAYLOAD):
            if byte == wire.HEADER_BYTE:  # BREAK_ON_HEADER_BYTE: a new packet starts
                self.state = S.WAIT_FOR_SECOND_HEADER_BYTE
                return None
        if state is S.WAIT_FOR_SEQUENCE_NUMBER:
            if byte != self.expected_seq:
                return self._reject(
                    RejectReason.UNEXPECTED_SEQUENCE,
                    f"Sequence number is unexpected (received, expected): {byte},{self.expected_seq}",
                )
            self._seq = byte
            self.state = S.WAIT_FOR_PAYLOAD_SIZE
            return None
        if state is S.WAIT_FOR_PAYLOAD_SIZE:
            return self._take_length(byte)
        if state is S.WAIT_FOR_PAYLOAD:
            return self._take_payload_byte(byte, S.WAIT_FOR_CRC_HIGH)
        if state is S.WAIT_FOR_CRC_HIGH:
            self._crc = byte << 8
            self.state = S.WAIT_FOR_CRC_LOW
            return None
        # WAIT_FOR_CRC_LOW: the packet is complete.
        payload = bytes(self._payload)
        return self._finish(payload, self._crc | byte == wire.packet_crc(self._seq, payload))

    def _take_length(self, length: int) -> PacketRejected | None:
        if not 1 <= length <= wire.MAX_PAYLOAD:
            return self._reject(
                RejectReason.BAD_LENGTH,
                f"Payload size is too big for packet with sequence number: {self.expected_seq}",
            )
        self._length = length
        self._payload.clear()
        self.state = ReceiverState.WAIT_FOR_PAYLOAD
        return None

    def _take_payload_byte(self, byte: int, then: ReceiverState) -> PacketRejected | None:
        """One payload byte; after the last, the receiver waits for the check (`then`)."""
        if not wire.PAYLOAD_MIN_BYTE <= byte <= wire.PAYLOAD_MAX_BYTE:
            return self._reject(
                RejectReason.ILLEGAL_BYTE,
                f"Payload byte not in acceptable (ASCII) range at position #{len(self._payload)}",
            )
        self._payload.append(byte)
        if len(self._payload) == self._length:
            self._check.clear()
            self.state = then
        return None

    def _finish(self, payload: bytes, check_matches: bool) -> Event:
        """The whole packet is here: refused, or taken into the queue."""
        self.state = ReceiverState.WAIT_FOR_HEADER_BYTE
        if not check_matches:
            return self._reject(
                RejectReason.CHECKSUM_MISMATCH,
                f"Checksum mismatch for packet with sequence number: {self.expected_seq}",
            )
        if self._queued >= self.queue_size:
            return self._reject(
                RejectReason.QUEUE_FULL,
                "Received packet could not be handled (buffer full), packet with sequence number: "
                f"{self.expected_seq}",
            )
        self._queued += 1
        self.expected_seq = self.format.next_seq(self.expected_seq)
        if self.variants.ack:
            self._output += self._frame(lab.ACK_KIND, self._seq)
        return CommandReceived(payload.decode("ascii"), self._seq)

    def _step_variant(self, byte: int) -> Event | None:
        """_step() for a variant's packets (docs/protocols.md section 1.1)."""
        state = self.state
        S = ReceiverState
        packet = self.format
        if byte == packet.start:
            if state is S.WAIT_FOR_HEADER_BYTE or state is S.WAIT_FOR_SEQUENCE_NUMBER and (
                    packet.starts == 1):
                # The first start byte, or (one start byte) more of a run: a run syncs.
                self.state = S.WAIT_FOR_SEQUENCE_NUMBER if packet.starts == 1 else (
                    S.WAIT_FOR_SECOND_HEADER_BYTE)
                return None
            if state is S.WAIT_FOR_SECOND_HEADER_BYTE or state is S.WAIT_FOR_SEQUENCE_NUMBER:
                self.state = S.WAIT_FOR_SEQUENCE_NUMBER
                return None
            if packet.armored or state in (S.WAIT_FOR_PAYLOAD_SIZE, S.WAIT_FOR_PAYLOAD):
                # A new packet starts: the start byte is no byte of a packet's body (armored),
                # or not of a length or payload (crc8's 0xFF, as BREAK_ON_HEADER_BYTE).
                self.state = S.WAIT_FOR_SEQUENCE_NUMBER if packet.starts == 1 else (
                    S.WAIT_FOR_SECOND_HEADER_BYTE)
                return None
        if state is S.WAIT_FOR_HEADER_BYTE:
            return None
        if state is S.WAIT_FOR_SECOND_HEADER_BYTE:
            self.state = S.WAIT_FOR_HEADER_BYTE
            return None
        if state is S.WAIT_FOR_SEQUENCE_NUMBER:
            seq = packet.read_seq(byte)
            if seq != self.expected_seq:
                return self._reject(
                    RejectReason.UNEXPECTED_SEQUENCE,
                    "Sequence number is unexpected (received, expected): "
                    f"{byte if seq is None else seq},{self.expected_seq}",
                )
            self._seq = seq
            self.state = S.WAIT_FOR_PAYLOAD_SIZE
            return None
        if state is S.WAIT_FOR_PAYLOAD_SIZE:
            return self._take_length(packet.read_len(byte))
        if state is S.WAIT_FOR_PAYLOAD:
            return self._take_payload_byte(byte, S.WAIT_FOR_CHECK)
        # WAIT_FOR_CHECK
        self._check.append(byte)
        if len(self._check) < packet.check_chars:
            return None
        payload = bytes(self._payload)
        return self._finish(
            payload, packet.read_check(bytes(self._check)) == packet.check(self._seq, payload))

    def _reject(self, reason: RejectReason, message: str) -> PacketRejected:
        self.state = ReceiverState.WAIT_FOR_HEADER_BYTE
        prefix = lab.COMPACT_PREFIXES["ProtoError"] if self.variants.compact_oob else "\nProtoError:"
        self._output += f"{prefix}{message}\n".encode("ascii")
        self._output += self._frame("r", self.expected_seq)
        return PacketRejected(reason, message, self.expected_seq)

    # -- sending -----------------------------------------------------------------------
    def send(self, event: EventIn) -> bytes:
        """Bytes for the host, including any automatic answers still waiting to go out."""
        if isinstance(event, CommandDone):
            if event.number is None:
                raise TypeError(f"an `o` frame needs the sequence number it answers: {event!r}")
            self._queued = max(0, self._queued - 1)
            if event.room is not None:
                self.room = event.room
            for line in event.response:
                self._output += self._response_line(line)
            self._output += self._frame("o", event.number)
        elif isinstance(event, RoomChanged):
            self.room = event.room
            if self.reported_room == 0 and event.room > 0:
                self._output += self._frame("q", 0)
        elif isinstance(event, OutOfBand):
            prefix = _COMPACT[event.kind] if self.variants.compact_oob else event.kind.value
            self._output += f"{prefix}{event.text}\n".encode("ascii", "replace")
        elif isinstance(event, Output):
            self._output += self._response_line(event.text)
        else:
            raise TypeError(f"cannot send {event!r}")
        return self.data_to_send()

    def data_to_send(self) -> bytes:
        data = bytes(self._output)
        self._output.clear()
        return data

    def _response_line(self, text: str) -> bytes:
        return f"{lab.response_line(text, self.variants)}\n".encode("ascii", "replace")

    def _frame(self, kind: str, seq: int) -> bytes:
        self.reported_room = self.room
        return f"\n{wire.frame_body(kind, seq, self.room)}\n".encode("ascii")


if TYPE_CHECKING:  # mypy holds the machine to the shared interface
    from fake_marlin.emulator.protocols.base import ProtocolMachine

    _: type[ProtocolMachine[Event, EventIn]] = UltimakerProtocol
