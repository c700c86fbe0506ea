"""The MK20's side of CommStack, as a sans-IO state machine (Printrhub's mk20 CommStack.cpp).

Frames are read one at a time. A request whose data checksum is wrong is answered at once with
an empty ResponseFailed for its task; a frame whose header checksum is wrong is dropped without
a word; a frame that is no COBS at all (or empty, as a stray 0x00 makes it) is answered with a
ResponseFailed for the task of the last packet, as the firmware reuses its last header. Only
requests are answered; responses from the other side are passed on and never answered.
"""

from dataclasses import dataclass

from fake_marlin.wire.commstack import (
    BadData,
    BadHeader,
    CommType,
    FrameSplitter,
    Packet,
    decode_frame,
    encode_packet,
)


# Events out.
@dataclass(frozen=True)
class RequestReceived:
    task: int
    data: bytes


@dataclass(frozen=True)
class ResponseReceived:
    packet: Packet


@dataclass(frozen=True)
class FrameRejected:
    """A damaged frame: `answered` if the firmware said ResponseFailed for it."""

    reason: str
    answered: bool


Event = RequestReceived | ResponseReceived | FrameRejected


# Events in.
@dataclass(frozen=True)
class Response:
    task: int
    success: bool = True
    data: bytes = b""


class CommStackProtocol:
    def __init__(self) -> None:
        self._frames = FrameSplitter()
        self._last_task = 0  # _currentHeader.taskID: what an undecodable frame is answered as
        self._output = bytearray()

    def receive_data(self, data: bytes) -> None:
        self._frames.receive_data(data)

    def next_event(self) -> Event | None:
        frame = self._frames.next_frame()
        if frame is None:
            return None
        decoded = decode_frame(frame)
        if isinstance(decoded, Packet):
            self._last_task = decoded.task
            if decoded.comm_type == CommType.REQUEST:
                return RequestReceived(decoded.task, decoded.data)
            return ResponseReceived(decoded)
        if isinstance(decoded, BadHeader):
            return FrameRejected("header checksum", answered=False)
        if isinstance(decoded, BadData):
            self._last_task = decoded.task
            self._fail(decoded.task)
            return FrameRejected("data checksum", answered=True)
        self._fail(self._last_task)
        return FrameRejected("not a COBS frame", answered=True)

    def _fail(self, task: int) -> None:
        self._output += encode_packet(Packet(task, CommType.RESPONSE_FAILED))

    def send(self, event: Response) -> bytes:
        if not isinstance(event, Response):
            raise TypeError(f"cannot send {event!r}")
        comm_type = CommType.RESPONSE_SUCCESS if event.success else CommType.RESPONSE_FAILED
        self._output += encode_packet(Packet(event.task, comm_type, event.data))
        return self.data_to_send()

    def data_to_send(self) -> bytes:
        data = bytes(self._output)
        self._output.clear()
        return data

