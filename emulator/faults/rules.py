"""Faults that fire on a trigger: the Nth unit, every Nth, a moment, a pattern, or chance.

A unit is what the protocol frames: a line of text either way, or an Ultimaker packet on its
way to the printer. Link faults act on units in one direction; printer faults act on the
printer when a command is about to run (or at a moment). Decisions come from seeded
generators and counters, never from a clock, so the same run makes the same faults. Each rule
draws from a generator of its own, seeded from the run's seed and its place in the file: what
it decides depends only on the units (or commands) it has seen, never on which other rule or
direction happened to draw first.
"""

import random
import re
from dataclasses import dataclass, field
from enum import Enum

from fake_marlin.emulator.printer.failures import Failure, FailureKind


class FaultKind(Enum):
    # On the link, per unit.
    DROP = "drop"
    DUPLICATE = "duplicate"
    TRUNCATE = "truncate"
    GARBAGE = "garbage"
    STALL = "stall"
    DISCONNECT = "disconnect"
    # In the printer.
    FIRMWARE_ERROR = "firmware-error"
    THERMAL_RUNAWAY = "thermal-runaway"
    MINTEMP = "mintemp"
    MAXTEMP = "maxtemp"
    HEATER_FAULT = "heater-fault"
    PLANNER_STALL = "planner-stall"
    QUEUE_FULL = "queue-full"
    REBOOT = "reboot"
    SD_REMOVED = "sd-removed"


LINK_KINDS = frozenset(
    {FaultKind.DROP, FaultKind.DUPLICATE, FaultKind.TRUNCATE, FaultKind.GARBAGE, FaultKind.STALL,
     FaultKind.DISCONNECT}
)


@dataclass(frozen=True)
class Trigger:
    """When a fault fires. `pattern` alone fires on every unit it finds; with nth, every or
    probability it only picks which units count (`pattern = "^o"`, `every = 10`: every tenth
    `o` frame)."""

    nth: int | None = None  # the Nth unit (or command), counting from 1
    every: int | None = None  # every Nth
    at: float | None = None  # simulated seconds after power-on
    pattern: str | None = None  # units (or commands) this regular expression finds
    probability: float | None = None  # chance per unit (or command)
    times: int | None = None  # fire at most this often (default: once for nth and at)

    def __post_init__(self) -> None:
        chosen = [n for n in ("nth", "every", "at", "probability") if getattr(self, n) is not None]
        if len(chosen) > 1 or not chosen and self.pattern is None:
            raise ValueError("a trigger needs one of nth, every, at, probability, or a pattern")
        if self.at is not None and self.pattern is not None:
            raise ValueError("at is a moment; it takes no pattern")
        if self.nth is not None and self.nth < 1 or self.every is not None and self.every < 1:
            raise ValueError("nth and every count from 1")
        if self.probability is not None and not 0 <= self.probability <= 1:
            raise ValueError("probability is between 0 and 1")
        if self.at is not None and self.at < 0:
            raise ValueError("at is seconds from power-on, 0 or more")
        if self.pattern is not None:
            try:
                re.compile(self.pattern)
            except re.error as error:
                raise ValueError(f"pattern {self.pattern!r} is no regular expression: {error}") from None

    @property
    def limit(self) -> int | None:
        if self.times is not None:
            return self.times
        return 1 if self.nth is not None or self.at is not None else None


@dataclass(frozen=True)
class FaultRule:
    kind: FaultKind
    trigger: Trigger
    direction: str | None = None  # "to-printer" or "to-host", for link faults
    seconds: float = 0.0  # stall, disconnect, planner-stall, queue-full: how long
    text: str = ""  # firmware-error: the message; garbage: what to send (default: noise)
    length: int = 0  # garbage: how many bytes; truncate: how many to keep (default: half)
    heater: str = "T0"  # T0.., or B for the bed


