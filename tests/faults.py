"""A host byte stream that damages what it carries, repeatably (seeded)."""

import random


class DamagingStream:
    def __init__(self, inner, seed: int, *, flip_out=0.0, flip_in=0.0, drop_in=0.0) -> None:
        self._inner = inner
        self._random = random.Random(seed)
        self.flip_out, self.flip_in, self.drop_in = flip_out, flip_in, drop_in

    def _damage(self, data: bytes, flip: float, drop: float) -> bytes:
        out = bytearray()
        for byte in data:
            if self._random.random() < drop:
                continue
            if self._random.random() < flip:
                byte ^= 1 << self._random.randrange(8)
            out.append(byte)
        return bytes(out)

    async def send_all(self, data: bytes) -> None:
        await self._inner.send_all(self._damage(data, self.flip_out, 0.0))

    async def receive_some(self, max_bytes: int = 4096) -> bytes:
        while True:
            data = self._damage(await self._inner.receive_some(max_bytes), self.flip_in, self.drop_in)
            if data:
                return data


class LineDroppingStream:
    """Passes what the printer says line by line, leaving out the lines `drop` picks."""

    def __init__(self, inner, drop) -> None:
        self._inner = inner
        self._drop = drop
        self._partial = b""
        self.dropped = 0

    async def send_all(self, data: bytes) -> None:
        await self._inner.send_all(data)

    async def receive_some(self, max_bytes: int = 4096) -> bytes:
        while True:
            *lines, self._partial = (self._partial + await self._inner.receive_some(max_bytes)).split(b"\n")
            kept = []
            for line in lines:
                if self._drop(line):
                    self.dropped += 1
                else:
                    kept.append(line + b"\n")
            if kept:
                return b"".join(kept)
