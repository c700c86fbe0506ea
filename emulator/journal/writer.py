"""The journal: one line per command the printer executed, in order, flushed at once."""

from typing import TextIO


class Journal:
    def __init__(self, stream: TextIO | None) -> None:
        self._stream = stream

    @classmethod
    def open(cls, path: str | None) -> "Journal":
        return cls(open(path, "a", encoding="ascii", errors="replace") if path else None)

    def record(self, command: str) -> None:
        if self._stream is not None:
            self._stream.write(command + "\n")
            self._stream.flush()

    def close(self) -> None:
        if self._stream is not None:
            self._stream.close()
