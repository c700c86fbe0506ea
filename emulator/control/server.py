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
number, from 1: {"op": "state", "printer": 3}; with one printer the number may be left out.
A request the channel cannot carry out gets {"ok": false, "error": "..."}; the connection stays.
"""

import json
import os
import stat
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

    def __init__(self, servers) -> None:
        self.servers = list(servers) if isinstance(servers, (list, tuple)) else [servers]

    def handle(self, request) -> object:
        if not isinstance(request, dict) or not isinstance(request.get("op"), str):
            raise ControlError('a request is a JSON object with an "op"')
        if request["op"] == "printers":
            return self.op_printers()
        handler = getattr(self, "op_" + request["op"], None)
        if handler is None:
            raise ControlError(f"unknown op {request['op']!r}; one of state, set_temperature, "
                               "set_target, inject, say, action, quirks, printers")
        self.server = self._addressed(request)
        return handler(request)

    def _addressed(self, request):
        number = request.get("printer")
        count = len(self.servers)
        if number is None:
            if count == 1:
                return self.servers[0]
            raise ControlError(f'this process serves {count} printers: say which, '
                               f'"printer": 1 to {count}')
        if isinstance(number, bool) or not isinstance(number, int) or not 1 <= number <= count:
            raise ControlError(f'"printer" must be a number from 1 to {count}, not {number!r}')
        return self.servers[number - 1]

    def op_printers(self) -> list:
        return [
            {"printer": number, "path": getattr(server.link, "path", None),
             "protocol": server.protocol_name, "firmware": server.firmware.profile.name,
             "boots": server.boots, **asdict(server.firmware.identity)}
            for number, server in enumerate(self.servers, start=1)
        ]

    def op_state(self, request) -> dict:
        server, printer = self.server, self.server.printer
        now = trio.current_time()
        heaters = {f"T{n}": h for n, h in enumerate(printer.hotends)} | {"B": printer.bed}
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


def check_control_path(path: str) -> str | None:
    """Why the control socket cannot be made at `path`, or None if it can."""
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        return f"no directory {directory}"
    if os.path.lexists(path) and not stat.S_ISSOCK(os.lstat(path).st_mode):
        return f"{path} exists and is not a socket; refusing to replace it"
    return None


async def serve_control(path: str, controller: Controller, task_status=trio.TASK_STATUS_IGNORED) -> None:
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
                    await _reply(stream, _answer(line, controller))


def _answer(line: bytes, controller: Controller) -> dict:
    try:
        request = json.loads(line)
    except ValueError as error:
        return {"ok": False, "error": f"not JSON: {error}"}
    try:
        return {"ok": True, "result": controller.handle(request)}
    except ControlError as error:
        return {"ok": False, "error": str(error)}


async def _reply(stream, reply: dict) -> None:
    try:
        await stream.send_all(json.dumps(reply).encode() + b"\n")
    except (trio.BrokenResourceError, trio.ClosedResourceError):
        pass
