"""The control channel: JSON lines on a Unix socket, so a test suite of any host software can
script the printer while its host is connected.

Each request is one JSON object on a line, each reply one line:
    {"op": "state"}                                   -> {"ok": true, "result": {...}}
    {"op": "set_temperature", "heater": "T0", "temperature": 250}
    {"op": "set_target", "heater": "B", "target": 60}
    {"op": "inject", "fault": {"kind": "thermal-runaway"}}   (a [[fault]] table of a scenario;
        without a trigger, a printer fault fires now and a link fault hits the next unit)
    {"op": "say", "text": "//action:pause"}           (the printer prints this line)
    {"op": "action", "action": "pause"}               (a host action, in the firmware's words:
        as if its LCD's pause had been pressed)
    {"op": "quirks", "set": {"ok_before_output": true}}  -> every quirk as it now is (without
        "set": as it is); the session takes them from its next line
    {"op": "printers"}                                -> [{"printer": 1, "path": ...}, ...]
In a process serving several printers (--printers, --farm) a request names its printer by
number, from 1 (or --first-number): {"op": "state", "printer": 3}; with one printer the number
may be left out. With --processes the socket is the first process's, and it hands each request
to the process serving that printer (control/fanout.py): the same requests, the same replies.
A request the channel cannot carry out gets {"ok": false, "error": "..."}; the connection stays.
"""

import inspect
import json
import os
import stat
from collections.abc import Sequence
from dataclasses import asdict

import trio

from fake_marlin.emulator.faults.rules import LINK_KINDS, FaultRule
from fake_marlin.emulator.firmware.quirks import describe, read_quirks
from fake_marlin.emulator.printer import failures
from fake_marlin.emulator.printer.statements import state
from fake_marlin.emulator.tables import TableError, TableReader
from fake_marlin.emulator.scenario.definition import TRIGGER_KEYS, ScenarioError, parse_fault_table

MAX_REQUEST = 64 * 1024


class ControlError(Exception):
    """A request that cannot be carried out; the message says why."""


