"""Our host's Marlin protocol against the emulated printer, over in-memory streams in simulated
time, and the sans-IO sender alone where the emulator cannot make the case."""

import random

import pytest
import trio

from fake_marlin.emulator.journal.verify import Kind, verify
from fake_marlin.emulator.server.lifecycle import ServerConfig
from fake_marlin.host.codecs.marlin import PROBE, LineKind, Ok, encode_line, xor_checksum
from fake_marlin.host.connect import connect
from fake_marlin.host.cores.marlin import HELLO, MarlinCore
from fake_marlin.host.errors import CommandError, PrinterHalted, PrinterNotResponding, PrinterReset
from fake_marlin.host.shell import ClientOptions
from tests.conftest import running_printer
from tests.faults import LineDroppingStream
from tests.terminal import Terminal, numbered

JOB = [f"G1 X{n % 50} Y{n % 7} F6000" for n in range(400)] + ["M400", "M114"]
MARLIN = ServerConfig(protocol="marlin")
TEMPERATURES = "T:21.00 /0.00 B:21.00 /0.00 @:0 B@:0"


class NoisyStream:
    """Seeded damage both ways: bit flips toward the printer, bit flips and lost bytes from it.

    Toward the printer a line's first byte is spared. It is the one byte Marlin's protocol
    cannot protect: a line that does not start with N is run as a bare command, unchecked, so
    no host can keep it from running (test_a_damaged_leading_n_... shows what happens then).
    """

    def __init__(self, inner, seed: int, flip_out=0.002, flip_in=0.002, drop_in=0.002) -> None:
        self._inner = inner
        # One generator each way: the damage one way does not shift with what goes the other.
        self._out = random.Random(f"{seed} out")
        self._in = random.Random(f"{seed} in")
        self.flip_out, self.flip_in, self.drop_in = flip_out, flip_in, drop_in

    @staticmethod
    def _flip(draw: random.Random, byte: int, rate: float) -> int:
        return byte ^ (1 << draw.randrange(8)) if draw.random() < rate else byte

    async def send_all(self, data: bytes) -> None:
        out = bytearray()
        for index, byte in enumerate(data):
            line_start = index == 0 or data[index - 1] == ord("\n")
            out.append(byte if line_start else self._flip(self._out, byte, self.flip_out))
        await self._inner.send_all(bytes(out))

    async def receive_some(self, max_bytes: int = 4096) -> bytes:
        while True:
            data = await self._inner.receive_some(max_bytes)
            draw = self._in
            kept = bytes(self._flip(draw, b, self.flip_in) for b in data if draw.random() >= self.drop_in)
            if kept:
                return kept


class Meddler:
    """Rewrites chosen lines on their way to the printer; leaves out chosen lines from it; and
    can hand what the printer says over one line per read."""

    def __init__(self, inner, outgoing=lambda line: line, drop_in=lambda line: False, by_line=False):
        self._inner = inner
        self._outgoing = outgoing
        self._drop_in = drop_in
        self._by_line = by_line
        self._pending = b""
        self.sent: list[bytes] = []
        self.dropped: list[bytes] = []

    async def send_all(self, data: bytes) -> None:
        lines = data.split(b"\n")
        self.sent += [line for line in lines if line]
        await self._inner.send_all(b"\n".join(self._outgoing(line) for line in lines))

    async def receive_some(self, max_bytes: int = 4096) -> bytes:
        while True:
            while b"\n" not in self._pending:
                self._pending += await self._inner.receive_some(max_bytes)
            *lines, self._pending = self._pending.split(b"\n")
            kept = []
            for line in lines:
                if self._drop_in(line):
                    self.dropped.append(line)
                else:
                    kept.append(line + b"\n")
            if kept and self._by_line:
                self._pending = b"".join(kept[1:]) + self._pending
                return kept[0]
            if kept:
                return b"".join(kept)


def once(predicate):
    """A predicate that holds only the first time `predicate` does."""
    fired = []

    def check(value) -> bool:
        if not fired and predicate(value):
            fired.append(value)
            return True
        return False

    return check


def nth(predicate, n: int):
    count = 0

    def check(value) -> bool:
        nonlocal count
        if predicate(value):
            count += 1
            return count == n
        return False

    return check


