"""The line in time: latency, jitter and baud-rate pacing keep bytes in order and on schedule."""

import pytest
import trio

from fake_marlin.emulator.link.conditions import LinkConditions, Pipe


async def deliveries(conditions: LinkConditions, chunks: list[bytes], seed: int = 0):
    arrived = []
    pipe = Pipe(lambda data: arrived.append((trio.current_time(), data)), conditions, seed)
    async with trio.open_nursery() as nursery:
        nursery.start_soon(pipe.run)
        start = trio.current_time()
        for chunk in chunks:
            pipe.put(chunk)
        await trio.sleep(60)
        nursery.cancel_scope.cancel()
    return [(round(t - start, 6), data) for t, data in arrived]


async def test_nothing_configured_passes_straight_through(autojump_clock):
    assert await deliveries(LinkConditions(), [b"a", b"b"]) == [(0.0, b"a"), (0.0, b"b")]


async def test_each_byte_costs_ten_bit_times(autojump_clock):
    arrived = await deliveries(LinkConditions(baud=9600), [b"x" * 96, b"y" * 48])
    assert arrived == [(pytest.approx(0.1), b"x" * 96), (pytest.approx(0.15), b"y" * 48)]


async def test_latency_with_jitter_never_reorders(autojump_clock):
    chunks = [bytes([n]) for n in range(50)]
    arrived = await deliveries(LinkConditions(latency=0.03, jitter=0.02), chunks, seed=3)
    assert [data for _, data in arrived] == chunks
    times = [t for t, _ in arrived]
    assert times == sorted(times) and all(0.03 <= t <= 0.05 for t in times)
