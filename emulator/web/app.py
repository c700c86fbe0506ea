"""The live view's web server: a small ASGI app on hypercorn's trio worker, in the printers'
own trio run.

    /                  the farm: a summary and a page of rows, live    (pages.farm_page)
    /events            its server-sent events: ?page=1&size=200&filter=all
    /printer/N         printer N: cards, plots, wire tail, events      (pages.printer_page)
    /printer/N/events  its server-sent events
    /api/farm          every row, as JSON;  /api/printer/N: printer N's detail, as JSON

It costs nothing while nobody looks: no task runs but hypercorn's accept. A Ticker per view
(the farm, or one printer) runs only while a page of it is open, reading its source once a
real second whatever the number of pages, and hands the same reading to each of them.
"""

import json
import math
from collections.abc import AsyncGenerator, AsyncIterator, Awaitable, Callable
from contextlib import aclosing, asynccontextmanager
from functools import partial
from typing import Any, cast
from urllib.parse import parse_qs

import trio
from hypercorn.config import Config
from hypercorn.trio import serve
from hypercorn.typing import Framework

from fake_marlin.emulator.link.tcp import host_port
from fake_marlin.emulator.web import pages
from fake_marlin.emulator.web.source import FarmSource, clock_speed

PERIOD = 1.0  # real seconds between two readings of a view
RETRY_MS = 2000  # how soon a page's EventSource reconnects to a server that went away
# Everything the pages use is inline or from here: any other source is refused by the browser.
POLICY = ("default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; "
          "img-src data:; connect-src 'self'; base-uri 'none'; form-action 'none'")

Scope = dict[str, Any]
Message = dict[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]


class Ticker:
    """Reads a view (`fetch`) once a PERIOD while anyone listens, and hands each reading to
    every listener; with no listener, no task."""

    def __init__(self, fetch: Callable[[], Awaitable[object]], nursery: trio.Nursery) -> None:
        self._fetch = fetch
        self._nursery = nursery
        self.listeners = 0
        self.value: object = None
        self.version = 0
        self._changed = trio.Event()
        self._scope: trio.CancelScope | None = None

    @asynccontextmanager
    async def listening(self) -> AsyncIterator["Ticker"]:
        self.listeners += 1
        if self._scope is None:
            self._scope = trio.CancelScope()
            self._nursery.start_soon(self._run, self._scope)
        try:
            yield self
        finally:
            self.listeners -= 1
            if self.listeners == 0 and self._scope is not None:
                self._scope.cancel()
                self._scope = None

    async def readings(self) -> AsyncIterator[object]:
        """Each new reading, from the next one on (a listener never gets one made before)."""
        seen = self.version
        while True:
            while self.version == seen:
                await self._changed.wait()
            seen = self.version
            yield self.value

    async def _run(self, scope: trio.CancelScope) -> None:
        with scope:
            while True:
                began = trio.current_time()
                try:
                    self.value = await self._fetch()
                except Exception as error:  # noqa: BLE001 (a farm process gone: say so, try again)
                    self.value = {"error": f"{type(error).__name__}: {error}"}
                self.version += 1
                self._changed.set()
                self._changed = trio.Event()
                await trio.sleep_until(began + PERIOD * clock_speed())


def _counts(rows: list[dict[str, Any]]) -> dict[str, int]:
    return {key: sum(1 for row in rows if test(row)) for key, test in FILTER_TESTS.items()}


FILTER_TESTS: dict[str, Callable[[dict[str, Any]], bool]] = {
    "all": lambda row: True,
    "connected": lambda row: bool(row["connected"]),
    "printing": lambda row: row["state"] == "printing",
    "heating": lambda row: row["state"] == "heating",
    "halted": lambda row: bool(row["halted"]),
    "errors": lambda row: bool(row["resends"] or row["last_error"] or row["halted"]),
}


class FarmReading:
    """The farm's rows as one reading: each with its commands per second since the reading
    before (simulated seconds, as the report's), and the summary over all of them."""

    def __init__(self, source: FarmSource) -> None:
        self._source = source
        self._before: dict[int, tuple[int, float]] = {}

    async def __call__(self) -> dict[str, Any]:
        rows = await self._source.rows()
        total_rate = 0.0
        for row in rows:
            add_rate(row, self._before)
            total_rate += row["rate"] or 0.0
        counts = _counts(rows)
        return {
            "rows": rows,
            "summary": {
                "printers": len(rows), "connected": counts["connected"],
                "printing": counts["printing"], "heating": counts["heating"],
                "halted": counts["halted"], "errors": counts["errors"],
                "rate": round(total_rate, 1), "commands": sum(row["commands"] for row in rows),
                "counts": counts,
            },
        }