def corrupt_checksum(line: bytes) -> bytes:
    body, _, checksum = line.rpartition(b"*")
    return body + b"*" + str((int(checksum) + 1) % 256).encode()


async def test_send_returns_the_response_data(autojump_clock):
    async with running_printer(MARLIN) as printer:
        async with connect(printer.link.open_host(), "marlin") as host:
            assert await host.send("M105") == (TEMPERATURES,)
            assert await host.send("M114") == ("X:0.00 Y:0.00 Z:0.00 E:0.00 Count X:0 Y:0 Z:0",)
            assert await host.send("G1 X5") == ()
            assert await host.send("M9999") == ('echo:Unknown command: "M9999"',)
            firmware = await host.send("M115")
            assert firmware[0].startswith("FIRMWARE_NAME:Marlin") and "Cap:EEPROM:1" in firmware
    assert printer.journal == ["M105", "M114", "G1 X5", "M9999", "M115"]


async def test_a_print_runs_every_command_once_in_order(autojump_clock):
    async with running_printer(MARLIN) as printer:
        async with connect(printer.link.open_host(), "marlin") as host:
            progress = []
            summary = await host.print_commands(JOB, progress.append)
    # The printer was reset when the port opened: its counter is 0, so the host adds nothing.
    assert printer.journal == JOB
    assert summary.commands == len(JOB) and progress[-1] == len(JOB)
    assert (summary.resends, summary.timeouts, summary.rejects, summary.unconfirmed) == (0, 0, 0, 0)
    assert host.stats.probes == 2  # the counter at connect, and the check at the job's end


@pytest.mark.parametrize("seed", range(8))
async def test_damage_in_both_directions_loses_and_repeats_nothing(autojump_clock, seed):
    async with running_printer(MARLIN) as printer:
        stream = NoisyStream(printer.link.open_host(), seed)
        async with connect(stream, "marlin", options=ClientOptions(max_transmissions=50)) as host:
            summary = await host.print_commands(JOB)
    # Two flips of one bit in two characters pass Marlin's XOR checksum: such a line runs
    # damaged, which no host can prevent; nothing may be lost or run twice.
    verdict = verify(list(enumerate(JOB, 1)), printer.journal)
    assert verdict.passed(allow_undetectable=True), verdict.problems
    assert summary.commands == len(JOB)
    assert summary.resends > 0 and summary.rejects > 0


async def test_a_line_damaged_past_the_checksum_is_reported_as_such(autojump_clock):
    """`N138 G1 X37 Y4 F6000`, with '3' -> '1' and '7' -> '5' (the same bit, twice): its XOR
    is unchanged, so Marlin runs it damaged, as the firmware would."""
    async with running_printer(MARLIN) as printer:
        hit = once(lambda line: line.startswith(b"N138 "))
        damage = lambda line: line.replace(b"X37", b"X15") if hit(line) else line  # noqa: E731
        async with connect(Meddler(printer.link.open_host(), damage), "marlin") as host:
            await host.print_commands(JOB)
    verdict = verify(list(enumerate(JOB, 1)), printer.journal)
    (damaged,) = verdict.problems
    assert damaged.kind is Kind.DAMAGED and damaged.command == JOB[137] == "G1 X37 Y4 F6000"
    assert damaged.ran_as == "G1 X15 Y4 F6000"
    assert xor_checksum(damaged.ran_as.encode()) == xor_checksum(damaged.command.encode())
    assert not verdict.passed() and verdict.passed(allow_undetectable=True)


async def test_damage_with_the_printers_own_fault_layer(autojump_clock):
    from fake_marlin.emulator.faults.layer import FaultConfig, LineFaults

    faults = FaultConfig(to_host=LineFaults(bit_error_rate=2e-4, drop_rate=2e-3), seed=3)
    async with running_printer(ServerConfig(protocol="marlin", faults=faults)) as printer:
        stream = NoisyStream(printer.link.open_host(), 3, flip_in=0, drop_in=0)
        async with connect(stream, "marlin", options=ClientOptions(max_transmissions=50)) as host:
            summary = await host.print_commands(JOB)
    assert printer.journal == JOB
    assert summary.resends > 0


