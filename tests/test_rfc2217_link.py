"""The printer on an RFC 2217 port (emulator/link/rfc2217.py), with pyserial's client and ours
(rfc2217:// in host/url_port.py): the baud rate the client sets, DTR pulses, and telnet's
escaping, over real loopback sockets."""

import time

import pytest
import serial
import trio

from fake_marlin.emulator.link.rfc2217 import Rfc2217Link
from fake_marlin.emulator.link.tcp import REFUSAL
from fake_marlin.host import open_printer
from fake_marlin.host.errors import PortError
from tests.test_tcp_link import JOB, fast_clock, read_all, serving, wait_for  # noqa: F401

pytestmark = [
    # End to end: pyserial's own RFC 2217 client, the one hosts open rfc2217:// URLs with, over
    # real loopback sockets, on real time (it polls in 50 ms steps; an open and a close take
    # about 0.35 s each).
    pytest.mark.e2e,
    # pyserial 3.5 names its reader thread the old way.
    pytest.mark.filterwarnings(r"ignore:set(Daemon|Name)\(\) is deprecated:DeprecationWarning"),
]


def open_serial(url: str, baudrate: int) -> serial.SerialBase:
    return serial.serial_for_url(url, baudrate, timeout=5)


def read_until(port: serial.SerialBase, marker: bytes) -> bytes:
    data = port.read_until(marker)
    assert data.endswith(marker), f"no {marker!r} in 5 s, only {data!r}"
    return data


async def test_a_job_over_rfc2217_runs_once_and_the_printer_knows_the_baud_rate(fast_clock):
    async with serving(Rfc2217Link()) as printer:
        assert printer.link.path == f"rfc2217://127.0.0.1:{printer.link.port}"
        assert printer.link.host_baud() is None  # nobody has set one
        async with open_printer(printer.link.path, protocol="marlin", baudrate=115200) as host:
            await host.print_commands(JOB)
            assert printer.link.host_baud() == 115200
        assert printer.journal == JOB
        assert printer.server.boots == 2  # power on, then the connection: once, not twice


async def test_a_dtr_pulse_reboots_the_printer_and_the_greeting_survives_the_open():
    async with serving(Rfc2217Link()) as printer:
        port = await trio.to_thread.run_sync(open_serial, printer.link.path, 57600)
        try:
            # pyserial's open() purges its input last; the connection's reset comes after that,
            # so the greeting is not purged with it.
            await trio.to_thread.run_sync(read_until, port, b"start\n")
            assert printer.server.boots == 2
            assert printer.link.host_baud() == 57600

            def pulse() -> None:  # as the Arduino IDE resets a board
                port.dtr = False
                time.sleep(0.05)
                port.dtr = True

            await trio.to_thread.run_sync(pulse)
            await trio.to_thread.run_sync(read_until, port, b"start\n")
            assert printer.server.boots == 3
            def raise_dtr() -> None:  # raised again while raised: no pulse, no reset
                port.dtr = True

            await trio.to_thread.run_sync(raise_dtr)
            await trio.to_thread.run_sync(port.write, b"M114\n")
            await trio.to_thread.run_sync(read_until, port, b"ok\n")
            assert printer.server.boots == 3
            assert printer.journal == ["M114"]
        finally:
            await trio.to_thread.run_sync(port.close)


async def test_the_host_baud_rate_paces_the_line():
    async with serving(Rfc2217Link(), baud_from_host=True) as printer:
        port = await trio.to_thread.run_sync(open_serial, printer.link.path, 19200)
        try:
            await trio.to_thread.run_sync(read_until, port, b"start\n")
            started = trio.current_time()
            await trio.to_thread.run_sync(port.write, b"M115\n")
            reply = await trio.to_thread.run_sync(read_until, port, b"ok\n")
            elapsed = trio.current_time() - started
        finally:
            await trio.to_thread.run_sync(port.close)
    # 10 bits a byte at 19200 baud (unpaced, loopback takes a millisecond or two).
    assert elapsed >= 0.8 * len(reply) * 10 / 19200, (len(reply), elapsed)


async def test_bytes_0xff_pass_escaped_both_ways():
    async with serving(Rfc2217Link(), protocol="commstack") as printer:
        port = await trio.to_thread.run_sync(open_serial, printer.link.path, 115200)
        try:
            await wait_for(lambda: printer.link._host and printer.link._host.announced, "reset")
            printer.link.send(b"\xffA\xff\xff\n")
            received = await trio.to_thread.run_sync(read_until, port, b"A\xff\xff\n")
            assert received.endswith(b"\xffA\xff\xff\n")  # after the printer's own frames
        finally:
            await trio.to_thread.run_sync(port.close)


async def test_ultimaker_packets_whose_0xffff_telnet_must_double_arrive_intact(fast_clock):
    async with serving(Rfc2217Link(), protocol="ultimaker") as printer:
        async with open_printer(printer.link.path, protocol="ultimaker") as host:
            summary = await host.print_commands(JOB)
        assert summary.resends == 0 and summary.rejects == 0
        assert printer.journal == JOB


async def test_a_second_client_is_refused_and_ours_says_so(fast_clock):
    async with serving(Rfc2217Link()) as printer:
        async with open_printer(printer.link.path, protocol="marlin") as host:
            second = await trio.open_tcp_stream("127.0.0.1", printer.link.port)
            assert await read_all(second) == REFUSAL
            await second.aclose()
            # pyserial waits for the negotiation that never comes: 3 s, unless the URL's
            # `timeout` says otherwise.
            with pytest.raises(PortError, match="no RFC 2217 answer .*another host already"):
                async with open_printer(f"{printer.link.path}?timeout=0.5", protocol="marlin"):
                    pass
            await host.print_commands(JOB[:10])
        assert printer.journal == JOB[:10]


async def test_malformed_telnet_drops_that_client_not_the_printer(fast_clock, capsys):
    async with serving(Rfc2217Link()) as printer:
        bad = await trio.open_tcp_stream("127.0.0.1", printer.link.port)
        # COM-PORT-OPTION SET-BAUDRATE without its four bytes: PortManager trips on it.
        await bad.send_all(b"\xff\xfa\x2c\x01\xff\xf0")
        said: list[str] = []

        def dropped() -> bool:
            said.append(capsys.readouterr().err)
            return "bad telnet negotiation" in "".join(said)

        await wait_for(dropped, "the client dropped")
        await bad.aclose()
        async with open_printer(printer.link.path, protocol="marlin") as host:
            await host.print_commands(JOB[:10])
        assert printer.journal == JOB[:10]


async def test_refused_connection_is_a_port_error():
    link = Rfc2217Link()
    url = link.path
    link.close()
    with pytest.raises(PortError, match=f"cannot open {url}: Connection refused"):
        async with open_printer(url, protocol="marlin"):
            pass