# The printer faults the printer model suffers itself; reboot and queue-full are the server's.
PRINTER_FAILURES = {
    FaultKind.FIRMWARE_ERROR: FailureKind.FIRMWARE_ERROR,
    FaultKind.THERMAL_RUNAWAY: FailureKind.THERMAL_RUNAWAY,
    FaultKind.MINTEMP: FailureKind.MINTEMP,
    FaultKind.MAXTEMP: FailureKind.MAXTEMP,
    FaultKind.HEATER_FAULT: FailureKind.HEATER_FAULT,
    FaultKind.PLANNER_STALL: FailureKind.PLANNER_STALL,
    FaultKind.SD_REMOVED: FailureKind.SD_REMOVED,
}


def printer_failure(rule: FaultRule) -> Failure:
    """The failure `rule` makes the printer model suffer (see printer.failures.apply)."""
    kind = PRINTER_FAILURES.get(rule.kind)
    if kind is None:
        raise ValueError(f"{rule.kind.value} is not a printer fault the model handles")
    return Failure(kind, heater=rule.heater, seconds=rule.seconds, text=rule.text)


def stream_random(seed: int, stream: str) -> random.Random:
    """A generator of its own for one stream of decisions (a rule, a direction's damage).

    Seeded with a string, which Random hashes with SHA-512: the same on every run, whatever
    PYTHONHASHSEED says."""
    return random.Random(f"{seed}/{stream}")


@dataclass
class _RuleState:
    random: random.Random
    count: int = 0
    fired: int = 0


@dataclass
class FaultPlan:
    rules: tuple[FaultRule, ...] = ()
    seed: int = 0
    _state: dict[int, _RuleState] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._state = {index: self._new_state(index) for index in range(len(self.rules))}

    def _new_state(self, index: int) -> _RuleState:
        return _RuleState(stream_random(self.seed, f"rule {index}"))

    def add(self, rule: FaultRule) -> None:
        """A fault added while the printer runs (the control channel)."""
        self.rules = (*self.rules, rule)
        self._state[len(self.rules) - 1] = self._new_state(len(self.rules) - 1)

    def link_rules(self, direction: str) -> list[tuple[int, FaultRule]]:
        return [
            (index, rule) for index, rule in enumerate(self.rules)
            if rule.kind in LINK_KINDS and rule.direction == direction and rule.trigger.at is None
        ]

    def printer_rules(self) -> list[tuple[int, FaultRule]]:
        return [
            (index, rule) for index, rule in enumerate(self.rules)
            if rule.kind not in LINK_KINDS and rule.trigger.at is None
        ]

    def timed_rules(self) -> list[tuple[float, int, FaultRule]]:
        """Rules that fire at a moment, in time order (file order at the same moment), each
        with its moment and index."""
        timed = [
            (rule.trigger.at, index, rule)
            for index, rule in enumerate(self.rules)
            if rule.trigger.at is not None
        ]
        return sorted(timed, key=lambda entry: entry[:2])

    def fires(self, index: int, text: str) -> bool:
        """Does rule `index` fire on this unit or command? Counts it either way."""
        rule, state = self.rules[index], self._state[index]
        trigger = rule.trigger
        if trigger.limit is not None and state.fired >= trigger.limit:
            return False
        if trigger.pattern is not None and re.search(trigger.pattern, text) is None:
            return False
        state.count += 1
        if trigger.nth is not None:
            hit = state.count == trigger.nth
        elif trigger.every is not None:
            hit = state.count % trigger.every == 0
        elif trigger.probability is not None:
            hit = state.random.random() < trigger.probability
        else:
            hit = True
        state.fired += hit
        return hit

    def garbage(self, index: int) -> bytes:
        """What rule `index` (a garbage fault) puts on the line this time: its text, or what a
        crashing co-processor spits out, debug text and stray bytes, drawn by the rule."""
        rule = self.rules[index]
        if rule.text:
            return rule.text.encode("latin-1")
        words = (b"DBG ", b"stack ", b"0x3ffb", b"rst:0x8 ", b"\x00", b"\xff", b"ets Jun  8 ",
                 b"boot:0x13 ", b"\r\n", b"load:0x4008 ")
        out = bytearray()
        draw = self._state[index].random
        while len(out) < (rule.length or 48):
            out += draw.choice(words)
        return bytes(out[: rule.length or 48])
