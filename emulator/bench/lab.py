"""The protocol lab's measurements (`fake-marlin bench --only lab`, docs/protocol-lab.md).

Every figure of a variant is a ratio to plain v3 measured in the same run, under the same
faults, on the same clock. The runs are the printer and our host in one process on trio's
MockClock, as a scenario runs (emulator/scenario/run.py): the line (baud, latency) and the
faults are simulated, so a figure depends on the protocol alone, never on how busy the machine
is, and the same run gives the same figures everywhere. The printer executes its moves at once
(acceleration and feed rates without limit): what limits a print here is the line, which is
what a protocol can change.

Two kinds of measurement:
- `stream`: a job of LAB_MOVES moves (payloads of about 30 bytes, seed 000's "average of 30
  bytes payload") streamed by our host; commands per second, bytes and bit times per command
  each way, resends, and what ran damaged (the journal against the job).
- `undetected`: the sans-IO receiver alone, fed packets with bit errors drawn per bit, to
  count what a check lets through. A packet with fewer than two flipped bits is always caught
  (both CRCs see every single-bit error), so only packets with two or more are drawn, and
  each is weighed by that chance: enough bits to say what CRC-8 misses and CRC-16 does not.
"""

import dataclasses
import io
import math
import random
import tempfile
from dataclasses import dataclass
from pathlib import Path

import trio
import trio.testing

from fake_marlin.emulator.faults.layer import FaultConfig, LineFaults
from fake_marlin.emulator.faults.rules import FaultKind, FaultRule, Trigger
from fake_marlin.emulator.firmware import Firmware
from fake_marlin.emulator.journal.verify import Kind, verify
from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.link.conditions import LinkConditions
from fake_marlin.emulator.link.memory import HostEnd, MemoryLink
from fake_marlin.emulator.printer.model import Printer, PrinterConfig
from fake_marlin.emulator.protocols.base import CommandReceived
from fake_marlin.emulator.protocols.ultimaker import UltimakerProtocol
from fake_marlin.emulator.scenario.run import pinned_scheduler
from fake_marlin.emulator.server.lifecycle import PrinterServer, ServerConfig
from fake_marlin.host.connect import connect
from fake_marlin.host.shell import ClientOptions
from fake_marlin.wire.ultimaker_variants import parse_variants

WIRE_BAUD = 250000
LATENCY = 0.030  # seconds each way: seed 000's "30ms+"
ERROR_RATES = (1e-5, 1e-4, 1e-3)
# What an open (floating) line or a glitch on an idle one reads as: a pulse low looks like a
# start bit followed by ones (0xFF), a longer one like 0xFF with its first bits low (0xF0,
# 0xFE): a burst of them between packets.
NOISE = b"\xff\xff\xf0\xff\xfe"
NOISE_PROBABILITY = 0.02  # per packet


def _instant(config: PrinterConfig) -> PrinterConfig:
    """`config` with motion that takes no time: acceleration and feed rates without limit."""
    return dataclasses.replace(config, acceleration=1e9, junction_speed=1e6,
                               max_feedrate=(1e6, 1e6, 1e6, 1e6), default_feedrate=1e9)


def lab_job(count: int) -> list[str]:
    """`count` moves as a slicer writes them, each line distinct: about 30 bytes each."""
    job = []
    for index in range(count):
        x = 100 + 20 * math.cos(index / 40)
        y = 100 + 20 * math.sin(index / 40)
        job.append(f"G1 X{x:.3f} Y{y:.3f} E{0.03 * (index + 1):.5f}")
    return job


@dataclass(frozen=True)
class Condition:
    name: str
    baud: int = WIRE_BAUD
    latency: float = 0.0
    bit_error_rate: float = 0.0  # toward the printer
    noise: bool = False  # open-line 0xFF bursts toward the printer
    busy: bool = False  # the printer moves at its own pace (a full planner), not at once


@dataclass(frozen=True)
class StreamResult:
    variants: str
    condition: str
    commands: int
    seconds: float  # simulated: first command sent to last acknowledged
    to_printer: int  # bytes
    to_host: int
    bit_times: int  # per byte, 2 + data bits
    resends: int
    timeouts: int
    bit_errors: int  # bytes toward the printer with a flipped bit
    damaged: int  # job commands that ran other than sent
    exactly_once: bool
    error: str = ""

    @property
    def rate(self) -> float:
        return self.commands / self.seconds if self.seconds else 0.0


class _Counter:
    def __init__(self, stream: HostEnd) -> None:
        self._stream = stream
        self.sent = 0
        self.received = 0

    async def send_all(self, data: bytes) -> None:
        self.sent += len(data)
        await self._stream.send_all(data)

    async def receive_some(self, max_bytes: int | None = 4096) -> bytes:
        data = await self._stream.receive_some(max_bytes or 4096)
        self.received += len(data)
        return data


