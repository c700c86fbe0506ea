"""The printer on a TCP port (emulator/link/tcp.py) and our host on socket:// URLs
(host/url_port.py): in-process over real loopback sockets, then `fake-marlin --tcp` with our
host's command line and with Printrun's printcore, which takes HOST:PORT as its port."""

import io
import json
import signal
import socket
import struct
import subprocess
import sys
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

import pytest
import trio

from fake_marlin.emulator.cli import links
from fake_marlin.emulator.cli.farm import PrinterPlan, copies
from fake_marlin.emulator.faults.layer import FaultConfig
from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.link.tcp import REFUSAL, LinkError, TcpLink
from fake_marlin.emulator.printer.model import Printer
from fake_marlin.emulator.scenario.definition import PrinterSetup
from fake_marlin.emulator.server.clock import ScaledClock
from fake_marlin.emulator.server.lifecycle import PrinterServer, ServerConfig
from fake_marlin.host import open_printer
from fake_marlin.host.codecs.marlin import Line
from fake_marlin.host.errors import ConnectionLost, PortError
from tests.test_real_hosts import printrun_python, run_driver, unnumbered, write_job  # noqa: F401

BIN = Path(sys.executable).parent
JOB = ["G28", "G92 E0", *(f"G1 X{n % 40} Y{n % 9} E{n / 10:.1f} F9000" for n in range(150)),
       "M105", "M400", "M114"]
DEADLINE = 30  # real seconds: no test may hang


@pytest.fixture
def fast_clock():
    """Simulated time 20 times faster than real time, as `fake-marlin --speed 20`: the moves
    take little real time, and a host's timeouts are still far longer than loopback's delays."""
    return ScaledClock(20)


class Served:
    def __init__(self, link: TcpLink, server: PrinterServer, journal: io.StringIO) -> None:
        self.link, self.server, self._journal = link, server, journal

    @property
    def journal(self) -> list[str]:
        return self._journal.getvalue().splitlines()


def speed() -> float:
    """How much faster than real time this test's trio clock runs."""
    clock = trio.lowlevel.current_clock()
    return clock.speed if isinstance(clock, ScaledClock) else 1


@asynccontextmanager
async def serving(link: TcpLink, protocol: str = "marlin", **config) -> AsyncIterator[Served]:
    """A printer on `link` in this trio run, as `fake-marlin` serves one."""
    text = io.StringIO()
    config = ServerConfig(protocol=protocol, **config)
    server = PrinterServer(link, Printer(), Journal(text), config)
    try:
        with trio.fail_after(DEADLINE * speed()):  # real seconds
            async with trio.open_nursery() as nursery:
                await nursery.start(server.run)
                yield Served(link, server, text)
                nursery.cancel_scope.cancel()
    finally:
        link.close()


async def read_all(stream: trio.SocketStream) -> bytes:
    data = b""
    while chunk := await stream.receive_some():
        data += chunk
    return data


async def wait_for(condition, what: str, seconds: float = 10) -> None:
    """Wait until condition() holds, for at most `seconds` of real time."""
    with trio.move_on_after(seconds * speed()):
        while not condition():
            await trio.sleep(0.01)
        return
    raise AssertionError(f"not so after {seconds} s: {what}")


# -- in-process ---------------------------------------------------------------------------------
async def test_a_job_over_tcp_runs_each_command_exactly_once(fast_clock):
    async with serving(TcpLink()) as printer:
        assert printer.link.path == f"socket://127.0.0.1:{printer.link.port}"
        assert printer.link.port != 0
        async with open_printer(printer.link.path, protocol="marlin") as host:
            summary = await host.print_commands(JOB)
        assert summary.commands == len(JOB)
        # The connection reset the printer, so its line counter was 0: no M110 from the host.
        assert printer.journal == JOB
        assert printer.server.boots == 2  # power on, then the host's connection


async def test_a_second_host_is_refused_and_the_first_prints_on(fast_clock):
    async with serving(TcpLink()) as printer:
        async with open_printer(printer.link.path, protocol="marlin") as host:
            await host.send("M105")
            second = await trio.open_tcp_stream("127.0.0.1", printer.link.port)
            assert await read_all(second) == REFUSAL
            await second.aclose()
            # Our own host, refused, says what the printer said.
            with pytest.raises(ConnectionLost, match="saying: fake-marlin: this printer already"):
                async with open_printer(printer.link.path, protocol="marlin") as refused:
                    await refused.send("M105")
            await host.print_commands(JOB)
        assert printer.journal == ["M105", *JOB]
        assert printer.server.boots == 2  # the refused hosts reset nothing


async def test_each_connection_reboots_the_printer_and_the_host_sees_start(fast_clock):
    seen: list[str] = []

    def on_line(line) -> None:
        if isinstance(line, Line):
            seen.append(line.text)

    async with serving(TcpLink()) as printer:
        for visit in (1, 2):
            async with open_printer(printer.link.path, protocol="marlin", on_line=on_line) as host:
                await host.send("G28")
            assert seen.count("start") == visit
        # Between hosts the printer runs on, talking to nobody: its output is dropped.
        await wait_for(lambda: printer.link._host is None, "the host gone")
        printer.server.announce(["nobody hears this"])
        assert not printer.link._pending
        assert printer.server.boots == 3
        assert printer.journal == ["G28", "G28"]