class Controller:
    """What the channel can do to the running PrinterServers (one, or a farm's)."""

    def __init__(self, servers, numbers: Sequence[int] | None = None) -> None:
        self.servers = list(servers) if isinstance(servers, (list, tuple)) else [servers]
        # The printers' numbers in the farm (a process of --processes serves a part of it).
        self.numbers = list(numbers) if numbers is not None else list(range(1, len(self.servers) + 1))
        self._by_number = dict(zip(self.numbers, self.servers))

    def handle(self, request) -> object:
        check_request(request)
        if request["op"] in _FARM_OPS:
            return getattr(self, "op_" + request["op"])()
        handler = getattr(self, "op_" + request["op"], None)
        if handler is None:
            raise ControlError(unknown_op(request["op"]))
        self.server = self._addressed(request)
        return handler(request)

    def _addressed(self, request):
        number = request.get("printer")
        if number is None and len(self.servers) == 1:
            return self.servers[0]
        check_printer_number(number, self.numbers[0], self.numbers[-1])
        server = self._by_number.get(number)
        if server is None:
            raise ControlError(f"no printer {number} here")
        return server

    def op_printers(self) -> list:
        return [
            {"printer": number, "path": getattr(server.link, "path", None),
             "protocol": server.protocol_name, "firmware": server.firmware.profile.name,
             "boots": server.boots, **asdict(server.firmware.identity)}
            for number, server in zip(self.numbers, self.servers)
        ]

    def op_web_rows(self) -> list:
        """The live view's rows of these printers (web/snapshot.py), for a --processes farm's
        first process, which serves the view."""
        from fake_marlin.emulator.web.snapshot import rows

        return rows(self.servers, self.numbers, [_path(server) for server in self.servers])

    def op_web_detail(self, request) -> dict:
        """The live view's page of one printer, which watches it (records its wire) a while."""
        from fake_marlin.emulator.web.source import watched_detail

        number = self.numbers[self.servers.index(self.server)]
        return watched_detail(self.server, number, _path(self.server))

    def op_state(self, request) -> dict:
        server, printer = self.server, self.server.printer
        now = trio.current_time()
        heaters = failures.heaters(printer)
        x, y, z, e = printer.motion.position
        return {
            "protocol": server.protocol_name,
            "firmware": server.firmware.profile.name,
            "identity": asdict(server.firmware.identity),
            "boots": server.boots,
            "halted": printer.halted,
            "temperatures": {
                name: {"actual": round(h.temperature(now), 2), "target": h.target}
                for name, h in heaters.items()
            },
            "position": {"X": x, "Y": y, "Z": z, "E": e},
            "planner_moves": printer.planner.moves(now),
            "fans": list(printer.fans),
            "sd_printing": printer.sd.printing,
            "simulated_time": now,
        }

    def _heater(self, request):
        name = request.get("heater", "T0")
        if not isinstance(name, str) or not (name in ("B", "bed") or name[:1] == "T" and name[1:].isdigit()
                                              and int(name[1:]) < len(self.server.printer.hotends)):
            raise ControlError(f"no heater {name!r}: T0..T{len(self.server.printer.hotends) - 1} or B")
        return failures.heater(self.server.printer, name)

    def _number(self, request, key: str) -> float:
        value = request.get(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ControlError(f'"{key}" must be a number')
        return float(value)

    def op_set_temperature(self, request) -> dict:
        heater = self._heater(request)
        heater.force_temperature(trio.current_time(), self._number(request, "temperature"))
        return {}

    def op_set_target(self, request) -> dict:
        heater = self._heater(request)
        heater.set_target(trio.current_time(), self._number(request, "target"))
        return {}

    def op_inject(self, request) -> dict:
        table = request.get("fault")
        if not isinstance(table, dict):
            raise ControlError('"fault" must be an object, as a [[fault]] table of a scenario')
        immediate = not any(key in table for key in TRIGGER_KEYS)
        try:
            fault = parse_fault_table({"nth": 1, **table} if immediate else table, "fault")
        except ScenarioError as error:
            raise ControlError(str(error)) from None
        if not isinstance(fault, FaultRule):
            self.server.faults.set_rate(*fault)
        elif immediate and fault.kind not in LINK_KINDS:
            self.server.fire_printer_fault(fault)
        else:
            self.server.faults.add_rule(fault)
        return {}

    def op_action(self, request) -> dict:
        action = request.get("action")
        if not isinstance(action, str) or not action or "\n" in action:
            raise ControlError('"action" must be an action\'s name, e.g. "pause"')
        self.server.announce((state("action", action=action),))
        return {}

    def op_quirks(self, request) -> dict:
        changes = request.get("set", {})
        if not isinstance(changes, dict):
            raise ControlError('"set" must be an object of quirk names and values')
        if changes:
            try:
                quirks = read_quirks(TableReader('"set"', "", dict(changes)),
                                     self.server.firmware.quirks)
            except TableError as error:
                raise ControlError(str(error)) from None
            self.server.set_quirks(quirks)
        return describe(self.server.firmware.quirks)

    def op_say(self, request) -> dict:
        text = request.get("text")
        if not isinstance(text, str) or "\n" in text:
            raise ControlError('"text" must be one line of text')
        self.server.announce((text,))
        return {}


def _path(server) -> str:
    """Where a host reaches the printer: its pty's path, or its socket:// URL."""
    return str(getattr(server.link, "path", ""))


_FARM_OPS = ("printers", "web_rows")  # of every printer: no "printer" in the request
OPS = tuple(sorted(name[3:] for name in vars(Controller) if name.startswith("op_")))


def check_request(request: object) -> None:
    """A request is a JSON object with an "op" (ControlError if not)."""
    if not isinstance(request, dict) or not isinstance(request.get("op"), str):
        raise ControlError('a request is a JSON object with an "op"')


def unknown_op(op: str) -> str:
    return f"unknown op {op!r}; one of {', '.join(OPS)}"


def check_printer_number(number: object, first: int, last: int) -> None:
    """A request's "printer", which must be one of first..last (ControlError if not)."""
    if number is None:
        raise ControlError(f"{last - first + 1} printers are served here: say which, "
                           f'"printer": {first} to {last}')
    if isinstance(number, bool) or not isinstance(number, int) or not first <= number <= last:
        raise ControlError(f'"printer" must be a number from {first} to {last}, not {number!r}')


def check_control_path(path: str) -> str | None:
    """Why the control socket cannot be made at `path`, or None if it can."""
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        return f"no directory {directory}"
    if os.path.lexists(path) and not stat.S_ISSOCK(os.lstat(path).st_mode):
        return f"{path} exists and is not a socket; refusing to replace it"
    return None


async def serve_control(path: str, controller, task_status=trio.TASK_STATUS_IGNORED) -> None:
    """Serve `controller` (a Controller, or anything whose handle(request) returns a request's
    result or an awaitable of it, raising ControlError) on the Unix socket at `path`."""
    problem = check_control_path(path)
    if problem:
        raise ControlError(problem)
    if os.path.lexists(path):
        os.unlink(path)  # a socket left by an earlier run
    sock = trio.socket.socket(trio.socket.AF_UNIX, trio.socket.SOCK_STREAM)
    await sock.bind(path)
    sock.listen()
    listener = trio.SocketListener(sock)
    task_status.started()
    try:
        await trio.serve_listeners(lambda stream: _serve_client(stream, controller), [listener])
    finally:
        if os.path.exists(path):
            os.unlink(path)


async def _serve_client(stream, controller: Controller) -> None:
    buffer = b""
    async with stream:
        while True:
            try:
                data = await stream.receive_some(4096)
            except trio.BrokenResourceError:
                return
            if not data:
                return
            buffer += data
            if len(buffer) > MAX_REQUEST and b"\n" not in buffer:
                await _reply(stream, {"ok": False, "error": "request too long"})
                return
            while b"\n" in buffer:
                line, buffer = buffer.split(b"\n", 1)
                if line.strip():
                    await _reply(stream, await _answer(line, controller))


async def _answer(line: bytes, controller) -> dict:
    try:
        request = json.loads(line)
    except ValueError as error:
        return {"ok": False, "error": f"not JSON: {error}"}
    try:
        result = controller.handle(request)
        if inspect.isawaitable(result):
            result = await result
        return {"ok": True, "result": result}
    except ControlError as error:
        return {"ok": False, "error": str(error)}


async def _reply(stream, reply: dict) -> None:
    try:
        await stream.send_all(json.dumps(reply).encode() + b"\n")
    except (trio.BrokenResourceError, trio.ClosedResourceError):
        pass
