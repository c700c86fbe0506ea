"""The wire log of a report: every record as (time, kind, text) a person can read and search.

Bytes are shown as text where they are printable ASCII; a newline and a return as \\n and
\\r; a backslash as \\\\; every other byte as \\xNN, so binary protocols (Ultimaker packets,
CommStack frames) read as what they are, byte for byte.
"""

import json

from fake_marlin.emulator.report.reader import Trace

# The kinds as the log's filters name them, in the order they are offered.
LABELS = {
    "in": "in (to printer)",
    "out": "out (to host)",
    "cmd": "cmd",
    "reject": "reject",
    "fault": "fault",
    "reset": "reset",
    "connect": "connect",
    "disconnect": "disconnect",
    "room": "room",
    "temp": "temp",
    "verdict": "verdict",
    "begin": "begin",
    "end": "end",
}
# Shown unless a reader ticks them: a sample every second would bury the conversation.
HIDDEN = frozenset({"room", "temp"})
_ESCAPES = {0x0A: "\\n", 0x0D: "\\r", 0x5C: "\\\\"}
_SHOWN = [_ESCAPES.get(code) or (chr(code) if 0x20 <= code < 0x7F else f"\\x{code:02x}")
          for code in range(256)]


def show_bytes(data: str) -> str:
    """Bytes as the trace holds them (one code point each, latin-1) in the log's spelling."""
    return "".join(_SHOWN[ord(char)] if ord(char) < 256 else f"\\u{ord(char):04x}" for char in data)


def _fault_label(record: dict) -> str:
    parts = [str(record["f"])]
    if record.get("dir"):
        parts.append(str(record["dir"]))
    if record.get("n") is not None:
        parts.append(f"n={record['n']}")
    if record.get("u") is not None:
        parts.append(f"on {record['u']!r}")
    return " ".join(parts)


def describe(record: dict) -> str:
    """A record as a person reads it: in the log, and as the label of its mark on the plot."""
    match record["k"]:
        case "in" | "out":
            return show_bytes(record["b"])
        case "cmd":
            return str(record["c"])
        case "room":
            return f"{record['v']} free blocks"
        case "temp":
            return f"{record['h']} {float(record['c']):.1f} °C, target {float(record['s']):g} °C"
        case "fault":
            return _fault_label(record)
        case "reject":
            resend = record.get("resend")
            return f"{record.get('why') or 'rejected'}" + ("" if resend is None else f"; resend {resend}")
        case "reset":
            return str(record.get("why", "")).strip()
        case "connect":
            return "a host opened the port"
        case "disconnect":
            return f"line dead for {record.get('seconds', '?')} s"
        case "verdict":
            return str(record.get("text") or ("passed" if record.get("passed") else "failed"))
        case "begin":
            keys: tuple[str, ...] = ("protocol", "speed", "seed", "scenario", "printer", "planner")
            return ", ".join(f"{key} {record.get(key)}" for key in keys if key in record)
        case "end":
            keys = ("commands", "bytes_in", "bytes_out")
            return ", ".join(f"{key} {record.get(key)}" for key in keys if key in record)
    return ""


def log_rows(trace: Trace) -> tuple[list[str], list[list[object]]]:
    """(kinds, rows): each row [t, index into kinds, text], in trace order."""
    kinds = list(LABELS)
    index = {kind: i for i, kind in enumerate(kinds)}
    rows: list[list[object]] = []
    for record in [trace.begin, *trace.records]:
        rows.append([round(float(record["t"]), 3), index[record["k"]], describe(record)])
    return kinds, rows


def embed_json(value: object) -> str:
    """JSON that is safe inside a <script> element: no `</script>` or `<!--` can end it."""
    text = json.dumps(value, ensure_ascii=False, separators=(",", ":"))
    return text.replace("<", "\\u003c").replace("\u2028", "\\u2028").replace("\u2029", "\\u2029")