async def test_a_host_that_vanishes_mid_line_leaves_the_printer_to_the_next(fast_clock):
    async with serving(TcpLink()) as printer:
        rude = socket.create_connection(("127.0.0.1", printer.link.port))
        rude.sendall(b"N1 G28*")  # half a line, then a reset instead of a close
        rude.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        await wait_for(lambda: printer.server.boots == 2, "the rude host's reset")
        rude.close()
        await wait_for(lambda: printer.link._host is None, "the rude host dropped")
        async with open_printer(printer.link.path, protocol="marlin") as host:
            await host.print_commands(JOB[:20])
        assert printer.journal == JOB[:20]


async def test_a_hung_up_line_refuses_hosts_until_it_comes_back_on_the_same_port(fast_clock):
    announced: list[str] = []
    link = TcpLink()
    link.on_new_path = announced.append
    async with serving(link) as printer:
        with pytest.raises(ConnectionLost, match=f"lost the connection to 127.0.0.1:{link.port}"):
            async with open_printer(link.path, protocol="marlin") as host:
                await host.send("M105")
                link.hang_up()
                await host.send("M114")
        with pytest.raises(PortError, match=f"cannot connect to 127.0.0.1:{link.port}: "
                                            "Connection refused"):
            async with open_printer(link.path, protocol="marlin"):
                pass
        link.reconnect()
        await wait_for(lambda: announced, "the line announced again")
        assert announced == [link.path]
        async with open_printer(link.path, protocol="marlin") as host:
            await host.send("M114")
        assert printer.journal[0] == "M105" and printer.journal[-1] == "M114"


async def test_output_to_a_host_that_does_not_read_is_bounded_and_never_blocks_the_printer():
    async with serving(TcpLink()) as printer:
        idle = await trio.open_tcp_stream("127.0.0.1", printer.link.port)
        await wait_for(lambda: printer.server.boots == 2, "the connection's reset")
        for _ in range(3000):  # 3 MB the host never reads
            printer.link.send(b"x" * 1000)
        assert len(printer.link._pending) <= 1 << 20
        await idle.aclose()


# -- what goes wrong, said plainly --------------------------------------------------------------
@pytest.mark.parametrize("port, message", [
    ("socket://127.0.0.1", "cannot open socket://127.0.0.1: expected socket://HOST:PORT"),
    ("socket://127.0.0.1:http", "cannot open socket://127.0.0.1:http: Port could not be cast"),
    ("socket://no-such-host.invalid:8099", "cannot connect to no-such-host.invalid:8099: "),
    ("telnet://127.0.0.1:23", "unknown kind of URL; use socket://HOST:PORT or rfc2217://"),
])
async def test_bad_urls_are_port_errors_that_say_why(port, message):
    with pytest.raises(PortError, match=message.replace("?", r"\?")):
        async with open_printer(port, protocol="marlin"):
            pass


async def test_a_taken_port_is_a_link_error():
    with socket.create_server(("127.0.0.1", 0)) as taken:
        number = taken.getsockname()[1]
        with pytest.raises(LinkError, match=f"cannot listen on 127.0.0.1:{number}: "
                                            "Address already in use"):
            TcpLink("127.0.0.1", number)


# -- the command line's glue (emulator/cli/links.py) -------------------------------------------
def link_parser():
    import argparse

    parser = argparse.ArgumentParser(prog="fake-marlin")
    parser.add_argument("--link")
    links.add_link_arguments(parser)
    return parser


def plans(argv: list[str], count: int) -> list[PrinterPlan]:
    """What --printers `count` makes of these link arguments: each printer's addresses."""
    args = link_parser().parse_args(argv)
    base = PrinterPlan(1, PrinterSetup(), FaultConfig(),
                       tcp=args.tcp, rfc2217=args.rfc2217)
    return copies(base, count)


def links_of(plans: list[PrinterPlan]) -> list:
    return [links.make_link(plan.tcp, plan.rfc2217) for plan in plans]


def test_make_link_gives_printer_n_the_port_plus_n():
    made = links_of(plans(["--tcp", "127.0.0.1:0"], 2))
    try:
        assert all(isinstance(link, TcpLink) for link in made)
        assert made[0].port != made[1].port  # port 0: each its own free port
    finally:
        for link in made:
            link.close()
    with socket.create_server(("127.0.0.1", 0)) as probe:
        free = probe.getsockname()[1]
    second = links_of(plans(["--rfc2217", str(free)], 2)[1:])[0]
    try:
        assert second.path == f"rfc2217://127.0.0.1:{free + 1}"
    finally:
        second.close()
    assert links_of(plans([], 1)) == [None]


