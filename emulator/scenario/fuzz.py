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
  unit (sometimes only on acknowledgements: `pattern = "^ok"`, Ultimaker's `"^o"`, g2core's
  responses `'^\\{"r"'`), for every protocol: the fault layer frames each wire format (lines,
  Ultimaker packets, Repetier's binary commands, CommStack's COBS frames, g2core's lines),
  except duplicated requests toward a CommStack printer (APPEND_ONLY says why) or a g2core
  board (UNSEQUENCED: g2core checks a line's checksum but never its number, so a line the wire
  duplicates runs twice, and nothing on the wire tells it from a line a host sent again);
- garbage bursts, at a moment (`at`) or by chance per unit (toward a g2core board, noise
  without an N word: NUMBERED_BY_ANY_LINE says why); link stalls of up to 6 s (less than the
  host's patience: 8 transmissions, 2 s apart);
- latency with jitter on the printer's line;
- the host dropping the port mid-print and reconnecting (`[host] disconnect_after`), or a
  pulled cable (`disconnect` fault) that the host reconnects after (`[host] reconnect_after`):
  streaming protocols only, g2core's among them (the loader refuses a CommStack host that
  drops its port, and a CommStack host that reconnects starts its whole upload and print
  again). Never both in one case: run_scenario's host reconnects after a hang-up only in the
  print that follows its own disconnect, so a cable pulled before that would end the run with
  ConnectionLost;
- a printer reboot (the `reboot` fault), in a case of its own kind, see below;
- a job of a few hundred moves (`[job] moves`, 200 to 400 unless the caller fixes it).

Three kinds of case, each with the expectation that is true of a correct host:

- exactly-once (most): `outcome = "completed"`, `exactly_once = true`, and
  `allow_undetectable = true`, since damage the protocol's own check cannot see (Marlin's XOR
  misses some double flips; g2core runs a line whose `*` is damaged unchecked) is what the
  firmware does too: verify classifies it as ran damaged, and the campaign counts it apart.
- reconnect: the same faults plus a port the host drops or a cable pulled. A command in flight
  when the line goes may have run without its acknowledgement coming back; the host cannot know,
  sends it again, and the printer, reset by the reopening, runs it again. Exactly once cannot
  hold, so the expectation is the shipped reconnect scenarios' (`um-host-disconnects-mid-print`,
  `um-cable-unplugged`): completed, `missing = 0`, and `duplicated_at_most` what can be in flight
  at each disconnect (Ultimaker: the window; Marlin: one line; Repetier: the most job commands
  that fit in the firmware's 127-byte receive buffer, the host's flow control, and one more:
  Repetier acknowledges a command when it is queued, before it runs, so the reset of the
  reopening may lose it, and a host that loses nothing must send it again too; g2core: the one
  line a host keeps in flight, since a board on native USB runs on, resets nothing when the port
  opens, and runs what it answered).
- reset: a printer reboot (`reboot` at the Nth command, well inside the job) loses what the
  printer had queued, and no host can put it back: a reset mid-print is not something to
  survive but to report. So reboots are never mixed into the exactly-once cases; a reset case
  expects what the shipped `*-printer-resets-mid-print.toml` expect: `outcome = "failed"`,
  `error = "PrinterReset"`, whatever else the line suffers (no disconnects, which would make
  ConnectionLost an equally right answer). For every protocol, CommStack too: a host that says
  "completed" for a print its printer dropped has lost commands silently. (A g2core board's
  banner may be lost or late; its host also knows the reset by the board's JSON verbosity gone
  back to the default.)

