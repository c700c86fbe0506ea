"""Print a G-code file with Printrun's printcore, the library behind Pronterface and pronsole.

Run with the printrun venv's python: `python printcore_driver.py PORT GCODE_FILE --timeout S`.
Prints one JSON object (every line printcore wrote, errors it reported, the lines each way in
order as `wire`, elapsed time) as the last line of stdout, and exits 0 only if the whole file was
acknowledged without an error. printcore has no acknowledgement timeout, so a line the printer
never answers would hang it forever: the overall timeout ends the run and names the line it was
stuck on.
"""

# printrun lives only in the host venv this driver runs under (tests/hosts/venvs.py), not in .venv.
# pyright: reportMissingImports=false

import argparse
import json
import logging
import os
import sys
import threading
import time


class Errors(logging.Handler):
    """printcore reports some failures only through `logging` (its own threads' exceptions)."""

    def __init__(self, errors: list[str]) -> None:
        super().__init__(logging.WARNING)
        self.errors = errors

    def emit(self, record: logging.LogRecord) -> None:
        self.errors.append(record.getMessage())


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("port")
    parser.add_argument("gcode")
    parser.add_argument("--timeout", type=float, default=120)
    args = parser.parse_args()
    deadline = time.monotonic() + args.timeout
    summary = {"sent": [], "errors": [], "received_tail": [], "printer_errors": [], "resends": 0,
               "unknown_commands": [], "elapsed": None, "stuck_on": None, "wire": []}
    logging.getLogger().addHandler(Errors(summary["errors"]))
    try:
        done = drive(args, deadline, summary)
    except Exception as error:  # a bug here must still produce a report
        summary["errors"].append(f"driver: {error!r}")
        done = False
    summary["lines_sent"] = len(summary["sent"])
    summary["rubbish"] = [e for e in summary["errors"] if "rubbish" in e]
    print(json.dumps(summary))
    sys.stdout.flush()
    # printcore's threads are not daemons; a stuck one must not keep us alive.
    os._exit(0 if done and not summary["errors"] else 1)


def drive(args, deadline: float, summary: dict) -> bool:
    from printrun import gcoder
    from printrun.printcore import printcore

    with open(args.gcode) as file:
        gcode = gcoder.LightGCode(file.read().splitlines())
    last = {"sent": 0.0, "ok": 0.0}
    received = summary["received_tail"]

    def on_send(command, gline):
        summary["sent"].append(command)
        summary["wire"].append("> " + command)
        last["sent"] = time.monotonic()

    def on_receive(line):
        received.append(line.rstrip())
        summary["wire"].append("< " + line.rstrip())
        del received[:-20]
        if line.startswith("Error:"):
            summary["printer_errors"].append(line.rstrip())
        elif line.startswith('echo:Unknown command: "'):
            summary["unknown_commands"].append(line.rstrip()[len('echo:Unknown command: "'):-1])
        elif line.lower().startswith("resend"):
            summary["resends"] += 1
        if line.startswith("ok"):
            last["ok"] = time.monotonic()

    core = printcore()
    core.sendcb = on_send
    core.recvcb = on_receive
    # printcore passes the printer's own `Error:` lines here too; on_receive keeps those apart.
    core.errorcb = lambda error: None if error.startswith("Error:") else summary["errors"].append(error)
    core.connect(args.port, 250000)
    try:
        if core.printer is None:
            return False
        if not wait_for(lambda: core.online, deadline):
            summary["errors"].append("printer not online before the timeout")
            return False
        # Like a person who clicks Print once the printer shows its temperature.
        wait_for(lambda: last["ok"], min(deadline, time.monotonic() + 2))
        started = time.monotonic()
        if not core.startprint(gcode):
            summary["errors"].append("startprint refused")
            return False
        # printcore's final M110 is written after `printing` drops: wait for its ok as well.
        finished = wait_for(lambda: not core.printing and core.print_thread is None
                            and core.priqueue.empty() and last["ok"] > last["sent"], deadline)
        summary["elapsed"] = round(time.monotonic() - started, 2)
        if not finished:
            summary["stuck_on"] = {"line": summary["sent"][-1] if summary["sent"] else None,
                                   "file_index": core.queueindex, "of": len(gcode)}
            summary["errors"].append(f"no progress before the timeout, stuck on {summary['stuck_on']}")
        return finished
    finally:
        closer = threading.Thread(target=core.disconnect, daemon=True)
        closer.start()
        closer.join(5)


def wait_for(condition, deadline: float) -> bool:
    while not condition():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.02)
    return True


if __name__ == "__main__":
    sys.exit(main())
