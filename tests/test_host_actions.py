"""Marlin's host action commands and prompts as it sends them: M0, M600, M24/M25, M876."""

import dataclasses

from tests.test_quirks import marlin

PROMPT = "//action:prompt_{}".format


async def test_m0_waits_for_the_user_and_says_so(autojump_clock):
    async with marlin() as (terminal, _):
        await terminal.send("M0 Swap the nozzle")
        lines = await terminal.read_until(lambda line: line == "echo:busy: paused for user")
        assert lines == ["echo:Swap the nozzle", PROMPT("end"), PROMPT("begin Swap the nozzle"),
                         PROMPT("button Continue"), PROMPT("show"), "echo:busy: paused for user"]
        assert await terminal.quiet_for(9) == ["echo:busy: paused for user"] * 4  # every 2 s
        await terminal.send("M108")  # the emergency parser ends the wait at once
        assert await terminal.read_line() == "ok"  # M0's
        assert await terminal.read_line() == "ok"  # the queued M108's


async def test_m0_ends_on_the_hosts_m876_or_its_own_timeout(autojump_clock):
    async with marlin() as (terminal, _):
        await terminal.send("M1")
        await terminal.read_until(lambda line: line == PROMPT("show"))
        await terminal.send("M876 S0")
        assert await terminal.quiet_for(1) == ["ok", "ok"]  # M1's, then the queued M876's
        assert await terminal.command("M0 S3 Cooling down") == [
            "echo:Cooling down", PROMPT("end"), PROMPT("begin Cooling down"),
            PROMPT("button Continue"), PROMPT("show"), "echo:busy: paused for user", "ok"]


async def test_m600_changes_filament_with_the_hosts_answers(autojump_clock):
    async with marlin() as (terminal, running):
        await terminal.send("M600")
        first = await terminal.read_until(lambda line: line == PROMPT("show"))
        assert first == ["//action:paused", PROMPT("end"), PROMPT("begin Pause"),
                         PROMPT("button Dismiss"), PROMPT("show")]
        parked = await terminal.read_until(lambda line: line == "echo:busy: paused for user")
        assert parked[-6:] == ["echo:Insert filament and send M108", PROMPT("end"),
                               PROMPT("begin Nozzle Parked"), PROMPT("button Continue"),
                               PROMPT("show"), "echo:busy: paused for user"]
        assert "echo:busy: processing" in parked  # unloading takes its time
        await terminal.send("M108")
        asked = await terminal.read_until(lambda line: line == PROMPT("show"))
        assert asked[-5:] == [PROMPT("end"), PROMPT("begin Paused"), PROMPT("button PurgeMore"),
                              PROMPT("button Continue"), PROMPT("show")]
        await terminal.send("M876 S0")  # purge more: asked again after the purge
        again = await terminal.read_until(lambda line: line == PROMPT("show"))
        assert again[-4] == PROMPT("begin Paused")
        await terminal.send("M876 S1")
        rest = await terminal.read_until(lambda line: line == "ok")
        assert rest[rest.index("//action:resumed"):] == [
            "//action:resumed", PROMPT("end"), PROMPT("begin Resuming"), PROMPT("button Dismiss"),
            PROMPT("show"), "ok"]
        assert "M600" in running.journal


async def test_m24_and_m25_tell_the_host(autojump_clock, tmp_path):
    async with marlin(tmp_path) as (terminal, _):
        (tmp_path / "sd" / "part.gco").write_text("G4 S1\n")
        await terminal.command("M23 part.gco")
        assert await terminal.command("M24") == [
            "//action:resume", PROMPT("end"), PROMPT("begin Resuming SD"),
            PROMPT("button Dismiss"), PROMPT("show"), "ok"]
        # The "Resuming SD" prompt is pending until the host answers: M25's is not shown.
        assert [line for line in await terminal.command("M25") if "busy" not in line] == [
            "//action:pause", "ok"]
        await terminal.command("M876 S1")
        assert await terminal.command("M25") == [
            PROMPT("end"), PROMPT("begin Pause SD"), PROMPT("button Resume"), PROMPT("show"),
            "//action:pause", "ok"]


async def test_without_host_action_commands_m600_says_no_action(autojump_clock):
    async with marlin() as (terminal, running):
        printer = running.server.printer
        printer.config = dataclasses.replace(printer.config, capabilities=(
            ("EMERGENCY_PARSER", True), ("HOST_ACTION_COMMANDS", False), ("PROMPT_SUPPORT", False)))
        await terminal.send("M600")
        lines = await terminal.read_until(lambda line: line == "echo:Insert filament and send M108")
        assert not [line for line in lines if line.startswith("//action")]
        await terminal.send("M108")
        assert (await terminal.read_until(lambda line: line == "ok"))[-1] == "ok"
