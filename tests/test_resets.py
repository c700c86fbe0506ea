"""A reset asked for while one is already coming: the board goes down once, and the lines that
came with the request are read by nobody (the boot that read them is ending)."""

import trio

from fake_marlin.testing import memory_printer
from tests.terminal import Terminal


async def test_twenty_firmware_restarts_in_one_write_reset_a_halted_klipper_once(autojump_clock):
    async with memory_printer(firmware="klipper") as printer:
        terminal = Terminal(printer.open())
        await terminal.command("M112")
        await terminal.quiet_for(1)
        boots = printer.server.boots
        await terminal.stream.send_all(b"FIRMWARE_RESTART\n" * 20)
        lines = await terminal.quiet_for(10)
        assert lines.count("ok") == 1  # the first one's; the other 19 reach a board going down
        assert printer.server.boots == boots + 1
        assert (await terminal.command("M105"))[0].startswith("ok B:")  # up and running again
