"""A small client for the control channel, for pytest suites of host software.

    with ControlClient("/tmp/printer.control") as printer:
        printer.inject(kind="thermal-runaway")
        assert printer.state()["halted"]

Plain blocking sockets: it works from any test, trio or not.
"""

import json
import socket


class ControlRequestError(Exception):
    """The printer refused a request; the message says why."""


class ControlClient:
    def __init__(self, path: str, timeout: float = 10.0, printer: int | None = None) -> None:
        """`printer`: which of a farm's printers the requests are for (from 1)."""
        self.printer = printer
        self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._socket.settimeout(timeout)
        self._socket.connect(path)
        self._reader = self._socket.makefile("rb")

    def request(self, op: str, **fields) -> object:
        if self.printer is not None:
            fields = {"printer": self.printer, **fields}
        self._socket.sendall(json.dumps({"op": op, **fields}).encode() + b"\n")
        line = self._reader.readline()
        if not line:
            raise ConnectionError("the printer closed the control channel")
        reply = json.loads(line)
        if not reply.get("ok"):
            raise ControlRequestError(reply.get("error", "refused"))
        return reply.get("result")

    def state(self) -> dict:
        state = self.request("state")
        if not isinstance(state, dict):
            raise ControlRequestError(f"the printer's state is not an object: {state!r}")
        return state

    def set_temperature(self, heater: str, temperature: float) -> None:
        self.request("set_temperature", heater=heater, temperature=temperature)

    def set_target(self, heater: str, target: float) -> None:
        self.request("set_target", heater=heater, target=target)

    def inject(self, **fault) -> None:
        """A fault as a scenario's [[fault]] table; with no trigger it happens now."""
        self.request("inject", fault=fault)

    def say(self, text: str) -> None:
        self.request("say", text=text)

    def printers(self) -> list[dict]:
        """Every printer the process serves: its number, path, protocol and boots."""
        found = self.request("printers")
        if not isinstance(found, list):
            raise ControlRequestError(f"the printer list is not a list: {found!r}")
        return found

    def close(self) -> None:
        self._reader.close()
        self._socket.close()

    def __enter__(self) -> "ControlClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