With `variants` (the protocol lab's, Ultimaker only) the printer and the host speak them, and
the faults are those of the plain case of the same seed and number: each variant meets the
same line. Its files are named `ultimaker-<variants, + between>-<seed>-<n>.toml`.

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
from fake_marlin.wire.ultimaker_variants import PLAIN, Variants

PROTOCOLS = ("ultimaker", "marlin", "repetier", "commstack", "g2core")
STREAMING = ("ultimaker", "marlin", "repetier", "g2core")
# The printer's firmware where only one speaks the protocol (its files are not named after it).
FIRMWARES = {"g2core": "g2core"}

MAX_RATE = 1e-3  # bit errors (per bit) and dropped bytes (per byte)
MIN_RATE = 1e-6
MAX_UNIT_PROBABILITY = 0.05  # drop, duplicate, truncate: chance per unit
# Protocols whose requests carry no sequence number and whose file writes only append: a
# request frame the line duplicates is two writes, which nothing on the wire tells from two
# the host sent (CommStack). The host sees it in the file's length and starts the upload over,
# so a print never runs damaged, but at a few percent of frames no upload gets through: the
# campaign duplicates only their answers.
APPEND_ONLY = frozenset({"commstack"})
# Protocols whose printer runs a numbered line that comes twice twice: g2core checks a line's
# checksum but never its number (cm_check_linenum() is dead code: the parser clears the flag
# that would call it), so a line the wire duplicates is two lines to the board, as a line a
# host sends again is; no host can tell them apart or stop the second. The campaign duplicates
# only their answers.
UNSEQUENCED = frozenset({"g2core"})
# Protocols whose printer takes a line number from any line it runs: g2core's model line number
# is the last N word of whatever line ran, and in Marlin flavour (after an E word, as in every
# generated job) a letter without a number reads 0, so the ESP32 boot noise `ets Jun  8` is a
# line N8 that runs. Such noise would make the board's line number lie about the host's line,
# and with that line's answer lost, no host could tell whether it ran. The campaign's garbage
# toward them is the boot-loader noise without its N word (GARBAGE_WORDS).
NUMBERED_BY_ANY_LINE = frozenset({"g2core"})
# The fault layer's boot-loader noise (emulator/faults/rules.py, FaultPlan.garbage), but the
# words with an N and a number.
GARBAGE_WORDS = (b"DBG ", b"stack ", b"0x3ffb", b"rst:0x8 ", b"\x00", b"\xff", b"boot:0x13 ",
                 b"\r\n", b"load:0x4008 ")
MIN_UNIT_PROBABILITY = 1e-3
MAX_STALL = 6.0  # seconds
RESET_SHARE = 0.15  # of the cases: a printer reboot, expected to be reported
MOVES = (200, 400)  # a job's moves, unless the caller fixes them
# Each kind of acknowledgement, for unit faults that hit only those.
ACK_PATTERNS = {"ultimaker": "^o", "marlin": "^ok", "repetier": "^ok", "g2core": '^\\{"r"'}
SECONDS_PER_MOVE = 0.4  # about what a generated job takes (simulated); `at` triggers fall inside

Table = dict[str, Any]


def case_name(protocol: str, seed: int, number: int, firmware: str = "marlin",
              variants: Variants = PLAIN) -> str:
    """The case's name, and its file's stem: `marlin-1-7`, `ultimaker-ack+crc8-1-7`."""
    if not variants.plain:
        return f"{protocol}-{'+'.join(variants.names)}-{seed}-{number}"
    if firmware not in ("marlin", FIRMWARES.get(protocol, "marlin")):
        return f"{protocol}-{firmware}-{seed}-{number}"
    return f"{protocol}-{seed}-{number}"


def case_random(protocol: str, seed: int, number: int) -> random.Random:
    """The case's own generator (a string seed: the same under any PYTHONHASHSEED)."""
    return random.Random(f"{seed}/{protocol}/{number}")


def generate(protocol: str, seed: int, number: int, moves: int | None = None,
             firmware: str = "marlin", variants: Variants = PLAIN) -> Table:
    """Case `number` of the campaign `seed` for `protocol`: a scenario, as its TOML tables.
    `firmware`: the printer's (the same faults for every firmware of one seed and number);
    marlin means the protocol's own where only one firmware speaks it (FIRMWARES)."""
    if protocol not in PROTOCOLS:
        raise ValueError(f"protocol must be one of {', '.join(PROTOCOLS)}, not {protocol!r}")
    if not variants.plain and protocol != "ultimaker":
        raise ValueError(f"protocol variants are Ultimaker's, not {protocol}'s")
    if firmware == "marlin":
        firmware = FIRMWARES.get(protocol, firmware)
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
    if not variants.plain:
        printer["variants"] = list(variants.names)  # the host speaks the printer's
    for direction in DIRECTIONS:
        for kind in ("bit-errors", "drop-bytes"):
            if some():
                faults.append({"kind": kind, "direction": direction,
                               "rate": _log_uniform(draw, MIN_RATE, MAX_RATE)})
    for kind in ("drop", "duplicate", "truncate"):
        for _ in range(some(2)):
            direction = draw.choice(DIRECTIONS)
            if kind == "duplicate" and protocol in APPEND_ONLY | UNSEQUENCED:
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
        if protocol in NUMBERED_BY_ANY_LINE and fault["direction"] == "to-printer":
            fault["text"] = _garbage_without_line_numbers(draw, fault.pop("length"))
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
        "name": case_name(protocol, seed, number, firmware, variants),
        "description": (f"fake-marlin scenario fuzz --protocol {protocol}"
                        + (f" --firmware {firmware}"
                           if firmware not in ("marlin", FIRMWARES.get(protocol)) else "")
                        + (f" --variant {variants}" if not variants.plain else "")
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
    if protocol == "g2core":
        # One line at a time (g2core cannot sequence more): the one whose fate the host did not
        # know yet. The board runs on while the port is closed (native USB), so what it had
        # answered it runs, and the host sends none of that again.
        return 1
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


def _garbage_without_line_numbers(draw: random.Random, length: int) -> str:
    """Boot-loader noise of `length` bytes, drawn from GARBAGE_WORDS (as Latin-1 text)."""
    out = bytearray()
    while len(out) < length:
        out += draw.choice(GARBAGE_WORDS)
    return out[:length].decode("latin-1")


def _log_uniform(draw: random.Random, low: float, high: float) -> float:
    """A rate between `low` and `high`, uniform on a log scale, to two significant figures."""
    value = math.exp(draw.uniform(math.log(low), math.log(high)))
    return min(high, float(f"{value:.2g}"))