def add_rate(row: dict[str, Any], before: dict[int, tuple[int, float]]) -> None:
    """Commands per simulated second since `before` (by printer number, updated), into the
    row, which then loses its time: a row that did not change reads the same."""
    number, commands, now = row["number"], row["commands"], row.pop("time")
    last = before.get(number)
    row["rate"] = None
    if last is not None and now > last[1]:
        row["rate"] = round(max(0, commands - last[0]) / (now - last[1]), 1)
    before[number] = (commands, now)


class LiveView:
    """The ASGI app (see the module's docstring)."""

    def __init__(self, source: FarmSource, nursery: trio.Nursery) -> None:
        self.source = source
        self._nursery = nursery
        self.farm = Ticker(FarmReading(source), nursery)
        self._api_reading = FarmReading(source)  # /api/farm's: rates since the last request
        self._printers: dict[int, Ticker] = {}

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "lifespan":
            await _lifespan(receive, send)
            return
        if scope["type"] != "http":
            return  # (a WebSocket: refused by returning before accepting)
        if scope["method"] not in ("GET", "HEAD"):
            await _respond(send, 405, b"GET only\n", "text/plain", [(b"allow", b"GET, HEAD")])
            return
        path = scope["path"]
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        head = scope["method"] == "HEAD"
        parts = path.strip("/").split("/")
        if path == "/":
            rows = await self.source.rows()
            await _html(send, 200, pages.farm_page(len(rows)), head)
        elif path == "/events":
            await self._farm_events(receive, send, query)
        elif path == "/api/farm":
            await _json(send, await self._api_reading(), head)
        elif path == "/favicon.ico":
            await _respond(send, 204, b"", "text/plain")
        elif parts[0] == "printer" and len(parts) == 2:
            await self._printer(receive, send, "page", parts[1], head)
        elif parts[0] == "printer" and len(parts) == 3 and parts[2] == "events":
            await self._printer(receive, send, "events", parts[1], head)
        elif parts[:2] == ["api", "printer"] and len(parts) == 3:
            await self._printer(receive, send, "api", parts[2], head)
        else:
            await _html(send, 404, pages.not_found_page(f"There is no page {path} here."), head)

    async def _printer(self, receive: Receive, send: Send, kind: str, text: str,
                       head: bool) -> None:
        """Printer `text`'s page, its events or its JSON (`kind`); 404 for no such printer."""
        number = int(text) if text.isdigit() and len(text) < 10 else None
        detail = None if number is None else await self.source.detail(number)
        if detail is None or number is None:
            await _html(send, 404, pages.not_found_page(
                f"This farm has no printer {text}."), head)
        elif kind == "api":
            await _json(send, detail, head)
        elif kind == "events":
            await self._printer_events(receive, send, number)
        else:
            row = detail["row"]
            await _html(send, 200, pages.printer_page(number, row["path"], row["firmware_title"]),
                        head)

    async def _farm_events(self, receive: Receive, send: Send, query: dict[str, list[str]]) -> None:
        size = _whole(query, "size", pages.DEFAULT_PAGE_SIZE)
        size = size if size in pages.PAGE_SIZES else pages.DEFAULT_PAGE_SIZE
        page = max(1, _whole(query, "page", 1)) - 1
        chosen = query.get("filter", ["all"])[0]
        test = FILTER_TESTS.get(chosen, FILTER_TESTS["all"])
        sent: dict[int, dict[str, Any]] = {}

        async def events() -> AsyncGenerator[bytes, None]:
            nonlocal page
            async with self.farm.listening() as ticker:
                async for reading in ticker.readings():
                    reading = cast(dict[str, Any], reading)
                    if "error" in reading:
                        yield _event({"error": reading["error"]})
                        continue
                    matching = [row for row in reading["rows"] if test(row)]
                    count = max(1, math.ceil(len(matching) / size))
                    page = min(page, count - 1)
                    shown = matching[page * size:(page + 1) * size]
                    changed = [row for row in shown if sent.get(row["number"]) != row]
                    sent.clear()
                    sent.update((row["number"], row) for row in shown)
                    yield _event({
                        "summary": reading["summary"], "filter": chosen, "page": page,
                        "pages": count, "size": size, "total": len(matching),
                        "numbers": [row["number"] for row in shown], "rows": changed,
                    })

        await _stream(receive, send, events())

    async def _printer_events(self, receive: Receive, send: Send, number: int) -> None:
        ticker = self._printers.get(number)
        if ticker is None:
            ticker = self._printers[number] = Ticker(PrinterReading(self.source, number),
                                                     self._nursery)

        async def events() -> AsyncGenerator[bytes, None]:
            async with ticker.listening():
                async for reading in ticker.readings():
                    yield _event(reading if reading is not None else {"gone": True})

        try:
            await _stream(receive, send, events())
        finally:
            if ticker.listeners == 0:
                self._printers.pop(number, None)


