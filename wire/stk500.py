"""STK500v2 messages, as stk500boot.c reads and writes them (docs/protocols.md section 4).

Both directions: `1B seq sizeHi sizeLo 0E body xor`, the xor over every byte before it. The
bootloader's answers are emulator/protocols/stk500.py's; these are the wire facts.
"""

from functools import reduce
from operator import xor

from fake_marlin.wire.framing import Framer

MESSAGE_START = 0x1B
TOKEN = 0x0E
HEADER_SIZE = 5  # start, sequence number, size high, size low, token
MAX_BODY = 285  # stk500boot.c's msgBuffer; a longer body would overrun it on the board
MAX_MESSAGE = HEADER_SIZE + MAX_BODY + 1


def checksum(data: bytes | bytearray) -> int:
    return reduce(xor, data, 0)


def encode_message(seq: int, body: bytes) -> bytes:
    """One message on the wire, either way: `1B seq sizeHi sizeLo 0E body xor`."""
    if not 0 <= seq <= 0xFF or len(body) > 0xFFFF:
        raise ValueError(f"no STK500v2 message has sequence number {seq} and {len(body)} bytes")
    message = bytes((MESSAGE_START, seq, len(body) >> 8, len(body) & 0xFF, TOKEN)) + body
    return message + bytes((checksum(message),))


def message_end(buffer: bytes, start: int) -> int | None:
    """Where the message starting at `start` ends; None until enough has come to say.

    Bytes that are no message (noise before a start byte, a start byte whose header or
    checksum is wrong) run as one unit to the next start byte after them, or to the end of what
    has come: nothing waits on them. The receiver, too, looks for a message again from the
    byte after a start that led nowhere.
    """
    if buffer[start] == MESSAGE_START:
        if len(buffer) < start + HEADER_SIZE:
            return None
        size = buffer[start + 2] << 8 | buffer[start + 3]
        if buffer[start + 4] == TOKEN and 1 <= size <= MAX_BODY:
            end = start + HEADER_SIZE + size + 1
            if end > len(buffer):
                return None
            if checksum(buffer[start:end]) == 0:
                return end
    noise_end = buffer.find(MESSAGE_START, start + 1)
    return noise_end if noise_end >= 0 else len(buffer)


MESSAGES = Framer(message_end, MAX_MESSAGE)
TO_PRINTER_UNITS = TO_HOST_UNITS = MESSAGES
