"""g2core's JSON protocol on the wire, both ways (docs/protocols.md section 7): its relaxed JSON,
its numbers, the response envelope and footer, the status codes, the single-character commands.

Read from g2core's source (synthetos/g2, edge @ c5b1cd72 = 101.03, master @ 1ff7f600 = 100.26):
json_parser.cpp, util.cpp floattoa(), error.h, xio.cpp, controller.cpp.
"""

import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

FOOTER_REVISION = 1  # json_parser.h:38, the footer's first element
JSON_INPUT_STRING_MAX = 512  # json_parser.h:40: a longer request is refused with 107
TOKEN_LEN = 6  # config.h:189: a longer name is refused with 107
NV_BODY_LEN = 40  # config.h:182: at most 39 name:value pairs, else 112
PLANNER_QUEUE_SIZE = 48  # planner.h:229: the idle `qr`
PLANNER_HEADROOM = 4  # planner.cpp:482-486: G-code is read only with this many buffers free

# Single characters that act at once, when they are the first byte of a line (xio.cpp:733-748).
FEEDHOLD = ord("!")
CYCLE_START = ord("~")
QUEUE_FLUSH = ord("%")  # a control only while a hold exists; a line of data otherwise
KILL_JOB = 0x04  # ^D, 101.x
ENQ = 0x05  # answered {"ack":true}
RESET = 0x18  # ^X
SINGLE_CHARACTERS = frozenset({FEEDHOLD, CYCLE_START, QUEUE_FLUSH, KILL_JOB, ENQ, RESET})

# error.h: the codes a host meets, and get_status_message()'s texts for them.
STATUS_MESSAGES: Mapping[int, str] = {
    0: "OK", 1: "Error", 2: "Eagain", 3: "No operation performed", 4: "Completed operation",
    5: "System shutdown", 6: "System panic", 13: "Buffer full non-fatal", 15: "Initializing",
    18: "System alarm", 20: "Internal error",
    100: "Unrecognized command or config name", 101: "Invalid or malformed command",
    102: "Bad number format", 103: "Unsupported number or JSON type",
    104: "Parameter is read-only", 105: "Parameter cannot be read", 106: "Command not accepted",
    107: "Input exceeds max length", 108: "Input less than minimum value",
    109: "Input exceeds maximum value", 110: "Input value range error", 111: "JSON syntax error",
    112: "JSON has too many pairs", 113: "JSON string too long",
    115: "JSON maximum nesting depth exceeded",
    116: "JSON value does not agree with variable type",
    118: "The provided checksum didn't match", 119: "The provided line number was out of sequence",
    120: "120", 130: "Generic Gcode input error", 131: "Gcode command unsupported",
    132: "M code unsupported", 133: "Gcode modal group violation", 134: "Axis word missing",
    200: "Generic error", 204: "Command rejected by ALARM [$clear to reset]",
    205: "Command rejected by SHUTDOWN [$clear to reset]",
    206: "Command rejected by PANIC [^x to reset]", 207: "Kill job",
}
OK = 0
NOOP = 3
UNRECOGNIZED_NAME = 100
BAD_NUMBER_FORMAT = 102
UNSUPPORTED_TYPE = 103
READ_ONLY = 104
INPUT_EXCEEDS_MAX_LENGTH = 107
INPUT_LESS_THAN_MIN = 108
INPUT_EXCEEDS_MAX = 109
JSON_SYNTAX_ERROR = 111
JSON_TOO_MANY_PAIRS = 112
JSON_TYPE_MISMATCH = 116
CHECKSUM_MISMATCH = 118
LINE_NUMBER_OUT_OF_SEQUENCE = 119
MISSING_LINE_NUMBER = 120
GCODE_COMMAND_UNSUPPORTED = 131
MCODE_UNSUPPORTED = 132
ALARMED = 204
KILL_JOB_STATUS = 207


class RelaxedJsonError(ValueError):
    """A request g2core's parser refuses; `status` is the code its footer says."""

    def __init__(self, status: int, detail: str) -> None:
        super().__init__(f"{status} ({STATUS_MESSAGES.get(status, status)}): {detail}")
        self.status = status


@dataclass(frozen=True, slots=True)
class Null:
    """A GET: the value `n` (or `""`) in a request, g2core's way of asking for a name."""


NULL = Null()
JsonValue = None | bool | int | float | str | Null | dict[str, "JsonValue"]

# A request is normalized as _normalize_json_string() does (json_parser.cpp:199-219): every byte
# up to the space and DEL go, the rest is lower-cased, but inside a `( ... )` G-code comment.
_KEEP_INSIDE = re.compile(r"\([^)]*\)?")
_TOKEN = re.compile(r'"(?:[^"\\]|\\.)*"|[{}:,]|[^{}:,"]+')


def normalize(text: str) -> str:
    out: list[str] = []
    at = 0
    for comment in _KEEP_INSIDE.finditer(text):
        out.append(_squeeze(text[at:comment.start()]))
        out.append(comment.group())
        at = comment.end()
    out.append(_squeeze(text[at:]))
    return "".join(out)


def _squeeze(text: str) -> str:
    return "".join(char for char in text if " " < char < "\x7f").lower()


