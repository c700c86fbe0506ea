"""`fake-marlin bench --only lab`: the protocol lab's table (measurements in bench/lab.py).

Each variant of Ultimaker's protocol (and the best combination) against plain v3, side by side
in the same run, in worker processes (the runs are on simulated time: how many run at once
changes nothing in what they measure). The rows hold seed 000's claims beside what was
measured; the tables below them hold every figure.
"""

import concurrent.futures
import multiprocessing
import os
from collections.abc import Callable
from typing import Any

from fake_marlin.emulator.bench import lab
from fake_marlin.emulator.bench.report import Row, Section, Table

PLAIN = "v3"
SINGLE = ("ack", "compact-oob", "crc8", "sync-byte", "7bit")
# The best combination: every variant that gained something alone (7bit brings sync-byte's
# packets with it); see docs/protocol-lab.md for why.
BEST = "ack,compact-oob,crc8,7bit"
VARIANT_SETS = (PLAIN, *SINGLE, BEST)
# The packet formats whose checks differ (ack and compact-oob change no packet).
CHECKED = (PLAIN, "crc8", "sync-byte", "crc8,sync-byte", "7bit", "crc8,7bit")
CLEAN = lab.Condition("250000 baud")
SLOW = lab.Condition("30 ms each way", latency=lab.LATENCY)
NOISY = lab.Condition("open-line noise", latency=lab.LATENCY, noise=True)
# A printer whose moves take their time (0.5 mm at 25 mm/s, a full planner), clean and at 1e-3.
BUSY = lab.Condition("busy printer", latency=lab.LATENCY, busy=True)
BUSY_ERRORS = lab.Condition("busy printer, bit errors 0.001", latency=lab.LATENCY, busy=True,
                            bit_error_rate=1e-3)


def errors_condition(rate: float) -> lab.Condition:
    return lab.Condition(f"bit errors {rate:g}", latency=lab.LATENCY, bit_error_rate=rate)


