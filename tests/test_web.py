"""The live view (emulator/web/): what its snapshots say of printers that ran G-code, that the
wire is recorded only while a printer's page watches it, and the app on hypercorn's trio worker
answering its pages, events and 404s over a real loopback socket. Its page in a browser is in
tests/test_web_browser.py."""

import json
from collections import deque
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import pytest
import trio

from fake_marlin.emulator.faults.rules import FaultKind, FaultRule, Trigger
from fake_marlin.emulator.server.lifecycle import WIRE_CHUNKS, PrinterServer
from fake_marlin.emulator.web import snapshot
from fake_marlin.emulator.web.app import serve_web
from fake_marlin.emulator.web.source import WATCH_LEASE, LocalFarm, watched_detail
from fake_marlin.host import connect
from fake_marlin.testing import MemoryPrinter, memory_printer

JOB = ["G28", "G92 E0", *(f"G1 X{n % 40} Y{n % 9} E{n / 10:.1f} F9000" for n in range(40)),
       "M400"]
DEADLINE = 20  # real seconds: no test of a real socket may hang


async def print_job(printer: MemoryPrinter, commands: list[str]) -> None:
    async with connect(printer.open(), protocol="marlin") as host:
        await host.print_commands(commands)


async def test_a_row_says_what_the_printer_did(autojump_clock):
    async with memory_printer(protocol="marlin") as printer:
        await print_job(printer, ["M104 S200", "M140 S60", *JOB])
        [row] = snapshot.rows([printer.server], [7], ["memory://7"])

    assert row["number"] == 7 and row["path"] == "memory://7"
    assert row["protocol"] == "marlin" and row["firmware"] == "marlin"
    assert row["connected"] is True and row["connects"] == 1
    assert row["commands"] == len(printer.journal) == len(JOB) + 2
    assert row["last_command"] == "M400"
    assert row["hotend"]["target"] == 200 and row["bed"]["target"] == 60
    assert 21 < row["hotend"]["actual"] < 200
    assert row["state"] == "heating"  # the moves are done (M400); the heaters are not there yet
    assert row["planner"] == {"queued": 0, "size": printer.server.printer.planner.max_moves}
    assert row["job"] is None and row["halted"] is False
    assert row["faults_fired"] == 0 and row["faults"] == {}
    json.dumps(row)  # it crosses processes as JSON


async def test_an_idle_printer_without_a_host(autojump_clock):
    async with memory_printer(protocol="auto") as printer:
        [row] = snapshot.rows([printer.server], [1], ["memory"])
    assert row["connected"] is False and row["commands"] == 0 and row["state"] == "idle"
    assert row["protocol"] is None and row["protocol_setting"] == "auto"
    assert row["last_error"] is None and row["resends"] == 0


@pytest.mark.parametrize("protocol", ["marlin", "repetier"])
async def test_refusals_faults_and_a_halt_are_counted(autojump_clock, protocol):
    async with memory_printer(protocol=protocol) as printer:
        host = printer.open()
        await trio.sleep(0.1)
        await host.send_all(b"N1 M105*99\n")  # a wrong checksum: refused, resend asked
        await trio.sleep(0.1)
        server = printer.server
        server.fire_printer_fault(FaultRule(FaultKind.THERMAL_RUNAWAY, Trigger(nth=1)))
        await trio.sleep(0.1)
        [row] = snapshot.rows([server], [1], ["memory"])
        events = [event["kind"] for event in snapshot.detail(server, 1, "memory")["events"]]

    assert row["faults"] == {"thermal-runaway": 1} and row["faults_fired"] == 1
    assert row["state"] == "halted" and row["halted"] is True
    if protocol == "marlin":
        assert row["resends"] == 1
        assert row["last_error"]["text"] == "thermal-runaway"
        assert row["last_error"]["kind"] == "fault"
        assert events == ["reset", "connect", "reset", "resend", "fault"]
    else:
        # Repetier-Firmware asks again, now and then, for a line that does not come (its
        # "no data" resend): refusals go on around the fault, each one counted.
        assert row["resends"] == events.count("resend") >= 1
        assert events[:4] == ["reset", "connect", "reset", "resend"] and "fault" in events
        assert row["last_error"]["kind"] in ("fault", "resend")