class PrinterReading:
    """A printer's detail as one reading, its row with commands per second as the farm's."""

    def __init__(self, source: FarmSource, number: int) -> None:
        self._source = source
        self._number = number
        self._before: dict[int, tuple[int, float]] = {}

    async def __call__(self) -> dict[str, Any] | None:
        detail = await self._source.detail(self._number)
        if detail is not None:
            add_rate(detail["row"], self._before)
        return detail


def _whole(query: dict[str, list[str]], key: str, default: int) -> int:
    text = query.get(key, [""])[0]
    return int(text) if text.isdigit() and len(text) < 7 else default


def _event(data: object) -> bytes:
    return b"data: " + json.dumps(data, separators=(",", ":")).encode() + b"\n\n"


async def _stream(receive: Receive, send: Send, events: AsyncGenerator[bytes, None]) -> None:
    """Server-sent events until the page goes (http.disconnect); then `events` is closed at
    once, so that its view stops listening."""
    await send({"type": "http.response.start", "status": 200, "headers": [
        (b"content-type", b"text/event-stream; charset=utf-8"), (b"cache-control", b"no-store"),
        (b"x-accel-buffering", b"no"), (b"content-security-policy", POLICY.encode()),
    ]})
    async with trio.open_nursery() as nursery:
        async def until_gone() -> None:
            while (await receive())["type"] != "http.disconnect":
                pass
            nursery.cancel_scope.cancel()

        nursery.start_soon(until_gone)
        await send({"type": "http.response.body", "body": f"retry: {RETRY_MS}\n\n".encode(),
                    "more_body": True})
        async with aclosing(events):
            async for chunk in events:
                await send({"type": "http.response.body", "body": chunk, "more_body": True})


async def _respond(send: Send, status: int, body: bytes, content_type: str,
                   headers: list[tuple[bytes, bytes]] | None = None, head: bool = False) -> None:
    await send({"type": "http.response.start", "status": status, "headers": [
        (b"content-type", content_type.encode()), (b"content-length", str(len(body)).encode()),
        (b"cache-control", b"no-store"), (b"content-security-policy", POLICY.encode()),
        (b"x-content-type-options", b"nosniff"), *(headers or []),
    ]})
    await send({"type": "http.response.body", "body": b"" if head else body})


async def _html(send: Send, status: int, text: str, head: bool = False) -> None:
    await _respond(send, status, text.encode(), "text/html; charset=utf-8", head=head)


async def _json(send: Send, data: object, head: bool = False) -> None:
    await _respond(send, 200, json.dumps(data, separators=(",", ":")).encode(),
                   "application/json", head=head)


async def _lifespan(receive: Receive, send: Send) -> None:
    while True:
        message = await receive()
        if message["type"] == "lifespan.startup":
            await send({"type": "lifespan.startup.complete"})
        elif message["type"] == "lifespan.shutdown":
            await send({"type": "lifespan.shutdown.complete"})
            return


def config(host: str, port: int) -> Config:
    """hypercorn's settings for the view: quiet but for errors (the caller says where it is),
    and its timeouts in real seconds whatever speed trio's clock runs at."""
    settings = Config()
    settings.bind = [host_port(host, port)]
    settings.accesslog = None
    settings.loglevel = "WARNING"
    settings.include_server_header = False
    speed = clock_speed()
    for name in ("keep_alive_timeout", "graceful_timeout", "shutdown_timeout",
                 "startup_timeout", "ssl_handshake_timeout"):
        setattr(settings, name, getattr(settings, name) * speed)
    return settings


async def serve_web(host: str, port: int, source: FarmSource,
                    task_status: trio.TaskStatus[str] = trio.TASK_STATUS_IGNORED) -> None:
    """Serve the live view of `source` on HOST:PORT (PORT 0: a free one) until cancelled;
    started with its address, `http://HOST:PORT/`, once it listens."""
    started = False
    try:
        async with trio.open_nursery() as nursery:
            app = LiveView(source, nursery)
            binds = await nursery.start(partial(serve, cast(Framework, app), config(host, port)))
            url = binds[0] if binds else f"http://{host_port(host, port)}"
            task_status.started(url.rstrip("/") + "/")
            started = True
    except* OSError as failed:
        if started:
            raise
        error = failed.exceptions[0]
        while isinstance(error, BaseExceptionGroup):
            error = error.exceptions[0]
        assert isinstance(error, OSError)
        raise OSError(error.errno, f"cannot serve the live view on {host_port(host, port)}: "
                      f"{error.strerror or error}") from None