def stream(variants_text: str, condition: Condition, moves: int, seed: int = 1) -> StreamResult:
    """One job streamed by our host through the line `condition` describes."""
    variants = parse_variants(variants_text)
    job = lab_job(moves)
    rules: tuple[FaultRule, ...] = ()
    if condition.noise:
        rules = (FaultRule(FaultKind.GARBAGE, Trigger(probability=NOISE_PROBABILITY),
                           "to-printer", text=NOISE.decode("latin-1")),)
    faults = FaultConfig(to_printer=LineFaults(bit_error_rate=condition.bit_error_rate),
                         seed=seed, rules=rules)
    config = ServerConfig(protocol="ultimaker", faults=faults, variants=variants,
                          conditions=LinkConditions(condition.baud, condition.latency))

    async def run() -> StreamResult:
        firmware = Firmware.make(seed=seed)
        with tempfile.TemporaryDirectory(prefix="fake-marlin-lab-") as sd_dir:
            printer_config = firmware.printer_config(1, Path(sd_dir))
            printer = Printer(printer_config if condition.busy else _instant(printer_config))
            journal = io.StringIO()
            link = MemoryLink()
            server = PrinterServer(link, printer, Journal(journal), config, firmware=firmware)
            flips = 0

            def count(kind: str, direction: str, number: int | None, unit: bytes | None) -> None:
                nonlocal flips
                if kind == "bit-errors" and direction == "to-printer":
                    flips += number or 0

            server.faults.on_fault = count
            error = ""
            async with trio.open_nursery() as nursery:
                await nursery.start(server.run)
                counter = _Counter(link.open_host())
                options = ClientOptions(variants=variants)
                started = trio.current_time()
                summary = None
                try:
                    async with connect(counter, "ultimaker", options) as host:
                        started = trio.current_time()
                        summary = await host.print_commands(job)
                except Exception as raised:  # noqa: BLE001 - a host that gives up is a figure
                    error = f"{type(raised).__name__}: {raised}"
                seconds = trio.current_time() - started
                await trio.sleep(5)  # what was sent runs
                nursery.cancel_scope.cancel()
            verdict = verify(list(enumerate(job, start=1)), journal.getvalue().splitlines())
            return StreamResult(
                str(variants), condition.name, len(job), seconds, counter.sent,
                counter.received, 2 + variants.data_bits,
                summary.resends if summary else 0, summary.timeouts if summary else 0, flips,
                verdict.count(Kind.DAMAGED), verdict.passed(allow_undetectable=True) and not error,
                error)

    with pinned_scheduler(seed):
        return trio.run(run, clock=trio.testing.MockClock(autojump_threshold=0))


@dataclass(frozen=True)
class UndetectedResult:
    variants: str
    bit_error_rate: float
    samples: int  # packets drawn with two or more flipped bits
    undetected: int  # of those, read as a command other than the one sent
    weight: float  # the chance that a packet has two or more flipped bits (mean)
    bits_per_packet: float

    @property
    def per_million(self) -> float:
        """Packets that run damaged, per million sent."""
        return 1e6 * self.weight * self.undetected / self.samples

    @property
    def upper_per_million(self) -> float:
        """The 95% upper bound of per_million (the rule of three when none was seen)."""
        high = self.undetected + 1.96 * math.sqrt(self.undetected) if self.undetected else 3.0
        return 1e6 * self.weight * high / self.samples

    @property
    def bits_covered(self) -> float:
        """The bits of line this stands for: samples over their chance, in packets' bits."""
        return self.samples / self.weight * self.bits_per_packet


def undetected(variants_text: str, bit_error_rate: float, samples: int,
               seed: int = 1) -> UndetectedResult:
    variants = parse_variants(variants_text)
    packet = variants.packet
    bits_per_byte = variants.data_bits
    job = [text.encode("ascii") for text in lab_job(500)]
    draw = random.Random(f"lab undetected {variants_text} {bit_error_rate} {seed}")
    end = bytes((packet.start,)) * packet.starts  # what follows: ends a packet cut long
    found = 0
    weights = 0.0
    bits = 0
    for number in range(samples):
        payload = job[number % len(job)]
        seq = number % packet.sequence_modulus
        data = bytearray(packet.encode(seq, payload))
        size = len(data) * bits_per_byte
        flips, weight = _flips(draw, size, bit_error_rate)
        weights += weight
        bits += size
        for position in draw.sample(range(size), flips):
            byte, bit = divmod(position, bits_per_byte)
            data[byte] ^= 1 << bit
        receiver = UltimakerProtocol(variants=variants)
        receiver.expected_seq = seq
        receiver.receive_data(bytes(data) + end)
        while (event := receiver.next_event()) is not None:
            if isinstance(event, CommandReceived) and event.text.encode() != payload:
                found += 1
    return UndetectedResult(str(variants), bit_error_rate, samples, found, weights / samples,
                            bits / samples)


def _flips(draw: random.Random, size: int, rate: float) -> tuple[int, float]:
    """How many bits of `size` flip, drawn given that two or more do; and that chance."""
    none = (1 - rate) ** size
    one = size * rate * (1 - rate) ** (size - 1)
    weight = 1 - none - one
    # The binomial's terms from k = 2, until they no longer matter.
    terms = []
    term = one * (size - 1) * rate / (2 * (1 - rate))
    k = 2
    while k <= size and (term > weight * 1e-9 or k == 2):
        terms.append(term)
        term *= (size - k) * rate / ((k + 1) * (1 - rate))
        k += 1
    pick = draw.random() * sum(terms)
    for index, term in enumerate(terms):
        pick -= term
        if pick <= 0:
            return index + 2, weight
    return len(terms) + 1, weight
