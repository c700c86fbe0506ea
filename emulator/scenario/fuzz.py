"""Random fault mixes: complete scenarios, each a pure function of (protocol, seed, number).

`fake-marlin scenario fuzz` (campaign.py runs them) draws cases from `random.Random` seeded with
the string `"<seed>/<protocol>/<number>"`: one generator per case, so case 7 of a campaign is the
same whether the campaign runs 10 cases or 500, and a failure is named by its file alone
(`<protocol>-<seed>-<number>.toml`). Each case first draws a harshness h in [0, 1), then each
kind of fault appears with chance h (some kinds once or twice): about one case in twelve has no
fault at all, some have everything. What a case may draw:

- bit errors and dropped bytes, each way, at a rate up to 1e-3 (per bit, per byte), drawn on a
  log scale, so that 1e-6 is as likely as 1e-4;
- unit faults, drop, duplicate and truncate, each way, with a probability trigger up to 5% per
  unit (sometimes only on acknowledgements: `pattern = "^ok"`, Ultimaker's `"^o"`), for every
  protocol: the fault layer frames each wire format (lines, Ultimaker packets, Repetier's
  binary commands, CommStack's COBS frames), except duplicated requests toward a CommStack
  printer (APPEND_ONLY says why);
- garbage bursts, at a moment (`at`) or by chance per unit; link stalls of up to 6 s (less
  than the host's patience: 8 transmissions, 2 s apart);
- latency with jitter on the printer's line;
- the host dropping the port mid-print and reconnecting (`[host] disconnect_after`), or a
  pulled cable (`disconnect` fault) that the host reconnects after (`[host] reconnect_after`):
  streaming protocols only (the loader refuses a CommStack host that drops its port, and a
  CommStack host that reconnects starts its whole upload and print again). Never both in one
  case: run_scenario's host reconnects after a hang-up only in the print that follows its own
  disconnect, so a cable pulled before that would end the run with ConnectionLost;
- a printer reboot (the `reboot` fault), in a case of its own kind, see below;
- a job of a few hundred moves (`[job] moves`, 200 to 400 unless the caller fixes it).

Three kinds of case, each with the expectation that is true of a correct host:

- exactly-once (most): `outcome = "completed"`, `exactly_once = true`, and
  `allow_undetectable = true`, since damage the protocol's own check cannot see (Marlin's XOR
  misses some double flips) is what the firmware does too: verify classifies it as ran damaged,
  and the campaign counts it apart.
- reconnect: the same faults plus a port the host drops or a cable pulled. A command in flight
  when the line goes may have run without its acknowledgement coming back; the host cannot know,
  sends it again, and the printer, reset by the reopening, runs it again. Exactly once cannot
  hold, so the expectation is the shipped reconnect scenarios' (`um-host-disconnects-mid-print`,
  `um-cable-unplugged`): completed, `missing = 0`, and `duplicated_at_most` what can be in flight
  at each disconnect (Ultimaker: the window; Marlin: one line; Repetier: the most job commands
  that fit in the firmware's 127-byte receive buffer, the host's flow control, and one more:
  Repetier acknowledges a command when it is queued, before it runs, so the reset of the
  reopening may lose it, and a host that loses nothing must send it again too).
- reset: a printer reboot (`reboot` at the Nth command, well inside the job) loses what the
  printer had queued, and no host can put it back: a reset mid-print is not something to
  survive but to report. So reboots are never mixed into the exactly-once cases; a reset case
  expects what the shipped `*-printer-resets-mid-print.toml` expect: `outcome = "failed"`,
  `error = "PrinterReset"`, whatever else the line suffers (no disconnects, which would make
  ConnectionLost an equally right answer). For every protocol, CommStack too: a host that says
  "completed" for a print its printer dropped has lost commands silently.

Every case is a valid scenario file: the loader's rules (no `at` for drop, duplicate and
truncate; no `disconnect_after` for CommStack) are kept here, and the tests load hundreds.
The mapping from seed to cases is stable for one version of this module, not across changes
to what it draws.
"""

import math
import random
from typing import Any

import tomli_w

from fake_marlin.emulator.scenario.definition import DIRECTIONS, generated_job

PROTOCOLS = ("ultimaker", "marlin", "repetier", "commstack")
STREAMING = ("ultimaker", "marlin", "repetier")