async def test_a_damaged_leading_n_runs_the_line_unchecked_but_no_command_twice(autojump_clock):
    """Marlin's limit, not the host's: `O101 G1 ...` is no numbered line, so Marlin runs it
    bare (here an unknown command; Marlin 2.1 would skip an `n101` and move). Its ok looks like
    line 101's; line 102 then draws Resend: 101 and the host sends line 101 again."""
    async with running_printer(MARLIN) as printer:
        hit = once(lambda line: line.startswith(b"N101 "))
        stream = Meddler(printer.link.open_host(), lambda line: b"O" + line[1:] if hit(line) else line)
        async with connect(stream, "marlin") as host:
            summary = await host.print_commands(JOB)
    garbage = f"O101 {JOB[100]}"
    assert printer.journal == JOB[:100] + [garbage] + JOB[100:]
    assert summary.resends == 2 and summary.rejects == 1  # lines 101 and 102


async def test_a_lost_ok_is_recovered_without_running_the_command_twice(autojump_clock):
    async with running_printer(MARLIN) as printer:
        stream = LineDroppingStream(printer.link.open_host(), nth(lambda line: line == b"ok", 150))
        async with connect(stream, "marlin") as host:
            summary = await host.print_commands(JOB)
    assert printer.journal == JOB
    assert stream.dropped == 1
    # One silence, one probe (the line had arrived), no resend; done without its own ok.
    assert (summary.timeouts, summary.resends, summary.unconfirmed) == (1, 0, 1)
    assert host.stats.probes == 3


async def test_auto_reports_neither_hide_a_lost_ok_nor_join_a_response(autojump_clock):
    """Temperatures and positions every second keep the line busy but say nothing about the
    command in flight: a lost ok must still be noticed, and M114's answer stays its own."""
    job = ["M155 S1", "M154 S1"] + [f"G1 X{n % 50} F600" for n in range(60)] + ["M400"]
    async with running_printer(MARLIN) as printer:
        stream = LineDroppingStream(printer.link.open_host(), nth(lambda line: line == b"ok", 30))
        with trio.fail_after(600):  # simulated seconds; a host deceived by the reports waits for ever
            async with connect(stream, "marlin") as host:
                summary = await host.print_commands(job)
                await trio.sleep(3)
                assert await host.send("M114") == ("X:9.00 Y:0.00 Z:0.00 E:0.00 Count X:720 Y:0 Z:0",)
    assert printer.journal == job + ["M114"]
    assert (summary.timeouts, summary.resends, summary.unconfirmed) == (1, 0, 1)


async def test_a_lost_ok_for_the_last_command_is_recovered(autojump_clock):
    job = JOB[:5]
    async with running_printer(MARLIN) as printer:
        # The first ok answers the probe at connect; the sixth is line 5's.
        stream = LineDroppingStream(printer.link.open_host(), nth(lambda line: line == b"ok", 6))
        async with connect(stream, "marlin") as host:
            summary = await host.print_commands(job)
            assert await host.send("M105") == (TEMPERATURES,)  # and the next ok is the next line's
    assert printer.journal == job + ["M105"]
    assert (summary.timeouts, summary.resends, summary.unconfirmed) == (1, 0, 1)


@pytest.mark.parametrize("victim", [b"N57 ", b"N402 "])
async def test_an_ok_whose_error_and_resend_were_lost_is_not_taken_for_the_line(autojump_clock, victim):
    """The printer refuses a damaged line with Error, Resend, ok; only the ok arrives. The host
    counts the line done, so the next line draws Resend for it; for the job's last line, the
    check at the end of the job finds it missing."""
    async with running_printer(MARLIN) as printer:
        damage = once(lambda line: line.startswith(victim))
        errors = once(lambda line: line.startswith(b"Error:"))
        resends = once(lambda line: line.startswith(b"Resend:"))
        stream = Meddler(
            printer.link.open_host(),
            lambda line: corrupt_checksum(line) if damage(line) else line,
            lambda line: errors(line) or resends(line),
        )
        async with connect(stream, "marlin") as host:
            summary = await host.print_commands(JOB)
    assert len(stream.dropped) == 2
    assert printer.journal == JOB
    assert summary.commands == len(JOB)
    number = int(victim[1:])
    assert stream.sent.count(encode_line(number, JOB[number - 1]).rstrip(b"\n")) == 2


