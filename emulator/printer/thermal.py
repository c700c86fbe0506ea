"""Heaters that warm and cool like real ones, evaluated at any simulated time.

A heater below its target runs at full power and approaches its saturation temperature
exponentially; once at target, PID holds it there; with a lower target it cools toward ambient.
Each piece is solved in closed form, so no tick loop is needed.
"""

import math
from dataclasses import dataclass

AMBIENT = 21.0
FULL_POWER = 127  # Marlin reports soft-PWM power 0..127


@dataclass(frozen=True)
class HeaterSpec:
    saturation: float  # where full power would settle
    heat_tau: float  # seconds; time constant while heating
    cool_tau: float  # seconds; time constant while cooling
    max_target: float


HOTEND = HeaterSpec(saturation=350.0, heat_tau=76.0, cool_tau=120.0, max_target=285.0)
BED = HeaterSpec(saturation=130.0, heat_tau=200.0, cool_tau=600.0, max_target=120.0)


class Heater:
    def __init__(self, spec: HeaterSpec, now: float = 0.0, temperature: float = AMBIENT) -> None:
        self.spec = spec
        self.broken = False  # a dead heater cartridge: it only ever cools
        self.target = 0.0
        self._since = now
        self._start_temperature = temperature

    def set_target(self, now: float, target: float) -> None:
        self._start_temperature = self.temperature(now)
        self._since = now
        self.target = max(0.0, min(target, self.spec.max_target))

    def force_temperature(self, now: float, temperature: float) -> None:
        """The heater is this hot now (a draught, a blast of fan, a test); physics goes on from here."""
        self._start_temperature = temperature
        self._since = now

    def break_down(self, now: float) -> None:
        self.set_target(now, self.target)
        self.broken = True

    def _heating(self) -> bool:
        return self.target > self._start_temperature and not self.broken

    def temperature(self, now: float) -> float:
        elapsed = max(0.0, now - self._since)
        start = self._start_temperature
        if self._heating():
            sat = self.spec.saturation
            value = sat - (sat - start) * math.exp(-elapsed / self.spec.heat_tau)
            return min(value, self.target)
        value = AMBIENT + (start - AMBIENT) * math.exp(-elapsed / self.spec.cool_tau)
        return max(value, self.target) if self.target > AMBIENT and not self.broken else value

    def reached_at(self, now: float) -> float:
        """When the temperature will be within a degree of target (now if it already is)."""
        current = self.temperature(now)
        if abs(current - self.target) <= 1.0 or self.target == 0.0:
            return now
        if self.broken:
            return math.inf
        if current < self.target:
            sat = self.spec.saturation
            goal = self.target - 0.5
            return now + self.spec.heat_tau * math.log((sat - current) / (sat - goal))
        goal = max(self.target + 0.5, AMBIENT + 0.5)
        if current <= goal:
            return now
        return now + self.spec.cool_tau * math.log((current - AMBIENT) / (goal - AMBIENT))

    def power(self, now: float) -> int:
        if self.target == 0.0:
            return 0
        if self.broken:
            return FULL_POWER  # driven flat out, to no effect
        if self.temperature(now) < self.target - 0.01:
            return FULL_POWER
        # Holding: the power that balances losses at this temperature.
        share = (self.target - AMBIENT) / (self.spec.saturation - AMBIENT)
        return max(0, min(FULL_POWER, round(share * FULL_POWER)))