async def test_the_wire_is_recorded_only_while_the_page_watches(autojump_clock):
    async with memory_printer(protocol="marlin") as printer:
        server: PrinterServer = printer.server
        plain_deliver = server._deliver
        async with connect(printer.open(), protocol="marlin") as host:
            await host.send("M105")
            assert server.watching is None  # nobody watched: nothing was recorded
            assert snapshot.detail(server, 1, "memory")["tail"] == []

            first = watched_detail(server, 1, "memory")
            assert first["watching"] is not None and first["tail"] == []
            await host.send("M115")
            await host.print_commands(JOB)
            await trio.sleep(1)
            detail = watched_detail(server, 1, "memory")
            tail = detail["tail"]
            assert any(line["dir"] == "in" and "M115" in line["text"] for line in tail)
            assert any(line["dir"] == "out" and line["text"].startswith("FIRMWARE_NAME")
                       for line in tail)
            assert sum(line["dir"] == "in" for line in tail) <= snapshot.TAIL_LINES
            assert [line["t"] for line in tail] == sorted(line["t"] for line in tail)
            series = detail["series"]
            assert len(series["t"]) == 2 and set(series["heaters"]) == {"T0", "B"}
            assert series["rate"][1] > 0 and series["planner_size"] > 0
            assert server._deliver != plain_deliver  # recording: the watched write

            await trio.sleep(WATCH_LEASE + 1)  # the page went: the lease runs out
            assert server.watching is None and server._deliver == plain_deliver
            assert snapshot.detail(server, 1, "memory")["tail"] == []


def test_the_wire_tail_reads_lines_across_reads_and_writes():
    wire = deque([
        (1.0, "in", b"N1 M105*38\nN2 M1"), (1.5, "out", b"ok T:21.0 /0.0\n"),
        (2.0, "in", b"14*35\n"), (2.5, "out", b"ok\r\nUltimaker\x00\xff\n"), (3.0, "in", b"M4"),
    ])
    assert snapshot.wire_tail(wire) == [
        {"t": 1.0, "dir": "in", "text": "N1 M105*38"},
        {"t": 1.5, "dir": "out", "text": "ok T:21.0 /0.0"},
        {"t": 2.0, "dir": "in", "text": "N2 M114*35"},
        {"t": 2.5, "dir": "out", "text": "ok"},
        {"t": 2.5, "dir": "out", "text": "Ultimaker\\x00\\xff"},
        {"t": 3.0, "dir": "in", "text": "M4", "partial": True},
    ]
    assert [line["text"] for line in snapshot.wire_tail(wire, per_direction=1)] == [
        "Ultimaker\\x00\\xff", "M4"]
    # A full recording dropped its oldest reads: the line it begins in the middle of is left out.
    full = deque([(0.0, "in", b"M104 S200\nM105\n")] * WIRE_CHUNKS, maxlen=WIRE_CHUNKS)
    lines = snapshot.wire_tail(full)
    assert len(lines) == snapshot.TAIL_LINES and lines[0]["text"] in ("M104 S200", "M105")
    binary = snapshot.wire_tail(deque([(0.0, "in", bytes(range(256)) * 3)]))
    assert len(binary) == 4 and all(len(line["text"]) <= 4 * snapshot.LINE_CHARS for line in binary)


# -- the app, on a real socket -----------------------------------------------------------------
@asynccontextmanager
async def farm(count: int = 3) -> AsyncIterator[tuple[str, list[MemoryPrinter]]]:
    """`count` printers in memory and the live view of them on a free port."""
    async with trio.open_nursery() as nursery:
        printers: list[MemoryPrinter] = []

        async def one(task_status=trio.TASK_STATUS_IGNORED) -> None:
            async with memory_printer(protocol="marlin") as printer:
                task_status.started(printer)
                await trio.sleep_forever()

        for _ in range(count):
            printers.append(await nursery.start(one))
        source = LocalFarm([p.server for p in printers], list(range(1, count + 1)),
                           [f"memory://{n}" for n in range(1, count + 1)])
        url = await nursery.start(serve_web, "127.0.0.1", 0, source)
        yield url, printers
        nursery.cancel_scope.cancel()


async def get(url: str, path: str, method: str = "GET") -> tuple[int, dict[str, str], bytes]:
    """One request, HTTP/1.1 with `Connection: close`: status, headers, body."""
    host, port = url.removeprefix("http://").rstrip("/").rsplit(":", 1)
    stream = await trio.open_tcp_stream(host, int(port))
    async with stream:
        await stream.send_all(f"{method} {path} HTTP/1.1\r\nHost: {host}\r\n"
                              "Connection: close\r\n\r\n".encode())
        data = b""
        while chunk := await stream.receive_some():
            data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    status_line, *lines = head.decode("latin-1").split("\r\n")
    headers = {k.lower(): v.strip() for k, v in (line.split(":", 1) for line in lines)}
    if headers.get("transfer-encoding") == "chunked":
        body = dechunk(body)
    return int(status_line.split()[1]), headers, body


def dechunk(body: bytes) -> bytes:
    out = b""
    while body:
        size_line, _, body = body.partition(b"\r\n")
        size = int(size_line.split(b";")[0], 16)
        if size == 0:
            break
        out, body = out + body[:size], body[size + 2:]
    return out