async def test_error_resend_and_ok_read_one_by_one_make_one_permission(autojump_clock):
    """printcore's bug (docs/hosts.md): the Resend line and the ok after it are one answer."""
    async with running_printer(MARLIN) as printer:
        damage = nth(lambda line: line.startswith(b"N"), 20)
        stream = Meddler(
            printer.link.open_host(), lambda line: corrupt_checksum(line) if damage(line) else line, by_line=True
        )
        async with connect(stream, "marlin") as host:
            summary = await host.print_commands(JOB[:40])
    assert printer.journal == JOB[:40]
    assert (summary.resends, summary.rejects, summary.timeouts) == (1, 1, 0)
    numbered_lines = [line for line in stream.sent if not line.startswith(b"N0 ")]
    assert len(numbered_lines) == 41  # every line once, the damaged one twice, nothing more


async def test_homing_dwelling_and_slow_moves_never_resend(autojump_clock):
    job = ["G28", "G4 S20", "M400"] + [f"G1 X{200 * (n % 2)} Y{n} F1200" for n in range(40)] + ["M400", "G28 X"]
    async with running_printer(MARLIN) as printer:
        async with connect(printer.link.open_host(), "marlin") as host:
            summary = await host.print_commands(job)
    assert printer.journal == job
    assert summary.elapsed > 39 * 10  # 200 mm at 20 mm/s each: the planner was full, oks late
    assert (summary.resends, summary.timeouts, summary.rejects) == (0, 0, 0)
    assert host.stats.probes == 2


async def test_a_long_silent_command_waits_long_timeout(autojump_clock):
    """With M113 S0 the printer stops its keepalives: a 30 s dwell is silence, and the host
    waits for it (long_timeout), neither resending nor moving on."""
    job = ["M113 S0", "G4 S30", "G1 X1", "M105"]
    async with running_printer(MARLIN) as printer:
        async with connect(printer.link.open_host(), "marlin") as host:
            summary = await host.print_commands(job)
    assert printer.journal == job
    assert (summary.resends, summary.timeouts, summary.unconfirmed) == (0, 0, 0)


async def test_a_printer_whose_counter_is_not_zero_gets_m110_once(autojump_clock):
    async with running_printer(MARLIN) as printer:
        terminal = Terminal(printer.link.open_host())  # another host numbered some lines
        await terminal.quiet_for(1)
        await terminal.command("N0 M110 N0*125")
        await terminal.command(numbered(1, "M105"))
        await terminal.command(numbered(2, "G28"))
        # Our host on the same open port: no reset, the printer's counter is 2. Its first
        # M110 arrives damaged and is refused.
        damage = once(lambda line: b"M110 N0" in line)
        stream = Meddler(printer.link.host, lambda line: corrupt_checksum(line) if damage(line) else line)
        async with connect(stream, "marlin") as host:
            summary = await host.print_commands(JOB[:20])
    assert printer.journal == ["M110 N0", "M105", "G28", "M110 N0"] + JOB[:20]
    assert summary.commands == 20
    assert [line for line in stream.sent if b"M110 N0" in line] == [b"N0 M110 N0*125"] * 2


async def test_the_m110_is_run_once_though_its_ok_is_lost(autojump_clock):
    async with running_printer(MARLIN) as printer:
        terminal = Terminal(printer.link.open_host())
        await terminal.quiet_for(1)
        await terminal.command(numbered(0, "M110 N5"))
        m110_sent = []
        stream = Meddler(
            printer.link.host,
            lambda line: m110_sent.append(line) or line if b"M110 N0" in line else line,
            once(lambda line: line == b"ok" and bool(m110_sent)),
        )
        async with connect(stream, "marlin") as host:
            await host.print_commands(JOB[:3])
    assert stream.dropped == [b"ok"]
    assert printer.journal == ["M110 N5", "M110 N0"] + JOB[:3]


