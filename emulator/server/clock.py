"""A trio clock that runs simulated time a fixed factor faster than real time."""

import time

import trio


class ScaledClock(trio.abc.Clock):
    def __init__(self, speed: float) -> None:
        if speed <= 0:
            raise ValueError("speed must be positive")
        self.speed = speed
        self._real_start = 0.0

    def start_clock(self) -> None:
        self._real_start = time.perf_counter()

    def current_time(self) -> float:
        return (time.perf_counter() - self._real_start) * self.speed

    def deadline_to_sleep_time(self, deadline: float) -> float:
        return max(0.0, (deadline - self.current_time()) / self.speed)
