"""The control channel, scripted from a test as a host developer's suite would."""

import socket

import pytest
import trio

from fake_marlin.emulator.control.client import ControlClient, ControlRequestError
from fake_marlin.emulator.control.server import Controller, serve_control
from fake_marlin.emulator.server.clock import ScaledClock
from fake_marlin.emulator.server.lifecycle import ServerConfig
from tests.conftest import running_printer
from tests.terminal import Terminal


async def with_control(tmp_path, script, protocol="marlin"):
    """Run `script(client, terminal)` in a thread against a printer with a control channel."""
    path = str(tmp_path / "control.sock")
    async with running_printer(ServerConfig(protocol=protocol)) as running:
        async with trio.open_nursery() as nursery:
            await nursery.start(serve_control, path, Controller(running.server))
            terminal = Terminal(running.link.open_host())
            await terminal.quiet_for(1)

            def scripted():
                with ControlClient(path) as client:
                    return script(client, terminal)

            result = await trio.to_thread.run_sync(scripted)
            nursery.cancel_scope.cancel()
    return result, terminal


def run_in_trio(terminal, coroutine, *args):
    return trio.from_thread.run(coroutine, *args)


@pytest.fixture
def fast_clock():
    """Simulated time 20 times faster than real time, as `fake-marlin --speed 20`: the quiet
    spells the terminal waits for take a twentieth of their seconds. (Not where a test reads a
    heater right after setting it: it cools in the real milliseconds between, 20 times as far.)"""
    return ScaledClock(20)


async def test_state_temperature_and_halting_from_outside(tmp_path):
    def script(client, terminal):
        state = client.state()
        assert state["protocol"] == "marlin" and state["halted"] is False
        assert state["temperatures"]["T0"] == {"actual": 21.0, "target": 0.0}
        client.set_temperature("T0", 230)
        (line,) = run_in_trio(terminal, terminal.command, "M105")
        assert line.startswith("ok T:230.00 /0.00")
        client.say("//action:pause")
        assert run_in_trio(terminal, terminal.read_line) == "//action:pause"
        client.inject(kind="thermal-runaway", heater="T0")
        lines = [run_in_trio(terminal, terminal.read_line) for _ in range(2)]
        assert lines == ["Error:Thermal Runaway, system stopped! Heater_ID: 0",
                         "Error:Printer halted. kill() called!"]
        return client.state()

    state, _ = await with_control(tmp_path, script)
    assert state["halted"] is True


async def test_link_faults_injected_live_hit_the_next_unit(tmp_path, fast_clock):
    def script(client, terminal):
        client.inject(kind="drop", direction="to-host", pattern="^ok")
        run_in_trio(terminal, terminal.send, "M114")
        return run_in_trio(terminal, terminal.quiet_for, 2)

    lines, _ = await with_control(tmp_path, script)
    assert lines == ["X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0"]  # its ok was lost


async def test_bad_requests_are_refused_and_the_channel_stays(tmp_path, fast_clock):
    def script(client, terminal):
        errors = []
        for op, fields in [("melt", {}), ("set_temperature", {"heater": "T7", "temperature": 1}),
                           ("set_target", {"heater": "B", "target": "hot"}),
                           ("inject", {"fault": {"kind": "melt"}}), ("say", {"text": "a\nb"})]:
            with pytest.raises(ControlRequestError) as refused:
                client.request(op, **fields)
            errors.append(str(refused.value))
        raw = socket.socket(socket.AF_UNIX)
        raw.connect(client._socket.getpeername())
        raw.sendall(b"not json\n")
        errors.append(raw.recv(1000).decode())
        raw.close()
        assert client.state()["halted"] is False
        return errors

    errors, _ = await with_control(tmp_path, script)
    assert "unknown op 'melt'" in errors[0] and "no heater 'T7'" in errors[1]
    assert "must be a number" in errors[2] and "kind: must be one of" in errors[3]
    assert "one line" in errors[4] and "not JSON" in errors[5]
