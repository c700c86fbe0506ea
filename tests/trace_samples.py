"""Traces made by hand, as docs/trace.md specifies them, for the report's tests.

TraceBuilder writes records one by one at a clock the test moves; marlin_print() makes a
small but complete print over a noisy Marlin line (heating, the planner filling and draining,
corrupted lines that draw resends, a reset), and big_trace() one of a given number of records.
"""

import gzip
import json
from pathlib import Path


class TraceBuilder:
    def __init__(self, protocol: str = "marlin", scenario: str | None = None, seed: int = 0,
                 planner: int = 15, speed: float = 1.0) -> None:
        self.t = 0.0
        self.records: list[dict] = []
        self.commands = self.bytes_in = self.bytes_out = 0
        self.record("begin", version=1, protocol=protocol, speed=speed, seed=seed,
                    scenario=scenario, printer=1, planner=planner)

    def at(self, t: float) -> "TraceBuilder":
        assert t >= self.t, "t never goes back"
        self.t = t
        return self

    def record(self, kind: str, **fields: object) -> "TraceBuilder":
        # `w` grows with the records: like a real trace's, it is no function of `t`.
        self.records.append({"t": round(self.t, 6), "w": round(len(self.records) * 1e-4, 3),
                             "k": kind, **fields})
        return self

    def host(self, data: str | bytes) -> "TraceBuilder":
        text = data.decode("latin-1") if isinstance(data, bytes) else data
        self.bytes_in += len(text)
        return self.record("in", b=text)

    def printer(self, data: str | bytes) -> "TraceBuilder":
        text = data.decode("latin-1") if isinstance(data, bytes) else data
        self.bytes_out += len(text)
        return self.record("out", b=text)

    def cmd(self, command: str) -> "TraceBuilder":
        self.commands += 1
        return self.record("cmd", c=command)

    def end(self) -> "TraceBuilder":
        return self.record("end", commands=self.commands, bytes_in=self.bytes_in,
                           bytes_out=self.bytes_out)

    def text(self) -> str:
        return "".join(json.dumps(record, ensure_ascii=False) + "\n" for record in self.records)

    def write(self, path: Path) -> Path:
        data = self.text().encode("utf-8")
        if path.name.endswith(".gz"):
            data = gzip.compress(data, compresslevel=1, mtime=0)  # read back, not kept
        path.write_bytes(data)
        return path


def checksum(line: str) -> int:
    value = 0
    for char in line:
        value ^= ord(char)
    return value


def marlin_print(moves: int = 60, noise_every: int = 17, verdict: bool = True,
                 seed: int = 3) -> TraceBuilder:
    """A print of `moves` moves; every `noise_every`-th line arrives with a flipped bit, is
    refused with Error:/Resend: and sent again. The planner (15 blocks) fills as the host
    streams and drains at the end; the hotend heats to 200 °C and the bed to 60 °C."""
    trace = TraceBuilder("marlin", "hand-made noisy print" if verdict else None, seed)
    trace.record("reset", why="PowerUp").printer("start\n")
    trace.record("room", v=15)
    trace.record("connect").record("reset", why=" External Reset").printer("start\n")
    job = ["M104 S200", "M140 S60", *(f"G1 X{i % 50} Y{i % 37} F3000" for i in range(moves)),
           "M104 S0", "M140 S0"]
    hotend = bed = 21.0
    hotend_target = bed_target = 0.0
    free = 15
    number = 0
    next_sample = 0.0
    for index, command in enumerate(job):
        number += 1
        line = f"N{number} {command}"
        wire = f"{line}*{checksum(line)}\n"
        trace.at(trace.t + 0.05)
        if index and index % noise_every == 0:
            damaged = wire[:3] + chr(ord(wire[3]) ^ 0x04) + wire[4:]
            trace.record("fault", f="bit-errors", dir="to-printer", n=1)
            trace.host(damaged)
            trace.record("reject", why="checksum mismatch", resend=number)
            trace.printer(f"Error:checksum mismatch, Last Line: {number - 1}\nResend: {number}\nok\n")
            trace.at(trace.t + 0.05)
        trace.host(wire)
        if command.startswith("G1"):
            while free == 0:  # the planner is full: a block finishes before this one fits
                trace.at(trace.t + 0.4)
                free += 1
                trace.record("room", v=free)
            free -= 1
        trace.cmd(command)
        if command.startswith("M104"):
            hotend_target = float(command.split("S")[1])
        if command.startswith("M140"):
            bed_target = float(command.split("S")[1])
        trace.record("room", v=free)
        trace.printer("ok\n")
        if trace.t >= next_sample or command.startswith(("M104", "M140")):
            hotend += (hotend_target - hotend) * 0.08 if hotend_target else (21 - hotend) * 0.02
            bed += (bed_target - bed) * 0.03 if bed_target else (21 - bed) * 0.01
            trace.record("temp", h="T0", c=round(hotend, 2), s=hotend_target)
            trace.record("temp", h="B", c=round(bed, 2), s=bed_target)
            next_sample = trace.t + 1.0
    while free < 15:  # the planner drains once the host has sent everything
        trace.at(trace.t + 0.4)
        free += 1
        trace.record("room", v=free)
    if verdict:
        trace.at(trace.t + 10).record(
            "verdict", passed=True, outcome="completed", job=len(job), ran=len(job),
            exactly_once=True, missing=[], duplicated=[],
            host={"resends": moves // noise_every, "timeouts": 0},
            text=f"PASS  hand-made noisy print\n      completed; {len(job)} commands executed",
        )
    return trace.end()


def big_trace(records: int) -> TraceBuilder:
    """About `records` records of a long print: commands, replies, room, heater samples."""
    trace = TraceBuilder("marlin", "a long print", planner=15)
    trace.record("reset", why="PowerUp").record("connect")
    number = 0
    while len(trace.records) < records:
        number += 1
        line = f"N{number} G1 X{number % 200 / 3:.3f} Y{number % 170 / 7:.3f} E{number / 50:.4f}"
        trace.at(trace.t + 0.2).host(f"{line}*{checksum(line)}\n")
        trace.cmd(line.split(" ", 1)[1]).record("room", v=number % 3).printer("ok\n")
        if number % 5 == 0:
            trace.record("temp", h="T0", c=200 + number % 3 * 0.4, s=200)
            trace.record("temp", h="B", c=60 - number % 2 * 0.2, s=60)
        if number % 997 == 0:
            trace.record("fault", f="bit-errors", dir="to-printer", n=2)
            trace.record("reject", why="checksum mismatch", resend=number)
    return trace.end()
