"""Splitting what a printer says into lines, with a bound so that noise cannot grow memory."""

MAX_LINE = 4096  # a longer "line" is noise: it is cut into pieces of this size


class LineBuffer:
    def __init__(self) -> None:
        self._buffer = bytearray()

    def receive_data(self, data: bytes) -> None:
        self._buffer += data

    def next_line(self) -> bytes | None:
        """The next line without its line feed, or None until one is complete."""
        end = self._buffer.find(b"\n", 0, MAX_LINE + 1)  # a line feed further on ends a piece
        if end < 0:
            if len(self._buffer) <= MAX_LINE:
                return None
            line = bytes(self._buffer[:MAX_LINE])
            del self._buffer[:MAX_LINE]
            return line
        line = bytes(self._buffer[:end])
        del self._buffer[: end + 1]
        return line
