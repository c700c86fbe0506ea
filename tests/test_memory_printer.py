"""fake_marlin.testing.memory_printer: a printer in the test's own trio run, for a trio host's
protocol tests on the autojump clock."""

import pytest
import trio

from fake_marlin.host import connect
from fake_marlin.testing import memory_printer

JOB = ["G28", *(f"G1 X{n % 50} Y{n % 30} F3000" for n in range(300)), "M400"]


async def test_minutes_of_printing_run_in_simulated_time(autojump_clock):
    async with memory_printer(protocol="marlin") as printer:
        async with connect(printer.open(), protocol="marlin") as host:
            summary = await host.print_commands(JOB)
        assert summary.commands == len(JOB)
        assert summary.elapsed > 10  # simulated seconds: the moves took their time
        assert printer.journal == JOB


async def test_faults_as_tables_reach_the_host(autojump_clock):
    noisy = [{"kind": "bit-errors", "direction": "to-printer", "rate": 2e-4}]
    async with memory_printer(protocol="ultimaker", faults=noisy, seed=3) as printer:
        async with connect(printer.open(), protocol="ultimaker") as host:
            summary = await host.print_commands(JOB)
        assert summary.resends > 0
        assert printer.journal == JOB


async def test_opening_the_port_resets_the_printer_as_a_pty_open_does(autojump_clock):
    async with memory_printer(protocol="marlin") as printer:
        boots = printer.server.boots
        stream = printer.open()
        await trio.sleep(1)
        assert printer.server.boots == boots + 1
        assert b"start" in await stream.receive_some()


async def test_options_it_cannot_honour_are_refused():
    with pytest.raises(TypeError, match="speed"):
        async with memory_printer(speed=10):
            pass