MAX_RATE = 1e-3  # bit errors (per bit) and dropped bytes (per byte)
MIN_RATE = 1e-6
MAX_UNIT_PROBABILITY = 0.05  # drop, duplicate, truncate: chance per unit
# Protocols whose requests carry no sequence number and whose file writes only append: a
# request frame the line duplicates is two writes, which nothing on the wire tells from two
# the host sent (CommStack). The host sees it in the file's length and starts the upload over,
# so a print never runs damaged, but at a few percent of frames no upload gets through: the
# campaign duplicates only their answers.
APPEND_ONLY = frozenset({"commstack"})
MIN_UNIT_PROBABILITY = 1e-3
MAX_STALL = 6.0  # seconds
RESET_SHARE = 0.15  # of the cases: a printer reboot, expected to be reported
MOVES = (200, 400)  # a job's moves, unless the caller fixes them
# Each kind of acknowledgement, for unit faults that hit only those.
ACK_PATTERNS = {"ultimaker": "^o", "marlin": "^ok", "repetier": "^ok"}
SECONDS_PER_MOVE = 0.4  # about what a generated job takes (simulated); `at` triggers fall inside

Table = dict[str, Any]


def case_name(protocol: str, seed: int, number: int, firmware: str = "marlin") -> str:
    """The case's name, and its file's stem: `marlin-1-7`."""
    if firmware != "marlin":
        return f"{protocol}-{firmware}-{seed}-{number}"
    return f"{protocol}-{seed}-{number}"


def case_random(protocol: str, seed: int, number: int) -> random.Random:
    """The case's own generator (a string seed: the same under any PYTHONHASHSEED)."""
    return random.Random(f"{seed}/{protocol}/{number}")


