"""The live view in a real browser: Debian's Chromium, headless, driven by playwright-core
(tests/hosts/web_page_driver.js), looking at a farm of 200 printers in this test's trio run while
our host streams a job to one of them over TCP.

The farm page must show 200 rows and the streaming printer's progress change without a reload;
its printer page its wire tail and plots; nothing may be fetched from elsewhere and nothing
logged as an error. Chromium comes from Debian's packages (tests/hosts/apt.py) and
playwright-core from npm into the cache outside the checkout (tests/hosts/npm.py), both
installed by `python -m tests.hosts.install`; no browser is downloaded. Where either is
missing, the test skips and names that command.
"""

import json
from pathlib import Path

import pytest
import trio

from fake_marlin.emulator.journal.writer import Journal
from fake_marlin.emulator.link.tcp import TcpLink
from fake_marlin.emulator.printer.model import Printer
from fake_marlin.emulator.server.lifecycle import PrinterServer, ServerConfig
from fake_marlin.emulator.web.app import serve_web
from fake_marlin.emulator.web.source import LocalFarm
from fake_marlin.host import open_printer
from tests.hosts import apt, npm

pytestmark = pytest.mark.e2e

DRIVER = Path(__file__).parent / "hosts" / "web_page_driver.js"
DRIVER_TIMEOUT = 180
PRINTERS = 200
STREAMING = 1  # the printer our host streams to


async def open_view(browser, url: str, screenshot: Path) -> dict:
    install, chromium = browser
    command = [install.node, str(DRIVER), url, str(screenshot), str(STREAMING), chromium]
    with trio.move_on_after(DRIVER_TIMEOUT) as waited:
        done = await trio.run_process(
            command, capture_stdout=True, capture_stderr=True, check=False, cwd=install.path,
            env={"NODE_PATH": str(install.path / "node_modules"), "PATH": "/usr/bin:/bin",
                 "HOME": str(Path.home())})
    if waited.cancelled_caught:
        pytest.fail(f"the browser did not finish with the page in {DRIVER_TIMEOUT} s")
    if done.returncode != 0:
        pytest.fail(f"web_page_driver.js exited {done.returncode}:\n{done.stderr.decode()[-3000:]}")
    return json.loads(done.stdout.decode().strip().splitlines()[-1])


def job(count: int) -> list[str]:
    return [f"G1 X{10 + n % 60} Y{10 + (n * 7) % 50} E{n / 20:.2f} F6000" for n in range(count)]


async def test_the_live_view_of_200_printers_with_a_job_streaming(browser, tmp_path):
    links = [TcpLink("127.0.0.1", 0) for _ in range(PRINTERS)]
    servers = [PrinterServer(link, Printer(), Journal(None), ServerConfig(protocol="marlin"))
               for link in links]
    try:
        async with trio.open_nursery() as nursery:
            for server in servers:
                await nursery.start(server.run)
            farm = LocalFarm(servers, list(range(1, PRINTERS + 1)), [link.path for link in links])
            url = await nursery.start(serve_web, "127.0.0.1", 0, farm)

            async def stream(task_status=trio.TASK_STATUS_IGNORED) -> None:
                async with open_printer(links[STREAMING - 1].path, protocol="marlin") as host:
                    await host.print_commands(["M104 S210", "M140 S60", "G28", "G92 E0"])
                    task_status.started()
                    while True:  # a job of 200 moves at a time, for as long as the page looks
                        await host.print_commands(job(200))

            await nursery.start(stream)
            seen = await open_view(browser, url, tmp_path / "farm.png")
            nursery.cancel_scope.cancel()
    finally:
        for link in links:
            link.close()
    print(f"\nlive view screenshots: {tmp_path / 'farm.png'} (the farm), "
          f"{tmp_path / 'farm-printer.png'} (printer {STREAMING}), {tmp_path / 'farm-full.png'}")

    assert seen["console_errors"] == [] and seen["requests"] == []
    assert seen["title"] == f"fake-marlin farm · {PRINTERS} printers"
    assert seen["rows"] == PRINTERS and seen["printers_card"] == str(PRINTERS)
    assert seen["page_count"].startswith(f"printers 1–{PRINTERS} of {PRINTERS}")
    # The job's progress changed on the page that was loaded once.
    before, after = (int(seen[key].replace(",", ""))
                     for key in ("commands_before", "commands_after"))
    assert after > before >= 4 and seen["same_page"] and seen["updates"] >= 2
    assert seen["host"] == "yes" and seen["state"] in ("printing", "heating")
    assert seen["last_command"].startswith("G1 ") and seen["idle_row"] == "idle"
    # Its page: the wire tail both ways, and the report's four plots, drawn.
    assert seen["printer_title"].startswith(f"printer {STREAMING} ")
    assert seen["tail_in"] > 10 and seen["tail_out"] > 10
    assert any(text.startswith("N") and " G1 " in text for text in seen["tail_texts"])
    assert seen["svgs"] == 1 and seen["svg_paths"] >= 6 and seen["svg_box"]["width"] > 600
    assert [title.split(":")[0] for title in seen["plot_titles"]] == [
        "Commands executed per second", "Planner", "Heaters", "Marks"]
    assert seen["missing_status"] == 404 and "no printer 100000" in seen["missing_text"]
