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


async def test_each_byte_costs_ten_bit_times_and_is_handed_on_as_it_comes(autojump_clock):
    arrived = await deliveries(LinkConditions(baud=9600), [b"x" * 96, b"y" * 48])
    assert b"".join(data for _, data in arrived) == b"x" * 96 + b"y" * 48
    byte_times = [t for t, data in arrived for _ in data]
    assert byte_times == [pytest.approx(n * 10 / 9600, abs=1e-6) for n in range(1, 145)]


async def test_of_two_packets_written_at_once_the_first_is_read_when_it_has_come(autojump_clock):
    # 250000 baud: 40 µs a byte. What the printer has read by the time the first packet's
    # last byte has come: the first packet, whatever came with it in the same write.
    arrived = await deliveries(LinkConditions(baud=250000), [b"A" * 34 + b"B" * 34])
    read_by = b"".join(data for t, data in arrived if t <= 34 * 40e-6 + 1e-9)
    assert read_by == b"A" * 34


async def test_latency_with_jitter_never_reorders(autojump_clock):
    chunks = [bytes([n]) for n in range(50)]
    arrived = await deliveries(LinkConditions(latency=0.03, jitter=0.02), chunks, seed=3)
    assert [data for _, data in arrived] == chunks
    times = [t for t, _ in arrived]
    assert times == sorted(times) and all(0.03 <= t <= 0.05 for t in times)