async def first_event(url: str, path: str) -> tuple[dict[str, str], dict]:
    """The first event of a server-sent event stream, read as a browser would, then closed."""
    host, port = url.removeprefix("http://").rstrip("/").rsplit(":", 1)
    stream = await trio.open_tcp_stream(host, int(port))
    async with stream:
        await stream.send_all(f"GET {path} HTTP/1.1\r\nHost: {host}\r\n"
                              "Accept: text/event-stream\r\n\r\n".encode())
        data = b""
        while b"\ndata: " not in data or not data.rstrip(b"\r\n").endswith(b"}"):
            data += await stream.receive_some()
    head = data.split(b"\r\n\r\n", 1)[0].decode("latin-1").split("\r\n")[1:]
    headers = {k.lower(): v.strip() for k, v in (line.split(":", 1) for line in head)}
    payload = data.split(b"\ndata: ", 1)[1].split(b"\n", 1)[0]
    return headers, json.loads(payload)


async def test_the_app_serves_the_farm_its_events_and_a_printer():
    with trio.fail_after(DEADLINE):
        async with farm(3) as (url, printers):
            assert url.startswith("http://127.0.0.1:") and url.endswith("/")
            status, headers, body = await get(url, "/")
            assert status == 200 and headers["content-type"].startswith("text/html")
            assert b"<title>fake-marlin farm \xc2\xb7 3 printers</title>" in body
            assert "default-src 'none'" in headers["content-security-policy"]

            headers, event = await first_event(url, "/events")
            assert headers["content-type"].startswith("text/event-stream")
            assert event["numbers"] == [1, 2, 3] and event["total"] == 3
            assert [row["number"] for row in event["rows"]] == [1, 2, 3]
            assert event["summary"]["printers"] == 3 and event["summary"]["connected"] == 0
            _, page = await first_event(url, "/events?size=50&page=9&filter=connected")
            assert page["numbers"] == [] and page["pages"] == 1 and page["page"] == 0

            status, _, body = await get(url, "/printer/2")
            assert status == 200 and b"<h1>Printer 2</h1>" in body and b"memory://2" in body
            assert printers[1].server.watching is not None  # the page watches its printer
            assert printers[0].server.watching is None
            _, detail = await first_event(url, "/printer/2/events")
            assert detail["row"]["number"] == 2 and "tail" in detail and "series" in detail

            status, headers, body = await get(url, "/api/printer/3")
            assert status == 200 and json.loads(body)["row"]["number"] == 3
            status, _, body = await get(url, "/api/farm")
            assert status == 200 and len(json.loads(body)["rows"]) == 3


@pytest.mark.parametrize("path", ["/printer/4", "/printer/0", "/printer/x", "/printer/1/x",
                                  "/nothing", "/api/printer/9"])
async def test_the_app_says_404_for_what_is_not_there(path):
    with trio.fail_after(DEADLINE):
        async with farm(3) as (url, _):
            status, headers, body = await get(url, path)
    assert status == 404 and headers["content-type"].startswith("text/html")
    assert b"Not found" in body and b'href="/"' in body


async def test_the_app_takes_only_get():
    with trio.fail_after(DEADLINE):
        async with farm(1) as (url, _):
            status, headers, _ = await get(url, "/", method="POST")
            head_status, _, head_body = await get(url, "/", method="HEAD")
    assert status == 405 and headers["allow"] == "GET, HEAD"
    assert head_status == 200 and head_body == b""


class TaskSteps(trio.abc.Instrument):
    """Counts the steps trio's tasks take: none while nothing at all runs."""

    def __init__(self) -> None:
        self.steps = 0

    def before_task_step(self, task: trio.lowlevel.Task) -> None:
        self.steps += 1


async def test_the_view_costs_an_idle_farm_nothing():
    with trio.fail_after(DEADLINE):
        async with farm(20) as (url, _):
            steps = TaskSteps()
            await trio.sleep(0.2)
            trio.lowlevel.add_instrument(steps)
            await trio.sleep(1.0)  # served, nobody looking: no task runs but this one's sleep
            idle = steps.steps
            await first_event(url, "/events")  # a page came and went
            await trio.sleep(0.3)
            steps.steps = 0
            await trio.sleep(1.5)
            after = steps.steps
            trio.lowlevel.remove_instrument(steps)
    assert idle <= 1 and after <= 1


async def test_a_farm_of_many_printers_comes_a_page_at_a_time():
    with trio.fail_after(DEADLINE):
        async with farm(120) as (url, _):
            _, event = await first_event(url, "/events?size=50&page=3")
    assert event["numbers"] == list(range(101, 121)) and event["pages"] == 3
    assert event["page"] == 2 and event["total"] == 120 and len(event["rows"]) == 20
    assert event["summary"]["printers"] == 120


async def test_a_port_taken_is_said_plainly():
    with trio.fail_after(DEADLINE):
        async with farm(1) as (url, printers):
            port = int(url.rstrip("/").rsplit(":", 1)[1])
            source = LocalFarm([printers[0].server], [1], ["memory://1"])
            async with trio.open_nursery() as nursery:
                taken = f"cannot serve the live view on 127.0.0.1:{port}"
                with pytest.raises(OSError, match=taken):
                    await nursery.start(serve_web, "127.0.0.1", port, source)
