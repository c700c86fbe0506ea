"""The printer side of Marlin's binary file transfer (`M28 B1`), as a sans-IO state machine.

Mirrors Marlin 2.1's feature/binary_stream.h: BinaryStream::receive() reads packets into the
ASCII line buffer (so a payload holds at most MAX_CMD_SIZE bytes), answers each in text
(`ok<sync>`, `rs<sync>`, `ss...`, `fe<sync>`, with the `echo:` lines the firmware prints on the
way), and SDFileTransferProtocol::process() runs the file requests, decompressing heatshrink
payloads as they come.

Bytes go in through receive_data(); next_event() gives what the card must do (FileOpened,
FileData, FileClosed, FileAborted), and BackToAscii once the host closes binary mode. Each file
event waits for the caller's FileResult (send()), which says whether the card managed it and
brings the firmware's `PFT:` answer; until then next_event() gives nothing more. The machine
reads no clock: the firmware's two timers (PACKET_MAX_WAIT inside a packet, TRANSFER_TIMEOUT
between file packets) run on the time the caller tells it (time_passed, next_deadline).
"""

import math
from dataclasses import dataclass
from enum import Enum, auto
from typing import TYPE_CHECKING

import heatshrink2.core  # type: ignore[import-untyped]  # the package has no type hints

from fake_marlin.wire.marlin_binary import (
    FOOTER_SIZE,
    HEADER_SIZE,
    PROTOCOL_VERSION,
    TOKEN,
    Control,
    FileRequest,
    Header,
    Protocol,
    checksum,
    parse_header,
)

BUFFER_SIZE = 96  # the line buffer it receives into: MAX_CMD_SIZE
WINDOW_BITS, LOOKAHEAD_BITS = 8, 4  # HEATSHRINK_STATIC_* in Marlin's heatshrink_config.h
PACKET_MAX_WAIT = 0.5  # s without a byte inside a packet: "Datastream timeout", resend
TRANSFER_TIMEOUT = 10.0  # s without a file packet while a file is open: the transfer is aborted


class StreamState(Enum):
    WAIT = auto()  # looking for the token
    HEADER = auto()
    DATA = auto()
    FOOTER = auto()


class Mode(Enum):
    BINARY = auto()  # reading packets
    ANSWER_PENDING = auto()  # a file event waits for its FileResult
    ASCII = auto()  # the host closed binary mode; enter() opens it again


# Events out.
@dataclass(frozen=True)
class FileOpened:
    name: str
    compressed: bool
    dummy: bool  # a benchmark: the firmware writes nothing to the card


@dataclass(frozen=True)
class FileData:
    data: bytes  # decompressed already


@dataclass(frozen=True)
class FileClosed:
    dummy: bool


@dataclass(frozen=True)
class FileAborted:
    dummy: bool
    timed_out: bool  # no file packet came for TRANSFER_TIMEOUT; the firmware says nothing


@dataclass(frozen=True)
class BackToAscii:
    unread: bytes  # bytes after the CLOSE packet: the ASCII protocol's to read


FileEvent = FileOpened | FileData | FileClosed | FileAborted
Event = FileEvent | BackToAscii


# Events in.
@dataclass(frozen=True)
class FileResult:
    """What became of the file event next_event() gave last."""

    ok: bool


class UsageError(RuntimeError):
    """The caller used the machine out of turn (a programming error, not the host's)."""


class _Decompressor:
    def __init__(self) -> None:
        reader = heatshrink2.core.Reader(window_sz2=WINDOW_BITS, lookahead_sz2=LOOKAHEAD_BITS)
        self._decoder = heatshrink2.core.Encoder(reader)

    def decompress(self, data: bytes) -> bytes:
        out: bytes = self._decoder.fill(data)
        return out


