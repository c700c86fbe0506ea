"""Printrun's printcore (Pronterface's and pronsole's library) streaming one G-code file, timed;
run with printrun's python:

    ~/.cache/fake-marlin/venvs/printrun-2.2.0/bin/python printcore_host.py PORT JOB.gcode

Prints one JSON object: whether the print finished, how many distinct job lines were sent, the
seconds from startprint to the last ok. printcore sends a line only once the previous one is
acknowledged and has no acknowledgement timeout, so the overall timeout ends a stuck run.
Standalone on purpose: printrun's venv has no fake_marlin.
"""

import argparse
import json
import os
import re
import sys
import threading
import time

_NUMBERED = re.compile(r"N-?\d+\s*(.*?)\*\d+\s*")


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("port")
    parser.add_argument("gcode")
    parser.add_argument("--timeout", type=float, default=300)
    args = parser.parse_args()
    report: dict = {"done": False, "acknowledged": 0, "elapsed": None, "errors": []}
    try:
        drive(args, time.monotonic() + args.timeout, report)
    except Exception as error:  # a bug here must still produce a report
        report["errors"].append(f"driver: {error!r}")
    print(json.dumps(report), flush=True)
    os._exit(0)  # printcore's threads are not daemons; a stuck one must not keep us alive


def drive(args: argparse.Namespace, deadline: float, report: dict) -> None:
    from printrun import gcoder  # type: ignore[import-not-found]
    from printrun.printcore import printcore  # type: ignore[import-not-found]

    with open(args.gcode) as file:
        lines = [line.strip() for line in file if line.strip()]
    job = set(lines)
    sent: set[str] = set()
    last = {"sent": 0.0, "ok": 0.0}

    def on_send(command: str, gline: object) -> None:
        match = _NUMBERED.fullmatch(command)
        line = match[1] if match else command.strip()
        if line in job:
            sent.add(line)
        last["sent"] = time.monotonic()

    def on_receive(line: str) -> None:
        if line.startswith("ok"):
            last["ok"] = time.monotonic()

    core = printcore()
    core.sendcb = on_send
    core.recvcb = on_receive
    core.errorcb = lambda error: (None if error.startswith("Error:")
                                  else report["errors"].append(error))
    core.connect(args.port, 250000)
    try:
        if core.printer is None or not wait_for(lambda: core.online, deadline):
            report["errors"].append("printer not online in time")
            return
        wait_for(lambda: last["ok"], min(deadline, time.monotonic() + 2))
        started = time.monotonic()
        if not core.startprint(gcoder.LightGCode(lines)):
            report["errors"].append("startprint refused")
            return
        # printcore's final M110 is written after `printing` drops: wait for its ok as well.
        done = wait_for(lambda: not core.printing and core.print_thread is None
                        and core.priqueue.empty() and last["ok"] > last["sent"], deadline)
        report["done"] = done
        report["elapsed"] = last["ok"] - started if done else None
        report["acknowledged"] = len(sent) if done else max(0, len(sent) - 1)
        report["job"] = len(job)
        if not done:
            report["errors"].append(f"not finished in time, at line {core.queueindex}")
    finally:
        closer = threading.Thread(target=core.disconnect, daemon=True)
        closer.start()
        closer.join(5)


def wait_for(condition, deadline: float) -> bool:
    # Coarse polling, in printcore's own process: its GIL is the host's. The times reported
    # come from the callbacks, so they do not depend on this step.
    while not condition():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.02)
    return True


if __name__ == "__main__":
    sys.exit(main())