def generate(protocol: str, seed: int, number: int, moves: int | None = None,
             firmware: str = "marlin") -> Table:
    """Case `number` of the campaign `seed` for `protocol`: a scenario, as its TOML tables.
    `firmware`: the printer's (the same faults for every firmware of one seed and number)."""
    if protocol not in PROTOCOLS:
        raise ValueError(f"protocol must be one of {', '.join(PROTOCOLS)}, not {protocol!r}")
    draw = case_random(protocol, seed, number)
    harshness = draw.random()

    def some(most: int = 1) -> int:
        return draw.randint(1, most) if draw.random() < harshness else 0

    moves = moves if moves is not None else draw.randint(*MOVES)
    commands = len(generated_job(moves))
    horizon = max(1.0, moves * SECONDS_PER_MOVE)
    reset = draw.random() < RESET_SHARE
    streaming = protocol in STREAMING

    faults: list[Table] = []
    printer: Table = {"protocol": protocol}
    if firmware != "marlin":
        printer["firmware"] = firmware
    host: Table = {"protocol": protocol}
    for direction in DIRECTIONS:
        for kind in ("bit-errors", "drop-bytes"):
            if some():
                faults.append({"kind": kind, "direction": direction,
                               "rate": _log_uniform(draw, MIN_RATE, MAX_RATE)})
    for kind in ("drop", "duplicate", "truncate"):
        for _ in range(some(2)):
            direction = draw.choice(DIRECTIONS)
            if kind == "duplicate" and protocol in APPEND_ONLY:
                direction = "to-host"
            chance = _log_uniform(draw, MIN_UNIT_PROBABILITY, MAX_UNIT_PROBABILITY)
            fault: Table = {"kind": kind, "direction": direction, "probability": chance}
            if direction == "to-host" and protocol in ACK_PATTERNS and draw.random() < 0.3:
                fault["pattern"] = ACK_PATTERNS[protocol]
            if kind == "truncate" and draw.random() < 0.5:
                fault["length"] = draw.randint(1, 12)
            faults.append(fault)
    for _ in range(some(2)):
        fault = {"kind": "garbage", "direction": draw.choice(DIRECTIONS),
                 "length": draw.randint(1, 80)}
        if draw.random() < 0.5:
            fault["at"] = round(draw.uniform(0.0, horizon), 2)
        else:
            fault["probability"] = _log_uniform(draw, 1e-3, 1e-2)
        faults.append(fault)
    for _ in range(some(2)):
        fault = {"kind": "stall", "direction": draw.choice(DIRECTIONS),
                 "seconds": round(draw.uniform(0.1, MAX_STALL), 2)}
        trigger = draw.choice(("at", "nth", "probability"))
        if trigger == "at":
            fault["at"] = round(draw.uniform(0.0, horizon), 2)
        elif trigger == "nth":
            fault["nth"] = draw.randint(1, commands)
        else:
            fault["probability"] = _log_uniform(draw, 1e-3, 1e-2)
            fault["times"] = draw.randint(1, 3)
        faults.append(fault)
    if some():
        printer["latency_ms"] = draw.randint(1, 50)
        if draw.random() < 0.5:
            printer["jitter_ms"] = draw.randint(1, 30)
    if protocol == "ultimaker":
        host["window"] = draw.randint(1, 3)

    disconnects = 0
    if reset:
        low, high = max(1, commands // 5), max(1, commands * 3 // 5)
        faults.append({"kind": "reboot", "nth": draw.randint(low, high)})
    elif streaming and some():
        # One or the other: run_scenario reconnects after a pulled cable only once the host
        # has dropped its port on purpose, not before (see the module's docstring).
        if draw.random() < 0.5:
            host["disconnect_after"] = draw.randint(min(5, commands), max(5, commands - 5))
            disconnects += 1
        else:
            fault = {"kind": "disconnect", "direction": draw.choice(DIRECTIONS),
                     "seconds": round(draw.uniform(0.5, 5.0), 2)}
            if draw.random() < 0.5:
                fault["at"] = round(draw.uniform(1.0, horizon), 2)
            else:
                fault["nth"] = draw.randint(min(10, commands), commands)
            faults.append(fault)
            host["reconnect_after"] = round(draw.uniform(0.5, 8.0), 2)
            disconnects += 1

    expect: Table
    if reset:
        kind, expect = "reset", {"outcome": "failed", "error": "PrinterReset"}
    elif disconnects:
        kind = "reconnect"
        most = disconnects * in_flight(protocol, moves, host.get("window", 3))
        expect = {"outcome": "completed", "missing": 0, "duplicated_at_most": most}
    else:
        kind = "exactly-once"
        expect = {"outcome": "completed", "exactly_once": True, "allow_undetectable": True}
    table: Table = {
        "name": case_name(protocol, seed, number, firmware),
        "description": (f"fake-marlin scenario fuzz --protocol {protocol}"
                        + (f" --firmware {firmware}" if firmware != "marlin" else "")
                        + f" --seed {seed}: "
                        f"case {number}, {kind}, harshness {harshness:.2f}, {len(faults)} faults"),
        "seed": draw.randrange(2**31),
        "printer": printer,
    }
    if faults:
        table["fault"] = faults
    table["job"] = {"moves": moves}
    table["host"] = host
    table["expect"] = expect
    return table


def case_kind(table: Table) -> str:
    """exactly-once, reconnect or reset: what the case expects (see the module's docstring)."""
    expect = table.get("expect", {})
    if expect.get("error") == "PrinterReset":
        return "reset"
    return "reconnect" if "duplicated_at_most" in expect else "exactly-once"


def in_flight(protocol: str, moves: int, window: int = 3) -> int:
    """The most job commands that can be in flight at once, unacknowledged: what one disconnect
    may make run twice."""
    if protocol == "ultimaker":
        return window
    if protocol == "repetier":
        # What fits in the firmware's receive buffer (the host's flow control), plus the command
        # in its one-command buffer: acknowledged when queued, before it runs, so a reset may
        # lose it, and a host that loses nothing must send it again as well.
        from fake_marlin.host.codecs.repetier import encode_command
        from fake_marlin.host.cores.repetier import RECEIVE_CACHE

        sizes = [min(len(encode_command(1000, command, version)[0]) for version in (1, 2))
                 for command in generated_job(moves)]
        most = 1
        for start in range(len(sizes)):
            total, count = 0, 0
            for size in sizes[start:]:
                if count and total + size > RECEIVE_CACHE:
                    break
                total, count = total + size, count + 1
            most = max(most, count)
        return most + 1
    # Marlin: one line in flight, and the two before it, which a host resends after a lost port
    # (MarlinClient.acknowledged_ahead: an ok that is not the line's counts a line done too soon).
    return 3


def scenario_text(table: Table, comment: str | None = None) -> str:
    """The scenario as a TOML file; `comment`, one line, goes first (`# comment`)."""
    # tomli-w writes an array of small tables inline; a scenario file's faults read better as
    # [[fault]] tables, as the shipped ones are written, so each table is written on its own.
    top = {key: value for key, value in table.items() if not isinstance(value, (dict, list))}
    chunks = [tomli_w.dumps(top)] if top else []
    for key, value in table.items():
        if isinstance(value, dict):
            chunks.append(tomli_w.dumps({key: value}))
        elif isinstance(value, list) and all(isinstance(item, dict) for item in value):
            chunks += [f"[[{key}]]\n" + tomli_w.dumps(item) for item in value]
        elif isinstance(value, list):
            raise ValueError(f"{key}: only lists of tables are written as scenario tables")
    text = "\n".join(chunks)
    if comment is None:
        return text
    return f"# {one_line(comment)}\n{text}"


def one_line(text: str, limit: int = 400) -> str:
    """`text` fit for a TOML comment: one line, no control characters, not too long."""
    text = " ".join(text.split())
    text = "".join(c if c.isprintable() and c != "\x7f" else f"\\x{ord(c):02x}" for c in text)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _log_uniform(draw: random.Random, low: float, high: float) -> float:
    """A rate between `low` and `high`, uniform on a log scale, to two significant figures."""
    value = math.exp(draw.uniform(math.log(low), math.log(high)))
    return min(high, float(f"{value:.2g}"))