def _sizes(quick: bool) -> dict[str, int]:
    scale = 5 if quick else 1
    return {"clean": 1000 // scale, "1e-05": 6000 // scale, "0.0001": 2000 // scale,
            "0.001": 1000 // scale, "noise": 1000 // scale, "busy": 500 // scale,
            "samples": 60000 // scale}


def lab_section(quick: bool, jobs: int | None = None) -> Section:
    sizes = _sizes(quick)
    tasks: list[tuple[tuple[str, ...], Callable[..., Any], tuple[Any, ...]]] = []
    for variants in VARIANT_SETS:
        tasks.append((("stream", variants, CLEAN.name), lab.stream,
                      (variants, CLEAN, sizes["clean"])))
        tasks.append((("stream", variants, SLOW.name), lab.stream,
                      (variants, SLOW, sizes["clean"])))
        tasks.append((("stream", variants, NOISY.name), lab.stream,
                      (variants, NOISY, sizes["noise"])))
        for condition in (BUSY, BUSY_ERRORS):
            tasks.append((("stream", variants, condition.name), lab.stream,
                          (variants, condition, sizes["busy"])))
        for rate in lab.ERROR_RATES:
            condition = errors_condition(rate)
            tasks.append((("stream", variants, condition.name), lab.stream,
                          (variants, condition, sizes[f"{rate:g}"])))
    for variants in CHECKED:
        for rate in lab.ERROR_RATES:
            tasks.append((("undetected", variants, f"{rate:g}"), lab.undetected,
                          (variants, rate, sizes["samples"])))
    results = _run_all(tasks, jobs or min(4, len(os.sched_getaffinity(0))))
    return _section(results, sizes)


def _run_all(tasks, jobs: int) -> dict[tuple[str, ...], Any]:
    if jobs <= 1:
        return {key: function(*args) for key, function, args in tasks}
    with concurrent.futures.ProcessPoolExecutor(
            max_workers=jobs, mp_context=multiprocessing.get_context("spawn")) as executor:
        futures = {key: executor.submit(function, *args) for key, function, args in tasks}
        return {key: future.result() for key, future in futures.items()}


def _ratio(value: float, reference: float) -> float | None:
    return value / reference if reference else None


def _pct(ratio: float | None) -> str:
    return "—" if ratio is None else f"{100 * (ratio - 1):+.0f}%"


def _lost_per_error(run: lab.StreamResult, clean: lab.StreamResult) -> float | None:
    """Simulated seconds the errors cost, each: against the clean line's pace."""
    if not run.bit_errors or not clean.rate:
        return None
    return max(0.0, run.seconds - run.commands / clean.rate) / run.bit_errors


def _section(results: dict[tuple[str, ...], Any], sizes: dict[str, int]) -> Section:
    def run(variants: str, condition: str) -> lab.StreamResult:
        return results[("stream", variants, condition)]

    section = Section("lab", f"Protocol lab: Ultimaker's variants against plain v3, "
                      f"{sizes['clean']:,}-move jobs on simulated time",
                      ("figure", "measured", "plain v3"))
    base, slow = run(PLAIN, CLEAN.name), run(PLAIN, SLOW.name)

    def line_bits(result: lab.StreamResult) -> float:
        return result.to_printer * result.bit_times / result.commands

    def bytes_out(result: lab.StreamResult) -> float:
        return result.to_printer / result.commands

    crc8, seven, best = run("crc8", CLEAN.name), run("7bit", CLEAN.name), run(BEST, CLEAN.name)
    rows = section.rows
    rows.append(Row("crc8: bytes per command to the printer", f"{bytes_out(crc8):.1f}",
                    f"{bytes_out(base):.1f}", _ratio(bytes_out(crc8), bytes_out(base)),
                    "seed 5: -6%"))
    rows.append(Row("7bit: line time per command to the printer (bit times)",
                    f"{line_bits(seven):.0f}", f"{line_bits(base):.0f}",
                    _ratio(line_bits(seven), line_bits(base)), "seed 8: -12%"))
    rows.append(Row(f"{BEST}: commands/s at 250000 baud", f"{best.rate:,.0f}",
                    f"{base.rate:,.0f}", _ratio(best.rate, base.rate), "—"))
    best_slow = run(BEST, SLOW.name)
    rows.append(Row(f"{BEST}: commands/s at 30 ms each way", f"{best_slow.rate:,.1f}",
                    f"{slow.rate:,.1f}", _ratio(best_slow.rate, slow.rate),
                    "seed: 30 ms+ delays limit far more"))
    rows.append(Row("v3: commands/s at 30 ms each way, against 250000 baud alone",
                    f"{slow.rate:,.1f}", f"{base.rate:,.0f}", _ratio(slow.rate, base.rate),
                    "seed: 30 ms+ delays limit far more"))
    mid = errors_condition(1e-4).name
    ack_lost = _lost_per_error(run("ack", mid), run("ack", SLOW.name))
    v3_lost = _lost_per_error(run(PLAIN, mid), slow)
    rows.append(Row("ack: time lost per bit error at 1e-4", _ms(ack_lost), _ms(v3_lost),
                    _ratio(ack_lost or 0.0, v3_lost or 0.0), "seed 1: resends earlier"))
    busy_ack = _lost_per_error(run("ack", BUSY_ERRORS.name), run("ack", BUSY.name))
    busy_v3 = _lost_per_error(run(PLAIN, BUSY_ERRORS.name), run(PLAIN, BUSY.name))
    rows.append(Row("ack: time lost per bit error at 1e-3, busy printer", _ms(busy_ack),
                    _ms(busy_v3), _ratio(busy_ack or 0.0, busy_v3 or 0.0),
                    "seed 1: resends earlier"))
    harsh = errors_condition(1e-3).name
    compact, plain = run("compact-oob", harsh), run(PLAIN, harsh)
    rows.append(Row("compact-oob: bytes to the host per command at 1e-3",
                    f"{compact.to_host / compact.commands:.1f}",
                    f"{plain.to_host / plain.commands:.1f}",
                    _ratio(compact.to_host, plain.to_host), "seed 4: small gain"))
    checked8, checked16 = results[("undetected", "crc8", "0.001")], results[
        ("undetected", PLAIN, "0.001")]
    rows.append(Row("crc8: packets run damaged per 10^6 at 1e-3", _per_million(checked8),
                    _per_million(checked16), None, "seed 5: CRC16 is overkill"))
    noisy, noisy_sync = run(PLAIN, NOISY.name), run("sync-byte", NOISY.name)
    rows.append(Row("sync-byte: resends under open-line noise", f"{noisy_sync.resends}",
                    f"{noisy.resends}", _ratio(noisy_sync.resends, noisy.resends),
                    "seed 7: 0xFF the worst sync"))

    clean_table = Table(
        "A clean line: bytes and speed (ratio to plain v3)",
        ("variants", "bytes/cmd to printer", "bit times/cmd to printer", "bytes/cmd to host",
         "cmd/s at 250000 baud", "cmd/s at 30 ms each way"))
    for variants in VARIANT_SETS:
        fast, late = run(variants, CLEAN.name), run(variants, SLOW.name)
        clean_table.rows.append((
            variants, f"{bytes_out(fast):.1f} ({_pct(_ratio(bytes_out(fast), bytes_out(base)))})",
            f"{line_bits(fast):.0f} ({_pct(_ratio(line_bits(fast), line_bits(base)))})",
            f"{fast.to_host / fast.commands:.1f}",
            f"{fast.rate:,.0f} ({_pct(_ratio(fast.rate, base.rate))})",
            f"{late.rate:,.1f} ({_pct(_ratio(late.rate, slow.rate))})"))
    errors_table = Table(
        "Bit errors toward the printer, 250000 baud and 30 ms each way",
        ("variants", "rate", "errors", "resends", "time lost per error", "ran damaged",
         "bytes/cmd to host", "exactly once"))
    for rate, name, clean in [*((rate, errors_condition(rate).name, SLOW.name)
                                for rate in lab.ERROR_RATES), (1e-3, BUSY_ERRORS.name, BUSY.name)]:
        reference = _lost_per_error(run(PLAIN, name), run(PLAIN, clean))
        for variants in VARIANT_SETS:
            result = run(variants, name)
            lost = _lost_per_error(result, run(variants, clean))
            errors_table.rows.append((
                variants, f"{rate:g}" + (", busy printer" if clean == BUSY.name else ""),
                f"{result.bit_errors:,}", f"{result.resends:,}",
                f"{_ms(lost)} ({_pct(_ratio(lost or 0.0, reference or 0.0))})",
                f"{result.damaged}", f"{result.to_host / result.commands:.1f}",
                "yes" if result.exactly_once else f"NO {result.error}"))
    checks_table = Table(
        "What the check lets through: packets drawn with 2+ flipped bits, into the receiver",
        ("packets", "rate", "drawn", "ran damaged", "per 10^6 packets sent (95% bound)",
         "bits of line covered"))
    for variants in CHECKED:
        for rate in lab.ERROR_RATES:
            result = results[("undetected", variants, f"{rate:g}")]
            checks_table.rows.append((
                variants, f"{rate:g}", f"{result.samples:,}", f"{result.undetected:,}",
                _per_million(result), f"{result.bits_covered:.2g}"))
    noise_table = Table(
        f"Open-line noise: {lab.NOISE.hex(' ')} before {lab.NOISE_PROBABILITY:.0%} of packets "
        "(30 ms each way)",
        ("variants", "resends", "cmd/s", "exactly once"))
    for variants in VARIANT_SETS:
        result = run(variants, NOISY.name)
        noise_table.rows.append((variants, f"{result.resends}",
                                 f"{result.rate:,.1f} ({_pct(_ratio(result.rate, noisy.rate))})",
                                 "yes" if result.exactly_once else f"NO {result.error}"))
    section.tables += [clean_table, errors_table, checks_table, noise_table]
    section.notes += [
        "simulated time (trio's MockClock): the figures are the protocol's, the same on any "
        "machine; the printer runs its moves at once, so the line is the limit",
        f"payloads: moves of {bytes_out(base) - 6:.1f} bytes on average (seed 000: about 30)",
        "time lost per error: the run's time beyond the clean line's pace, over the bytes a "
        "bit error hit",
        "ran damaged: job commands the journal shows other than sent; the check table draws "
        "packets with two or more flipped bits (fewer are always caught) and weighs each by "
        "that chance",
    ]
    return section


def _ms(seconds: float | None) -> str:
    return "—" if seconds is None else f"{1000 * seconds:.1f} ms"


def _per_million(result: lab.UndetectedResult) -> str:
    if not result.undetected:
        return f"0 (< {result.upper_per_million:.2g})"
    return f"{result.per_million:.3g} (< {result.upper_per_million:.2g})"