def parse_request(line: str) -> dict[str, JsonValue]:
    """One `{...}` request in g2core's relaxed JSON, to its name:value pairs in order (a value of
    NULL asks for the name). Names need no quotes; a value is told by its first character, as
    _get_nv_pair() does: `n...` or `""` null, `t...` true, `f...` false, a digit or `-` a number,
    `"..."` a string, `{` a group. The check is g2core's; the reading of what passes it is the
    standard library's json (quotes put on names and words first)."""
    text = normalize(line)
    if len(text) > JSON_INPUT_STRING_MAX:
        raise RelaxedJsonError(INPUT_EXCEEDS_MAX_LENGTH, f"{len(text)} characters")
    strict: list[str] = []
    expect_name = False
    pairs = 0
    for token in _TOKEN.findall(text):
        if token in "{,":
            expect_name = True
            strict.append(token)
        elif token in ":}":
            expect_name = False
            strict.append(token)
        elif expect_name:
            name = token[1:-1] if token.startswith('"') else token
            if not name or len(name) > TOKEN_LEN or '"' in name:
                raise RelaxedJsonError(INPUT_EXCEEDS_MAX_LENGTH if len(name) > TOKEN_LEN
                                       else JSON_SYNTAX_ERROR, f"name {token!r}")
            pairs += 1
            strict.append(json.dumps(name))
        else:
            strict.append(_value(token))
    if pairs >= NV_BODY_LEN:
        raise RelaxedJsonError(JSON_TOO_MANY_PAIRS, f"{pairs} pairs")
    try:
        parsed = json.loads("".join(strict), parse_constant=_no_constant,
                            object_pairs_hook=_pairs)
    except ValueError as error:
        raise RelaxedJsonError(JSON_SYNTAX_ERROR, str(error)) from None
    if not isinstance(parsed, dict) or not parsed:
        raise RelaxedJsonError(JSON_SYNTAX_ERROR, "not an object of name:value pairs")
    return parsed


_NULL_MARK = '"\\u0000null"'  # a string no request can hold (controls are normalized away)


def _value(token: str) -> str:
    first = token[0]
    if token == '""' or first == "n":
        return _NULL_MARK
    if first == "t":
        return "true"
    if first == "f":
        return "false"
    if first == '"':
        return token
    if first.isdigit() or first == "-":
        try:
            number = float(token)
        except ValueError:
            raise RelaxedJsonError(BAD_NUMBER_FORMAT, token) from None
        if not math.isfinite(number):
            raise RelaxedJsonError(BAD_NUMBER_FORMAT, token)
        return token
    if first == "[":
        raise RelaxedJsonError(JSON_TYPE_MISMATCH, "arrays are not taken")
    raise RelaxedJsonError(JSON_SYNTAX_ERROR, f"value {token!r}")


def _no_constant(name: str) -> object:
    raise ValueError(f"{name} is not a number g2core reads")


def _pairs(pairs: list[tuple[str, object]]) -> dict[str, object]:
    return {name: NULL if value == "\x00null" else value for name, value in pairs}


def format_number(value: float, places: int) -> str:
    """floattoa() (util.cpp:295-366): rounded to `places`, trailing zeros and a bare point
    dropped: 0.000 -> 0, 20.100 -> 20.1."""
    text = f"{value:.{places}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


@dataclass(frozen=True, slots=True)
class Number:
    """A float as g2core writes it: with the precision its config table gives the name."""

    value: float
    places: int = 3


OutValue = None | bool | int | str | Number | float | Sequence["OutValue"] | Mapping[str, "OutValue"]


def dumps(value: OutValue) -> str:
    """JSON as g2core's json_serialize() writes it: no spaces, keys in the order given, floats as
    floattoa() prints them (the standard library cannot leave 0.000 as 0). Strings are quoted
    by the standard library."""
    if value is None:
        return "null"
    if value is True:
        return "true"
    if value is False:
        return "false"
    if isinstance(value, Number):
        return format_number(value.value, value.places)
    if isinstance(value, float):
        return format_number(value, 3)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, Mapping):
        return "{" + ",".join(f"{json.dumps(key)}:{dumps(item)}" for key, item in value.items()) + "}"
    return "[" + ",".join(dumps(item) for item in value) + "]"


def response(body: Mapping[str, OutValue], status: int, length: int) -> bytes:
    """`{"r":{...},"f":[1,<status>,<length>]}\\n`: the answer to one line; `length` is the
    footer's third element, the bytes of that line (cs.linelen+1)."""
    return f'{{"r":{dumps(body)},"f":[{FOOTER_REVISION},{status},{length}]}}\n'.encode()


def report(name: str, body: OutValue) -> bytes:
    """A report of the board's own (`sr`, `qr`, `er`, `prb`...): a bare object, no footer."""
    return f"{{{json.dumps(name)}:{dumps(body)}}}\n".encode()


@dataclass(frozen=True, slots=True)
class Footer:
    revision: int
    status: int
    length: int


@dataclass(frozen=True, slots=True)
class Reply:
    """A line from the board, read by a host: a response (`r` and its footer) or a report."""

    body: dict[str, object]  # `r`'s body, or the whole object of a report
    footer: Footer | None  # None: a report of the board's own (`sr`, `qr`, `er`)


def parse_reply(line: bytes) -> Reply | None:
    """A line from the board; None for one that is no JSON object (a text-mode prompt, noise).
    The board writes strict JSON, so the standard library reads it."""
    try:
        parsed = json.loads(line)
    except (ValueError, UnicodeDecodeError, RecursionError):  # (noise nested past the stack)
        return None
    if not isinstance(parsed, dict):
        return None
    footer = parsed.get("f")
    if isinstance(footer, list) and len(footer) >= 3 and all(isinstance(x, int) for x in footer[:3]):
        body = parsed.get("r")
        return Reply(body if isinstance(body, dict) else {}, Footer(*footer[:3]))
    return Reply(parsed, None)