async def test_auto_detection_and_advanced_ok(autojump_clock):
    config = ServerConfig(protocol="auto", advanced_ok=True)
    async with running_printer(config) as printer:
        async with connect(printer.link.open_host(), "marlin") as host:
            summary = await host.print_commands(JOB[:50])
            assert host.room is not None and 0 <= host.room <= 15
            assert await host.send("M105") == (TEMPERATURES,)
    assert printer.journal == JOB[:50] + ["M105"]
    assert summary.resends == 0


async def test_a_reset_mid_print_is_reported(autojump_clock):
    async with running_printer(MARLIN) as printer:
        with pytest.raises(PrinterReset, match="restarted"):
            async with connect(printer.link.open_host(), "marlin") as host:
                await host.print_commands(JOB[:10])
                printer.link.open_host()  # someone else opened the port: the printer resets
                await host.print_commands(JOB[10:])


async def test_a_halt_is_reported(autojump_clock):
    async with running_printer(MARLIN) as printer:
        with pytest.raises(PrinterHalted, match="kill"):
            async with connect(printer.link.open_host(), "marlin") as host:
                await host.send("G28")
                await host.send("M112")
    assert printer.server.printer.halted


async def test_a_port_with_no_printer_gives_up(autojump_clock):
    class Silent:
        async def send_all(self, data: bytes) -> None:
            pass

        async def receive_some(self, max_bytes: int = 4096) -> bytes:
            await trio.sleep_forever()

    start = trio.current_time()
    with pytest.raises(PrinterNotResponding):
        async with connect(Silent(), "marlin") as host:
            await host.send("M105")
    assert trio.current_time() - start < 60


async def test_unsendable_commands_are_refused_before_sending(autojump_clock):
    async with running_printer(MARLIN) as printer:
        for command in ("M110 N7", "G1 X1 ; move", "M117 " + "x" * 90):
            with pytest.raises(CommandError):
                async with connect(printer.link.open_host(), "marlin") as host:
                    await host.send(command)
    assert printer.journal == []


# -- the sans-IO sender alone --------------------------------------------------------------
def synced_sender(**options) -> MarlinCore:
    sender = MarlinCore(**options)
    assert sender.poll(0.0) == [PROBE]
    answer(sender, 0, 0.0)
    return sender


def answer(sender: MarlinCore, last: int, now: float, ok: bool = True) -> None:
    """The printer refuses a line: Error, Resend, ok."""
    sender.on_line_error(last, now)
    sender.on_resend(last + 1, now)
    if ok:
        sender.on_ok(Ok(), (), now)


def test_an_ok_after_resend_is_no_permission_however_it_arrives():
    sender = synced_sender()
    ticket = sender.submit("G28")
    assert sender.poll(1.0) == [encode_line(1, "G28")]
    sender.on_line_error(0, 1.1)
    sender.on_resend(1, 1.1)
    assert sender.poll(1.1) == []  # wait for the ok that belongs to them
    sender.on_ok(Ok(), (), 1.2)
    assert sender.poll(1.2) == [encode_line(1, "G28")]
    assert sender.poll(1.2) == [] and not ticket.done
    sender.on_ok(Ok(), (), 3.0)
    assert ticket.done and ticket.confirmed


def test_when_the_ok_of_a_long_command_comes_before_the_probes_answer():
    """Real Marlin reads no input while G28 runs: the probe waits, and its answer follows G28's
    ok. (The emulator answers at once, before the ok; both orders complete the line once.)"""
    sender = synced_sender()
    ticket = sender.submit("M114")
    sender.poll(1.0)
    assert sender.next_deadline() == 3.0
    assert sender.poll(3.0) == [PROBE]
    sender.on_ok(Ok(), ("X:1.00 Y:0.00",), 3.5)
    assert not ticket.done
    answer(sender, 1, 3.5)
    assert ticket.done and ticket.confirmed and ticket.response == ("X:1.00 Y:0.00",)
    assert sender.stats.resends == 0 and sender.take_completed() == [ticket]


