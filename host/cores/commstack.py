"""The ESP's end of CommStack, as a sans-IO state machine: one request in flight, its answer
matched by task (CommStack has no sequence numbers), and the MK20's own pings answered.

What an exchange can end in (Exchange.outcome):
- SUCCESS / FAILED: a ResponseSuccess / ResponseFailed for the task in flight. A ResponseFailed
  comes for a request whose data checksum was wrong (it did nothing), but also, from the MK20,
  for a frame it could not decode at all, under the task of the last good packet: it does not
  prove which request failed. So retrying a request that is not idempotent (file data) can store
  it twice; the client checks an upload's length at the end for that reason.
- TIMEOUT: no answer for `timeout` seconds. The request may have been lost, or its answer.
"""

import struct
from dataclasses import dataclass
from enum import Enum, auto

from fake_marlin.wire.commstack import CommType, FrameSplitter, Packet, Task, decode_frame, encode_packet

BUILD_NUMBER = 1  # what this host answers the MK20's pings with, as the ESP answers its own


class Outcome(Enum):
    SUCCESS = auto()
    FAILED = auto()
    TIMEOUT = auto()


@dataclass(eq=False)
class Exchange:
    task: int
    data: bytes
    sent_at: float | None = None
    outcome: Outcome | None = None
    answer: bytes = b""


@dataclass
class CommStackStats:
    packets_sent: int = 0
    resends: int = 0
    timeouts: int = 0
    rejects: int = 0  # ResponseFailed answers
    corrupt_frames: int = 0
    unconfirmed: int = 0


class CommStackEndpoint:
    def __init__(self, timeout: float = 2.0) -> None:
        self.timeout = timeout
        self.stats = CommStackStats()
        self.printer_seen = False
        self._frames = FrameSplitter(limit=1 << 16)
        self._current: Exchange | None = None
        self._answers: list[bytes] = []  # our responses to the printer's requests

    def start(self, task: int, data: bytes = b"") -> Exchange:
        if self._current is not None and self._current.outcome is None:
            raise RuntimeError("one CommStack request at a time")
        self._current = Exchange(task, data)
        return self._current

    def poll(self, now: float) -> list[bytes]:
        out, self._answers = self._answers, []
        current = self._current
        if current is None or current.outcome is not None:
            return out
        if current.sent_at is None:
            current.sent_at = now
            self.stats.packets_sent += 1
            out.append(encode_packet(Packet(current.task, CommType.REQUEST, current.data)))
        elif now >= current.sent_at + self.timeout:
            self.stats.timeouts += 1
            current.outcome = Outcome.TIMEOUT
        return out

    def next_deadline(self) -> float | None:
        current = self._current
        if current is None or current.outcome is not None or current.sent_at is None:
            return None
        return current.sent_at + self.timeout

    def receive_data(self, data: bytes) -> None:
        self._frames.receive_data(data)
        while (frame := self._frames.next_frame()) is not None:
            decoded = decode_frame(frame)
            if not isinstance(decoded, Packet):
                if frame:
                    self.stats.corrupt_frames += 1  # the ESP only logs these
                continue
            self.printer_seen = True
            if decoded.comm_type == CommType.REQUEST:
                self._answer(decoded)
            else:
                self._settle(decoded)

    def _answer(self, request: Packet) -> None:
        data = struct.pack("<i", BUILD_NUMBER) if request.task == Task.PING else b""
        self._answers.append(encode_packet(Packet(request.task, CommType.RESPONSE_SUCCESS, data)))

    def _settle(self, response: Packet) -> None:
        current = self._current
        if current is None or current.outcome is not None or current.sent_at is None:
            return  # late: for an exchange that has timed out, or stray
        if response.task != current.task:
            return
        if response.comm_type == CommType.RESPONSE_SUCCESS:
            current.outcome = Outcome.SUCCESS
        else:
            self.stats.rejects += 1
            current.outcome = Outcome.FAILED
        current.answer = response.data
