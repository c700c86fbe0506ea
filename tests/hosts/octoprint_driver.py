"""Print G-code files through OctoPrint's own serial layer, as OctoPrint would, without its server.

Run with the OctoPrint venv's python:

    python octoprint_driver.py PORT GCODE_FILE [PORT GCODE_FILE ...] --timeout S
    python octoprint_driver.py --serve --timeout S     # requests on stdin, one JSON object a line

It uses `octoprint.util.comm.MachineCom`, the code that talks to the printer in OctoPrint 1.11,
with a throwaway settings folder and the bundled plugins. OctoPrint's import and its settings
and plugins set-up cost seconds, so one process prints to several ports, one after the other:
a fresh MachineCom for each, connected, printing its file, closed before the next.

For each port it prints one JSON object on a line of its own, when that port is done: the port,
states, temperatures, the firmware name OctoPrint detected (on_comm_firmware_info) and its info
and capabilities, errors, what OctoPrint logged at warning level (`warnings`) and its notes on
the firmware and the link (`notes`: firmware detection, timeouts, resends), the terminal's own
messages (`log`), every line sent and received, whether the print completed, the seconds it
took. With PORT GCODE_FILE pairs the exit code is 0 only if every port connected, printed to
the end and saw no error. With --serve each stdin line is {"port": ..., "gcode": ..., "id": ...,
"timeout": S (optional)}, answered with its report (carrying the same "id"), after a first line
{"ready": true, "setup_seconds": S} once OctoPrint is set up; it exits at EOF. `--timeout` bounds
each port, not the whole run. `wire` is every line each way in order, `> ` sent, `< ` received.
"""

# octoprint lives only in the host venv this driver runs under (tests/hosts/venvs.py), not in .venv.
# pyright: reportMissingImports=false

import argparse
import json
import logging
import os
import shutil
import sys
import tempfile
import threading
import time

# What OctoPrint's comm layer says at INFO that explains what it did to the printer (the rest is
# chatter: state changes, the serial port's settings).
NOTES = ("Detected ", "Printer reports firmware name", "Firmware didn't send an 'ok'",
         "Ignoring resend", "Got a resend request", "Communication timeout",
         "Timeout while in an active heatup", "No response from printer",
         "Printer seems to support the busy protocol", "Externally triggered heatup detected")
KEPT_LINES = 5000  # sent and received lines per port, at most (a long job's are the tail)


class Records(logging.Handler):
    """What OctoPrint's loggers say while one port is printed: warnings, and the notes."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.warnings: list[str] = []
        self.notes: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        try:
            message = record.getMessage()
        except Exception:  # a plugin's bad format string must not end the run
            message = str(record.msg)
        if record.levelno >= logging.WARNING:
            self.warnings.append(f"{record.levelname}: {message}")
        elif message.startswith(NOTES):
            self.notes.append(message.splitlines()[0])  # (a resend's note quotes the terminal)


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("targets", nargs="*", metavar="PORT GCODE_FILE",
                        help="ports and the files to print to them, in pairs")
    parser.add_argument("--serve", action="store_true",
                        help="read {\"port\", \"gcode\", \"id\"} requests from stdin instead")
    parser.add_argument("--timeout", type=float, default=120, help="seconds per port")
    args = parser.parse_args()
    if args.serve == bool(args.targets) or len(args.targets) % 2:
        parser.error("give PORT GCODE_FILE pairs, or --serve")
    # OctoPrint hands its threads' exceptions to logging: keep them, and off our stdout.
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    records = Records()
    octoprint_logger = logging.getLogger("octoprint")
    octoprint_logger.setLevel(logging.INFO)  # for the notes; stderr's handler still shows warnings
    octoprint_logger.addHandler(records)
    for handler in logging.getLogger().handlers:
        handler.setLevel(logging.WARNING)
    setting_up = time.monotonic()
    try:
        basedir = set_up()
    except Exception as error:  # no OctoPrint at all: every port gets the same report
        basedir = None
        broken = f"driver: OctoPrint set-up failed: {error!r}"
    else:
        broken = None
    all_done = True
    try:
        if args.serve:
            emit({"ready": not broken, "setup_seconds": round(time.monotonic() - setting_up, 2)})
            for line in sys.stdin:
                if not line.strip():
                    continue
                request = json.loads(line)
                report = one_port(request["port"], request["gcode"],
                                  float(request.get("timeout", args.timeout)), records, broken)
                report["id"] = request.get("id")
                emit(report)
        else:
            for port, gcode in zip(args.targets[::2], args.targets[1::2]):
                report = one_port(port, gcode, args.timeout, records, broken)
                all_done &= report["done"] and not report["errors"]
                emit(report)
    finally:
        if basedir is not None:
            shutil.rmtree(basedir, ignore_errors=True)
    # MachineCom's timers and threads are not all daemons: leave regardless of them.
    os._exit(0 if all_done else 1)


def emit(report: dict) -> None:
    print(json.dumps(report))
    sys.stdout.flush()


def set_up() -> str:
    """OctoPrint's settings (in a throwaway folder) and plugins, once for every port."""
    from octoprint.plugin import plugin_manager
    from octoprint.printer.profile import PrinterProfileManager
    from octoprint.settings import settings

    basedir = tempfile.mkdtemp(prefix="octoprint-driver-")
    settings(init=True, basedir=basedir)
    # The port is given, so no autodetection; the glob only lets OctoPrint list the ptys too.
    settings().set(["serial", "additionalPorts"], ["/dev/pts/[0-9]*"])
    plugin_manager(init=True)
    # The first profile manager makes the default printer profile (logging an error that there
    # was none): here, not in the first port's report.
    PrinterProfileManager()
    return basedir