def test_a_disagreeing_report_is_not_believed():
    sender = synced_sender()
    sender.submit("G1 X1")
    sender.poll(1.0)
    sender.on_line_error(7, 1.1)  # a damaged digit: "Last Line: 7" with "Resend: 1"
    sender.on_resend(1, 1.1)
    sender.on_ok(Ok(), (), 1.1)
    assert sender.poll(1.1) == [encode_line(1, "G1 X1")]  # the Resend named the line in flight
    sender.on_line_error(0, 1.2)
    sender.on_resend(9, 1.2)  # names nothing in flight: ask
    sender.on_ok(Ok(), (), 1.2)
    assert sender.poll(1.2) == [PROBE]


def test_an_old_answer_cannot_move_the_host_back():
    sender = synced_sender()
    for number in range(1, 4):
        sender.submit(f"G1 X{number}")
        sender.poll(float(number))
        sender.on_ok(Ok(), (), number + 0.5)
    assert sender.poll(4.0) == []
    sender.request_verification()
    assert sender.poll(4.0) == [PROBE]
    answer(sender, 3, 4.1)
    assert sender.idle
    answer(sender, 1, 4.2)  # a late answer to an earlier probe: nothing to resend
    assert sender.poll(4.3) == [] and sender.idle


def test_a_start_line_before_the_first_answer_is_the_boot_not_a_reset():
    sender = MarlinCore()
    assert sender.poll(0.5) == [PROBE]
    sender.on_line(LineKind.START, "start", 0.6)
    answer(sender, 0, 0.7)
    assert sender.synced
    with pytest.raises(PrinterReset):
        sender.on_line(LineKind.START, "start", 5.0)


def test_m110_is_resent_only_when_a_later_probe_shows_it_did_not_run():
    sender = MarlinCore()
    assert sender.poll(0.5) == [PROBE]
    answer(sender, 5, 0.6)  # another host left the counter at 5
    assert sender.poll(0.6) == [b"\nN0 M110 N0*125\n"]
    answer(sender, 5, 0.7)  # a refusal, or a late answer to an earlier probe: ask again
    assert sender.poll(0.7) == [PROBE]
    answer(sender, 5, 0.8)  # this probe went out after the M110: it did not run
    assert sender.poll(0.8) == [b"\nN0 M110 N0*125\n"]
    sender.on_ok(Ok(), (), 0.9)
    assert sender.poll(0.9) == [PROBE]  # an ok is no proof either; the counter is
    answer(sender, 0, 1.0)
    assert sender.synced and sender.stats.packets_sent == 5


def test_probes_without_answers_end_in_an_error():
    sender = MarlinCore(max_transmissions=3)
    now = 0.0
    with pytest.raises(PrinterNotResponding):
        while now < 100:
            sender.poll(now)
            now = sender.next_deadline()
    assert now <= 3 * 2.0


def probes_until_given_up(sender: MarlinCore, answer_probe) -> int:
    """Probes the sender sends, each answered by `answer_probe(sender, now)`, until it gives up."""
    now, probes = 0.0, 0
    with pytest.raises(PrinterNotResponding, match="no believable answer"):
        while probes < 1000:
            for data in sender.poll(now):
                # (and once a plain M105, to a printer silent from the start: the test below)
                assert data in (PROBE, HELLO)
                probes += 1
                answer_probe(sender, now + 0.01)
            deadline = sender.next_deadline()
            now = max(now + 0.01, deadline if deadline is not None else now)
    return probes


def test_a_silent_printer_is_given_up_on_after_max_transmissions_probes():
    assert probes_until_given_up(MarlinCore(max_transmissions=8), lambda sender, now: None) == 8


def test_answers_that_arrive_damaged_are_no_silence_the_host_keeps_asking():
    """At a bit error rate of 1e-3 half the probes' answers arrive damaged (here: a Resend with
    no legible Error line before it, which cannot be believed): eight in a row are no proof
    of a dead printer. Only many more are (a device that babbles but never answers)."""
    def damaged(sender, now):
        sender.on_resend(None, now)
        sender.on_ok(Ok(), (), now)

    assert probes_until_given_up(MarlinCore(max_transmissions=8), damaged) == 64