class MarlinBinaryProtocol:
    def __init__(self, buffer_size: int = BUFFER_SIZE) -> None:
        self.buffer_size = buffer_size
        self.mode = Mode.BINARY
        self.sync = 0  # the number of the packet it waits for
        self.retries = 0
        self.file_packets = 0  # file-protocol packets processed; each restarts TRANSFER_TIMEOUT
        self.transfer_active = False
        self._dummy = False
        self._decompressor: _Decompressor | None = None
        self._pending: FileEvent | None = None
        self._timed_out: FileAborted | None = None  # a timer's event, for next_event()
        self._input = bytearray()
        self._output = bytearray()
        self._last_byte = self._last_file_packet = -math.inf
        self._heard = True  # entering binary mode counts as a byte (see time_passed)
        self._file_packets_told = 0  # file_packets at the last time_passed()
        self._reset_packet()

    def _reset_packet(self) -> None:
        self.state = StreamState.WAIT
        self._previous = 0  # the byte before, for a token split across reads
        self._header_bytes = bytearray()
        self._header: Header | None = None
        self._payload = bytearray()
        self._footer = bytearray()

    @property
    def mid_packet(self) -> bool:
        """Inside a packet: PACKET_MAX_WAIT without a byte is a timeout."""
        return self.mode is not Mode.ASCII and self.state is not StreamState.WAIT

    # -- receiving ---------------------------------------------------------------------
    def enter(self, data: bytes = b"") -> None:
        """`M28 B1` (again): binary mode from here, starting with `data`. The stream's sync and
        an open transfer carry over, as the firmware's BinaryStream lives on."""
        if self.mode is not Mode.ASCII:
            raise UsageError("the binary protocol is in use already")
        self.mode = Mode.BINARY
        self._input += data
        self._heard = True

    def receive_data(self, data: bytes) -> None:
        if self.mode is Mode.ASCII:
            raise UsageError("binary mode is closed: these bytes are the ASCII protocol's")
        self._input += data
        self._heard = self._heard or bool(data)

    def next_event(self) -> Event | None:
        if self._timed_out is not None:
            timed_out, self._timed_out = self._timed_out, None
            return timed_out
        if self.mode is not Mode.BINARY:
            return None
        data = self._input
        position = 0
        try:
            while position < len(data):
                position, event = self._read(data, position)
                if isinstance(event, BackToAscii):
                    event = BackToAscii(bytes(data[position:]))
                    position = len(data)
                    self.mode = Mode.ASCII
                    return event
                if event is not None:
                    self._pending = event
                    self.mode = Mode.ANSWER_PENDING
                    return event
            return None
        finally:
            del data[:position]

    def _read(self, data: bytearray, position: int) -> tuple[int, Event | None]:
        """Read on from `position` to the end of the current stage of a packet."""
        if self.state is StreamState.WAIT:
            return self._find_token(data, position), None
        if self.state is StreamState.HEADER:
            take = HEADER_SIZE - len(TOKEN) - len(self._header_bytes)
            self._header_bytes += data[position:position + take]
            position += min(take, len(data) - position)
            if len(self._header_bytes) == HEADER_SIZE - len(TOKEN):
                return position, self._header_done()
            return position, None
        if self.state is StreamState.DATA:
            assert self._header is not None
            take = min(self._header.size, self.buffer_size) - len(self._payload)
            if take == 0:  # the next byte would not fit: the firmware reads it, and gives up
                self._say("echo:Datastream packet data buffer overrun")
                self._fatal_error()
                return position + 1, None
            self._payload += data[position:position + take]
            position += min(take, len(data) - position)
            if len(self._payload) == self._header.size:
                self.state = StreamState.FOOTER
            return position, None
        take = FOOTER_SIZE - len(self._footer)
        self._footer += data[position:position + take]
        position += min(take, len(data) - position)
        if len(self._footer) == FOOTER_SIZE:
            return position, self._footer_done()
        return position, None

    def _find_token(self, data: bytearray, position: int) -> int:
        if self._previous == TOKEN[0] and data[position] == TOKEN[1]:
            self.state = StreamState.HEADER
            return position + 1
        found = data.find(TOKEN, position)
        if found < 0:
            self._previous = data[-1]
            return len(data)
        self.state = StreamState.HEADER
        return found + len(TOKEN)

    def _header_done(self) -> Event | None:
        header = parse_header(self._header_bytes)
        if header is None:
            self._say(f"echo:Packet header({self._header_bytes[0]}?) corrupt")
            self._resend()
        elif header.protocol == Protocol.CONTROL and header.type == Control.SYNC:
            # SYNC is answered whatever its sync number: it tells the host the stream's.
            self._say(f"ss{self.sync},{self.buffer_size},{PROTOCOL_VERSION}")
            self._reset_packet()
        elif header.sync == self.sync:
            if not header.size:
                return self._process(header, b"")  # no payload, no footer
            self._header = header
            self.state = StreamState.DATA
        elif header.sync == self.sync - 1:  # (no wrap: the firmware's int arithmetic)
            self._say(f"ok{header.sync}")  # our `ok` was lost: say it again, drop the payload
            self._reset_packet()
        elif self.retries:
            self._reset_packet()  # already asked for a resend: what was sent before it, unacked
        else:
            self._say("echo:Datastream packet out of order")
            self._resend()
        return None

    def _footer_done(self) -> Event | None:
        header = self._header
        assert header is not None
        if checksum(self._payload, checksum(self._header_bytes)) != (
            int.from_bytes(self._footer, "little")
        ):
            self._say(f"echo:Packet({header.sync}) payload corrupt")
            self._resend()
            return None
        return self._process(header, bytes(self._payload))

    def _process(self, header: Header, payload: bytes) -> Event | None:
        self.sync = (self.sync + 1) & 0xFF
        self.retries = 0
        self._say(f"ok{header.sync}")
        self._reset_packet()
        return self._dispatch(header, payload)

    def _resend(self) -> None:
        self.retries = (self.retries + 1) & 0xFF
        self._say(f"echo:Resend request {self.retries}")
        self._say(f"rs{self.sync}")
        self._reset_packet()

    def _fatal_error(self) -> None:
        assert self._header is not None
        self._say(f"fe{self._header.sync}")
        self.sync = self.retries = 0  # the host must SYNC again
        self._reset_packet()

    # -- time ----------------------------------------------------------------------------
    def time_passed(self, now: float) -> None:
        """The bytes and file packets read since the last call came now. A packet left half
        sent for PACKET_MAX_WAIT is asked for again; an open transfer without a file packet
        for TRANSFER_TIMEOUT is aborted (and its file removed) without a word to the host: a
        FileAborted from next_event(), which waits for its FileResult."""
        if self._heard:
            self._last_byte, self._heard = now, False
        if self.file_packets != self._file_packets_told:
            self._last_file_packet, self._file_packets_told = now, self.file_packets
        deadline = self.next_deadline()
        if deadline is None or now < deadline or self.mode is not Mode.BINARY:
            return
        if self.mid_packet:
            self._say("echo:Datastream timeout")
            self._resend()
        else:
            self._timed_out = self._pending = FileAborted(self._dummy, timed_out=True)
            self.mode = Mode.ANSWER_PENDING

    def next_deadline(self) -> float | None:
        if self.mid_packet:
            return self._last_byte + PACKET_MAX_WAIT
        if self.transfer_active and self.mode is not Mode.ASCII:
            return self._last_file_packet + TRANSFER_TIMEOUT
        return None

    # -- the requests ------------------------------------------------------------------
    def _dispatch(self, header: Header, payload: bytes) -> Event | None:
        if header.protocol == Protocol.CONTROL:
            if header.type == Control.CLOSE:
                return BackToAscii(b"")
            self._say("echo:Unknown BinaryProtocolControl Packet")
            return None
        if header.protocol != Protocol.FILE_TRANSFER:
            self._say("echo:Unsupported Binary Protocol")
            return None
        self.file_packets += 1
        request = header.type
        if request == FileRequest.QUERY:
            self._say(f"PFT:version:{PROTOCOL_VERSION}:compression:heatshrink,"
                      f"{WINDOW_BITS},{LOOKAHEAD_BITS}")
        elif request == FileRequest.OPEN:
            return self._open(payload)
        elif request == FileRequest.CLOSE:
            if self.transfer_active:
                return FileClosed(self._dummy)
            self._say("PFT:invalid")
        elif request == FileRequest.WRITE:
            return self._write(payload)
        elif request == FileRequest.ABORT:
            if self.transfer_active:
                return FileAborted(self._dummy, timed_out=False)
            self._say("PFT:success")
        else:
            self._say("PTF:invalid")  # sic: the firmware's spelling
        return None

    def _open(self, payload: bytes) -> FileOpened | None:
        if self.transfer_active:
            self._say("PFT:busy")
            return None
        if len(payload) <= 2 or payload[-1] != 0:
            self._say("PFT:fail")
            return None
        self._dummy = bool(payload[0] & 1)
        compressed = bool(payload[1] & 1)
        self._decompressor = _Decompressor() if compressed else None
        name = payload[2:].split(b"\0", 1)[0].decode("utf-8", "replace")
        return FileOpened(name, compressed, self._dummy)

    def _write(self, payload: bytes) -> FileData | None:
        if not self.transfer_active:
            self._say("PFT:invalid")
            return None
        if self._dummy:
            return None
        data = payload
        if self._decompressor is not None:
            try:
                data = self._decompressor.decompress(payload)
            except (ValueError, RuntimeError):
                self._say("PFT:ioerror")
                return None
        return FileData(data) if data else None

    # -- sending -----------------------------------------------------------------------
    def send(self, result: FileResult) -> bytes:
        """The card's outcome of the pending file event; returns what the firmware says then."""
        event = self._pending
        if event is None or not isinstance(result, FileResult):
            raise UsageError(f"no file event waits for {result!r}")
        self._pending = None
        self.mode = Mode.BINARY
        if isinstance(event, FileOpened):
            self.transfer_active = result.ok
            self._say("PFT:success" if result.ok else "PFT:fail")
        elif isinstance(event, FileData):
            if not result.ok:
                self._say("PFT:ioerror")
        elif isinstance(event, FileClosed):
            self.transfer_active = not result.ok  # a close that failed leaves it open
            self._decompressor = None
            self._say("PFT:success" if result.ok else "PFT:ioerror")
        else:
            self.transfer_active = False
            self._decompressor = None
            if not event.timed_out:
                self._say("PFT:success")
        return self.data_to_send()

    def _say(self, text: str) -> None:
        self._output += text.encode("ascii", "replace") + b"\n"

    def data_to_send(self) -> bytes:
        data = bytes(self._output)
        self._output.clear()
        return data


if TYPE_CHECKING:  # mypy holds the machine to the shared interface
    from fake_marlin.emulator.protocols.base import TimedMachine

    _: type[TimedMachine[Event, FileResult]] = MarlinBinaryProtocol
