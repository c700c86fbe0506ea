"""OctoPrint's own serial layer streaming one G-code file, timed; run with OctoPrint's python:

    ~/.cache/fake-marlin/venvs/octoprint-1.11/bin/python octoprint_host.py PORT JOB.gcode

It uses `octoprint.util.comm.MachineCom`, the code that talks to the printer in OctoPrint 1.11,
with a throwaway settings folder and without the server, and prints one JSON object: whether
the print finished, how many distinct job lines were sent, the seconds from startPrint to done.
OctoPrint sends a line only once the previous one is acknowledged, so a finished print has had
every line acknowledged. Standalone on purpose: it runs in OctoPrint's venv, which has no
fake_marlin (the bench must not import the test suite, whose driver this follows).
"""

import argparse
import json
import logging
import os
import re
import shutil
import sys
import tempfile
import threading
import time

_NUMBERED = re.compile(r"N-?\d+\s*(.*?)\*\d+\s*")


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("port")
    parser.add_argument("gcode")
    parser.add_argument("--timeout", type=float, default=300)
    args = parser.parse_args()
    # OctoPrint hands its threads' exceptions to logging: keep them off our stdout.
    logging.basicConfig(level=logging.ERROR, stream=sys.stderr)
    report: dict = {"done": False, "acknowledged": 0, "elapsed": None, "errors": []}
    try:
        drive(args, time.monotonic() + args.timeout, report)
    except Exception as error:  # a bug here must still produce a report
        report["errors"].append(f"driver: {error!r}")
    print(json.dumps(report), flush=True)
    # MachineCom's timers and threads are not all daemons: leave regardless of them.
    os._exit(0)


def drive(args: argparse.Namespace, deadline: float, report: dict) -> None:
    from octoprint.plugin import plugin_manager  # type: ignore[import-not-found]
    from octoprint.printer.profile import PrinterProfileManager  # type: ignore[import-not-found]
    from octoprint.settings import settings  # type: ignore[import-not-found]
    from octoprint.util import comm  # type: ignore[import-not-found]

    with open(args.gcode) as file:
        job = {line.strip() for line in file if line.strip()}
    sent: set[str] = set()
    basedir = tempfile.mkdtemp(prefix="octoprint-bench-")
    settings(init=True, basedir=basedir)
    settings().set(["serial", "additionalPorts"], [os.path.realpath(args.port)])
    plugin_manager(init=True)
    finished = threading.Event()
    times: dict[str, float] = {}

    class Callback(comm.MachineComPrintCallback):  # type: ignore[misc]
        def on_comm_log(self, message: str) -> None:
            if message.startswith("Send: "):
                match = _NUMBERED.fullmatch(message[6:])
                line = match[1] if match else message[6:].strip()
                if line in job:
                    sent.add(line)

        def on_comm_state_change(self, state: int) -> None:
            if state in (comm.MachineCom.STATE_ERROR, comm.MachineCom.STATE_CLOSED_WITH_ERROR):
                report["errors"].append(f"state: {machine.getStateString(state)}")
                finished.set()

        def on_comm_error(self, error, reason, consequence=None, faq=None, logs=None) -> None:
            report["errors"].append(f"{reason}: {error}")
            finished.set()

        def on_comm_print_job_done(self, suppress_script: bool = False) -> None:
            times["done"] = time.monotonic()
            report["done"] = True
            finished.set()

        def on_comm_print_job_failed(self, reason=None) -> None:
            report["errors"].append(f"print job failed: {reason}")
            finished.set()

    machine = comm.MachineCom(args.port, baudrate=250000, callbackObject=Callback(),
                              printerProfileManager=PrinterProfileManager())
    machine.start()
    try:
        if not wait_for(lambda: machine.isOperational() or machine.isError(), deadline):
            report["errors"].append(f"not operational in time: {machine.getStateString()}")
            return
        # M115's answer is what tells OctoPrint the printer's capabilities: wait for its end.
        wait_for(lambda: machine._firmware_capabilities_received or machine.isError(),
                 min(deadline, time.monotonic() + 10))
        if machine.isError():
            return
        machine.selectFile(os.path.abspath(args.gcode), False)
        started = time.monotonic()
        machine.startPrint()
        if not finished.wait(max(0.0, deadline - time.monotonic())):
            report["errors"].append(f"not finished in time: {machine.getStateString()}")
        if report["done"]:
            report["elapsed"] = times["done"] - started
        report["acknowledged"] = len(sent) if report["done"] else max(0, len(sent) - 1)
        report["job"] = len(job)
    finally:
        closer = threading.Thread(target=machine.close, kwargs={"wait": False}, daemon=True)
        closer.start()
        closer.join(5)
        shutil.rmtree(basedir, ignore_errors=True)


def wait_for(condition, deadline: float) -> bool:
    while not condition():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.02)
    return True


if __name__ == "__main__":
    sys.exit(main())