@pytest.mark.parametrize("argv, message", [
    (["--tcp", "x"], "argument --tcp: the port must be a number from 0 (any free port) to 65535"),
    (["--tcp", "70000"], "argument --tcp: the port must be a number"),
    (["--tcp", "::1"], "argument --tcp: expected [HOST:]PORT"),
    (["--tcp", "1", "--rfc2217", "2"], "argument --rfc2217: not allowed with argument --tcp"),
    (["--tcp", "1", "--link", "/tmp/p"], "argument --link: there is no pty to link to with --tcp"),
])
def test_bad_link_arguments_are_usage_errors(argv, message, capsys):
    parser = link_parser()
    with pytest.raises(SystemExit) as exit:
        links.check_link_arguments(parser, parser.parse_args(argv))
    assert exit.value.code == 2
    assert message in capsys.readouterr().err


# -- the programs ---------------------------------------------------------------------------------
@pytest.mark.e2e
def test_fake_marlin_tcp_prints_its_url_and_our_host_prints_over_it(fake_printer_factory, tmp_path):
    printer = fake_printer_factory(protocol="marlin", speed=50, extra_args=["--tcp", "127.0.0.1:0"])
    assert printer.port.startswith("socket://127.0.0.1:")
    job = tmp_path / "job.gcode"
    job.write_text("\n".join(JOB) + "\n")
    done = subprocess.run(
        [BIN / "fake-marlin-host", "print", printer.port, job, "--protocol", "marlin", "--json"],
        capture_output=True, text=True, timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["commands"] == len(JOB)
    assert printer.journal == JOB


@pytest.mark.e2e
def test_fake_marlin_tcp_with_several_printers_takes_consecutive_ports():
    with socket.create_server(("127.0.0.1", 0)) as probe:
        free = probe.getsockname()[1]
    # Not a FakePrinter: its one journal and SD card are for one printer.
    process = subprocess.Popen(
        [BIN / "fake-marlin", "--protocol", "marlin", "--printers", "3",
         "--tcp", f"127.0.0.1:{free}"],
        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        urls = [process.stdout.readline().strip() for _ in range(3)]
        assert urls == [f"socket://127.0.0.1:{free + n}" for n in range(3)], process.stderr
        with socket.create_connection(("127.0.0.1", free + 2), timeout=10) as third:
            said = b""
            while b"start\n" not in said:  # its connection's reset
                said += third.recv(4096) or pytest.fail(f"closed, after {said!r}")
            third.sendall(b"M105\n")
            while b"ok T:" not in said:
                said += third.recv(4096) or pytest.fail(f"closed, after {said!r}")
    finally:
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=10)
    assert process.returncode == 0 and "Traceback" not in stderr, stderr


@pytest.mark.e2e
def test_fake_marlin_says_plainly_when_its_port_is_taken(tmp_path):
    with socket.create_server(("127.0.0.1", 0)) as taken:
        number = taken.getsockname()[1]
        done = subprocess.run([BIN / "fake-marlin", "--tcp", f"127.0.0.1:{number}"],
                              capture_output=True, text=True, timeout=30)
    assert done.returncode == 2
    assert f"cannot listen on 127.0.0.1:{number}: Address already in use" in done.stderr
    assert "Traceback" not in done.stderr


@pytest.mark.e2e
def test_fake_marlin_rfc2217_prints_its_url_and_our_host_prints_over_it(fake_printer_factory,
                                                                        tmp_path):
    printer = fake_printer_factory(protocol="marlin", speed=50,
                                   extra_args=["--rfc2217", "127.0.0.1:0"])
    assert printer.port.startswith("rfc2217://127.0.0.1:")
    done = subprocess.run(
        [BIN / "fake-marlin-host", "send", printer.port, "M115", "--protocol", "marlin"],
        capture_output=True, text=True, timeout=60,
    )
    assert done.returncode == 0, done.stderr
    assert "FIRMWARE_NAME:Marlin" in done.stdout
    assert printer.journal == ["M115"]


@pytest.mark.e2e
def test_printcore_streams_a_file_over_tcp(fake_printer_factory, printrun_python, tmp_path):
    """Printrun's printcore takes HOST:PORT as its port and connects a socket to it."""
    printer = fake_printer_factory(protocol="marlin", speed=50, extra_args=["--tcp", "127.0.0.1:0"])
    address = printer.port.removeprefix("socket://")
    gcode = tmp_path / "job.gcode"
    commands = write_job(gcode, 2000)
    code, report = run_driver(printrun_python, "printcore_driver.py", address, gcode)
    assert code == 0 and report["errors"] == [] and not report["printer_errors"], json.dumps(
        {key: value for key, value in report.items() if key != "sent"}, indent=1)
    # As over the pty (test_real_hosts): hellos, then the job between printcore's M110s, and
    # the connection's reset left the printer's counter at 0.
    sent = [unnumbered(line) for line in report["sent"]]
    hellos = len(sent) - len(commands) - 2
    assert hellos >= 1 and sent == ["M105"] * hellos + ["M110 N-1", *commands, "M110 N-1"]
    assert printer.journal == sent
