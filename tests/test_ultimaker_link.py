"""Printer and host client together over in-memory streams, in simulated time."""

import trio

from fake_marlin.host.codecs.ultimaker import Ack, FrameParser, RoomInfo
from fake_marlin.host.connect import connect
from fake_marlin.host.errors import CommandError, PrinterReset
from fake_marlin.host.shell import ClientOptions
from fake_marlin.wire.ultimaker import encode_packet
from tests.conftest import running_printer
from tests.faults import DamagingStream, LineDroppingStream

JOB = [f"G1 X{n % 50} Y{n % 7} F6000" for n in range(400)] + ["M400", "M114"]


async def test_send_returns_the_response_data(autojump_clock):
    async with running_printer() as printer:
        async with connect(printer.link.open_host()) as host:
            assert await host.send("M105") == ("T:21.00 /0.00 B:21.00 /0.00 @:0 B@:0",)
            assert await host.send("M114") == ("X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0",)
            assert await host.send("G1 X5") == ()


async def test_a_print_runs_every_command_once_in_order_across_sequence_wrap(autojump_clock):
    async with running_printer() as printer:
        async with connect(printer.link.open_host()) as host:
            progress = []
            summary = await host.print_commands(JOB, progress.append)
    assert printer.journal == JOB
    assert summary.commands == len(JOB) and summary.resends == 0
    assert progress[-1] == len(JOB)


async def test_damage_in_both_directions_loses_and_repeats_nothing(autojump_clock):
    for seed in range(6):
        async with running_printer() as printer:
            stream = DamagingStream(printer.link.open_host(), seed, flip_out=0.002, flip_in=0.002, drop_in=0.002)
            async with connect(stream, options=ClientOptions(max_transmissions=50)) as host:
                summary = await host.print_commands(JOB)
        assert printer.journal == JOB, f"seed {seed}"
        assert summary.resends > 0


async def test_lost_bytes_from_the_printer_are_recovered(autojump_clock):
    async with running_printer() as printer:
        stream = DamagingStream(printer.link.open_host(), 1, drop_in=0.02)
        async with connect(stream, options=ClientOptions(max_transmissions=50)) as host:
            await host.print_commands(JOB)
    assert printer.journal == JOB


async def test_a_lost_ok_for_the_last_command_is_recovered_by_timeout(autojump_clock):
    job = JOB[:5]
    last_ok = f"o{len(job) - 1:02X}".encode()
    async with running_printer() as printer:
        stream = LineDroppingStream(printer.link.open_host(), lambda line: line.startswith(last_ok))
        options = ClientOptions(timeout=2.0, received_timeout=10.0)
        async with connect(stream, options=options) as host:
            summary = await host.print_commands(job)
    assert printer.journal == job
    assert stream.dropped == 1
    assert summary.commands == len(job)  # the unconfirmed one counts as done, progress too
    assert summary.timeouts == 1 and summary.resends == 1 and summary.unconfirmed == 1
    assert 12.0 <= summary.elapsed < 13.0


async def test_reopening_the_port_reboots_the_printer_and_nothing_is_lost(autojump_clock):
    async with running_printer() as printer:
        async with connect(printer.link.open_host()) as host:
            await host.print_commands(JOB[:100])
        async with connect(printer.link.open_host()) as host:
            await host.print_commands(JOB[100:])
        assert printer.server.boots == 3  # power-on, then one per open
    assert printer.journal == JOB


async def test_a_reset_mid_print_is_reported(autojump_clock):
    async with running_printer() as printer:
        stream = printer.link.open_host()
        try:
            async with connect(stream) as host:
                await host.print_commands(JOB[:10])
                printer.link.open_host()  # someone else opened the port: the printer resets
                await host.print_commands(JOB[10:])
        except PrinterReset:
            pass
        else:
            raise AssertionError("the reset went unnoticed")


async def test_a_full_planner_delays_ok_and_q_reports_room_again(autojump_clock):
    async with running_printer() as printer:
        stream = printer.link.open_host()
        parser = FrameParser()
        events = []

        async def read_for(seconds):
            with trio.move_on_after(seconds):
                while True:
                    parser.receive_data(await stream.receive_some())
                    while (event := parser.next_event()) is not None:
                        events.append((trio.current_time(), event))

        await read_for(0.1)
        start = trio.current_time()
        for seq in range(16):  # each move is 10 mm at 20 mm/s: about half a second
            await stream.send_all(encode_packet(seq, b"G1 X%d F1200" % ((seq + 1) * 10)))
        await read_for(30)
    acks = [(t - start, e) for t, e in events if isinstance(e, Ack)]
    assert [e.room for _, e in acks[:15]] == list(range(14, -1, -1))
    assert acks[14][0] < 0.01  # the 15th move fits: answered at once
    assert 0.5 < acks[15][0] < 0.55 and acks[15][1].room == 0  # the 16th waits for the first move
    rooms = [e.room for t, e in events if isinstance(e, RoomInfo) and t > start]
    assert rooms[0] == 1  # room opened after the host last saw 0


async def test_a_healthy_print_with_long_moves_and_homing_never_resends(autojump_clock):
    job = ["G28", "M400"] + [f"G1 X{200 * (n % 2)} Y{n} F1200" for n in range(40)] + ["M400", "G28 X"]
    async with running_printer() as printer:
        async with connect(printer.link.open_host()) as host:
            summary = await host.print_commands(job)
    assert printer.journal == job
    assert summary.elapsed > 39 * 10  # 200 mm at 20 mm/s each (the first is empty): a full planner
    assert (summary.resends, summary.timeouts, summary.rejects) == (0, 0, 0)


async def test_a_callers_error_inside_the_block_comes_back_as_itself(autojump_clock):
    async with running_printer() as printer:
        try:
            async with connect(printer.link.open_host()) as host:
                await host.send("M117 caf\u00e9")
        except CommandError as error:
            assert "ASCII" in str(error)
        else:
            raise AssertionError("an unsendable command was accepted")