def one_port(port: str, gcode: str, timeout: float, records: Records, broken: str | None) -> dict:
    """Connect to `port`, print `gcode`, close; the report."""
    started = time.monotonic()
    summary = {"port": port, "states": [], "temperatures": [], "firmware_name": None,
               "firmware_info": {}, "capabilities": {}, "errors": [], "warnings": [], "notes": [],
               "log": [], "done": False, "timed_out": False, "final_state": None,
               "elapsed": None, "print_elapsed": None, "sent": [], "received": [], "wire": []}
    records.warnings, records.notes = summary["warnings"], summary["notes"]
    if broken:
        summary["errors"].append(broken)
    else:
        try:
            summary["done"] = drive(port, gcode, started + timeout, summary)
        except Exception as error:  # a bug here must still produce a report
            summary["errors"].append(f"driver: {error!r}")
            summary["done"] = False
    summary["elapsed"] = round(time.monotonic() - started, 2)
    # The report is a snapshot: the old MachineCom's threads may still log after it.
    for key in ("warnings", "notes", "log", "sent", "received", "wire", "states"):
        summary[key] = list(summary[key])[-KEPT_LINES:]
    summary["temperatures"] = summary["temperatures"][-20:]
    records.warnings, records.notes = [], []
    return summary


def drive(port: str, gcode: str, deadline: float, summary: dict) -> bool:
    from octoprint.printer.profile import PrinterProfileManager
    from octoprint.util import comm

    finished = threading.Event()
    named: list[float] = []  # when OctoPrint read the firmware's name

    class Callback(comm.MachineComPrintCallback):
        def on_comm_log(self, message):
            for prefix, key, arrow in (("Send: ", "sent", "> "), ("Recv: ", "received", "< ")):
                if message.startswith(prefix):
                    summary[key].append(message[len(prefix):])
                    summary["wire"].append(arrow + message[len(prefix):])
                    return
            summary["log"].append(message)

        def on_comm_state_change(self, state):
            summary["states"].append(machine.getStateString(state))
            if state in (comm.MachineCom.STATE_ERROR, comm.MachineCom.STATE_CLOSED_WITH_ERROR):
                finished.set()

        def on_comm_temperature_update(self, temp, bedTemp, chamberTemp, customTemp):
            summary["temperatures"].append({"tools": {str(k): v for k, v in temp.items()}, "bed": bedTemp})

        def on_comm_error(self, error, reason, consequence=None, faq=None, logs=None):
            summary["errors"].append(f"{reason}: {error}")
            finished.set()

        def on_comm_firmware_info(self, firmware_name, firmware_data):
            named.append(time.monotonic())
            summary["firmware_name"] = firmware_name
            summary["firmware_info"] = dict(firmware_data)

        def on_comm_print_job_done(self, suppress_script=False):
            summary["done"] = True
            finished.set()

        def on_comm_print_job_failed(self, reason=None):
            summary["errors"].append(f"print job failed: {reason}")
            finished.set()

        def on_comm_print_job_cancelled(self, suppress_script=False, user=None):
            summary["errors"].append("print job cancelled")
            finished.set()

    machine = comm.MachineCom(port, baudrate=250000, callbackObject=Callback(),
                              printerProfileManager=PrinterProfileManager())
    machine.start()
    try:
        if not wait_for(lambda: machine.isOperational() or machine.isError(), deadline):
            summary["timed_out"] = True
            summary["errors"].append(f"not operational before the timeout: {machine.getStateString()}")
            return False
        # M115's answer is what tells OctoPrint the printer's name and capabilities: wait for its
        # end (a firmware without `Cap:` lines has none: the name alone, a second ago, is its end).
        wait_for(lambda: machine._firmware_capabilities_received or machine.isError() or (
            named and not machine._firmware_capabilities and time.monotonic() > named[0] + 1),
            min(deadline, time.monotonic() + 5))
        if machine.isError():
            return False
        machine.selectFile(os.path.abspath(gcode), False)
        printing = time.monotonic()
        machine.startPrint()
        if not finished.wait(max(0.0, deadline - time.monotonic())):
            summary["timed_out"] = True
            summary["errors"].append(f"print not finished before the timeout: {machine.getStateString()}, "
                                     f"last sent {summary['sent'][-1:]}")
            return False
        summary["print_elapsed"] = round(time.monotonic() - printing, 2)
        # Done is announced before the state is back to operational: that waits for the last
        # command's ok, and when the firmware dropped it, for OctoPrint's communication timeout.
        wait_for(lambda: machine.getState() == comm.MachineCom.STATE_OPERATIONAL, deadline)
        return summary["done"] and machine.getState() == comm.MachineCom.STATE_OPERATIONAL
    finally:
        if machine.isError() or machine.getErrorString():
            summary["errors"].append(f"error string: {machine.getErrorString()}")
        summary["final_state"] = machine.getStateString()
        summary["capabilities"] = dict(machine._firmware_capabilities)  # no public accessor in 1.11
        summary["firmware_info"] = summary["firmware_info"] or dict(machine._firmware_info)
        closer = threading.Thread(target=machine.close, kwargs={"wait": False}, daemon=True)
        closer.start()
        closer.join(5)


def wait_for(condition, deadline: float) -> bool:
    while not condition():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.05)
    return True


if __name__ == "__main__":
    sys.exit(main())