def test_a_printer_that_counts_less_than_it_accepted_restarted():
    """A reset whose `start` line was lost: the probes' answers say the counter is 0 again.
    One such answer may be a late one; three in a row are a restarted printer."""
    sender = synced_sender()
    for number, command in enumerate(["G28", "G1 X1", "G1 X2"], 1):
        sender.submit(command)
        assert sender.poll(float(number)) == [encode_line(number, command)]
        sender.on_ok(Ok(), (), number + 0.5)
    sender.submit("G1 X3")
    assert sender.poll(4.0) == [encode_line(4, "G1 X3")]
    now, counts = 4.0, [3]  # the first probe finds line 3 accepted; then the printer restarts
    with pytest.raises(PrinterReset, match="counts line 0, though it had accepted line 3"):
        for _ in range(20):
            deadline = sender.next_deadline()
            now = deadline if deadline is not None else now + 1
            for data in sender.poll(now):
                if data == PROBE:
                    answer(sender, counts.pop() if counts else 0, now + 0.01)


def unprobeable_sender() -> MarlinCore:
    """A printer that takes the probe for a command (Klipper: `ok` to the M105 in it), twice:
    the sender takes it for one that checks no line numbers, and says M110 N0 once."""
    sender = MarlinCore()
    now = 0.0
    for _ in range(2):
        assert sender.poll(now) == [PROBE]
        sender.on_ok(Ok("T:21.0 /0.0"), ("T:21.0 /0.0",), now + 0.01)
        now = sender.next_deadline()
    assert sender.poll(now) == [b"N0 M110 N0*125\n"] and sender.unchecked
    sender.on_ok(Ok(), (), now + 0.01)
    return sender


def test_a_printer_that_checks_no_line_numbers_gets_them_one_in_flight_and_never_twice():
    sender = unprobeable_sender()
    sender.submit("G28")
    sender.submit("G1 X1")
    assert sender.poll(10.0) == [encode_line(1, "G28")]
    sender.on_ok(Ok(), (), 10.1)
    assert sender.poll(10.2) == [encode_line(2, "G1 X1")]
    # Its ok never comes: nothing can tell whether it arrived, so it is not sent again.
    deadline = sender.next_deadline()
    assert sender.poll(deadline) == [] and sender.idle
    assert [t.confirmed for t in sender.take_completed()] == [True, False]
    assert sender.stats.unconfirmed == 1 and sender.stats.resends == 0


def test_a_resend_request_of_an_unprobeable_printer_sends_the_line_it_names():
    sender = unprobeable_sender()
    for number, command in enumerate(["G28", "G1 X1", "G1 X2"], 1):
        sender.submit(command)
        assert sender.poll(float(number)) == [encode_line(number, command)]
        if number < 3:
            sender.on_ok(Ok(), (), number + 0.1)
    sender.on_resend(2, 3.1)  # Smoothieware's `rs N2`: line 2 again, then 3
    assert sender.poll(3.2) == [encode_line(2, "G1 X1")]
    sender.on_ok(Ok(), (), 3.3)
    assert sender.poll(3.4) == [encode_line(3, "G1 X2")]


def _ascii_firmwares() -> list[str]:
    from fake_marlin.emulator.firmware import load_profile, shipped

    return [name for name in shipped() if "marlin" in load_profile(name).protocols]


@pytest.mark.parametrize("firmware, quirks", [
    ("marlin", {"unchecked_line_numbers": True}),
    *((name, {}) for name in _ascii_firmwares()),
])
async def test_our_host_prints_exactly_once_to_every_ascii_firmware(
        autojump_clock, firmware, quirks):
    from fake_marlin.emulator.firmware import Firmware, Quirks, load_profile
    from fake_marlin.emulator.printer.model import Printer
    from fake_marlin.testing import serve_in_memory

    profile = load_profile(firmware)
    made = Firmware.make(profile, quirks=Quirks(**{**profile.quirks.__dict__, **quirks}))
    printer = Printer(made.printer_config())
    async with serve_in_memory(ServerConfig(protocol="marlin"), printer, made) as running:
        async with connect(running.open(), "marlin") as host:
            summary = await host.print_commands(JOB[:50], lambda done: None)
        assert summary.unconfirmed == 0 and summary.commands == 50
        verdict = verify(list(enumerate(JOB[:50], 1)), running.journal)
        assert verdict.passed(), verdict.problems
