"""Print a G-code file through OctoPrint's own serial layer, as OctoPrint would, without its server.

Run with the OctoPrint venv's python: `python octoprint_driver.py PORT GCODE_FILE --timeout S`.
It uses `octoprint.util.comm.MachineCom`, the code that talks to the printer in OctoPrint 1.11,
with a throwaway settings folder and the bundled plugins, and prints one JSON object: states,
temperatures, firmware info and capabilities, errors, every line sent and received, whether the
print completed. Exit 0 only if it connected, printed to the end and saw no error.
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


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("port")
    parser.add_argument("gcode")
    parser.add_argument("--timeout", type=float, default=120)
    args = parser.parse_args()
    deadline = time.monotonic() + args.timeout
    # OctoPrint hands its threads exceptions to logging: keep them, and off our stdout.
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    summary = {"states": [], "temperatures": [], "firmware_name": None, "firmware_info": {},
               "capabilities": {}, "errors": [], "done": False, "sent": [], "received": []}
    try:
        done = drive(args, deadline, summary)
    except Exception as error:  # a bug here must still produce a report
        summary["errors"].append(f"driver: {error!r}")
        done = False
    print(json.dumps(summary))
    sys.stdout.flush()
    # MachineCom's timers and threads are not all daemons: leave regardless of them.
    os._exit(0 if done and not summary["errors"] else 1)


def drive(args, deadline: float, summary: dict) -> bool:
    from octoprint.plugin import plugin_manager
    from octoprint.printer.profile import PrinterProfileManager
    from octoprint.settings import settings
    from octoprint.util import comm

    basedir = tempfile.mkdtemp(prefix="octoprint-driver-")
    settings(init=True, basedir=basedir)
    # The port is given, so no autodetection; the glob only lets OctoPrint list the pty too.
    settings().set(["serial", "additionalPorts"], [os.path.realpath(args.port), "/dev/pts/[0-9]*"])
    plugin_manager(init=True)
    finished = threading.Event()

    class Callback(comm.MachineComPrintCallback):
        def on_comm_log(self, message):
            for prefix, key in (("Send: ", "sent"), ("Recv: ", "received")):
                if message.startswith(prefix):
                    summary[key].append(message[len(prefix):])

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

    machine = comm.MachineCom(args.port, baudrate=250000, callbackObject=Callback(),
                              printerProfileManager=PrinterProfileManager())
    machine.start()
    try:
        if not wait_for(lambda: machine.isOperational() or machine.isError(), deadline):
            summary["errors"].append(f"not operational before the timeout: {machine.getStateString()}")
            return False
        # M115's answer is what tells OctoPrint the printer's capabilities: wait for its end.
        wait_for(lambda: machine._firmware_capabilities_received or machine.isError(),
                 min(deadline, time.monotonic() + 10))
        if machine.isError():
            return False
        machine.selectFile(os.path.abspath(args.gcode), False)
        machine.startPrint()
        if not finished.wait(max(0.0, deadline - time.monotonic())):
            summary["errors"].append(f"print not finished before the timeout: {machine.getStateString()}, "
                                     f"last sent {summary['sent'][-1:]}")
            return False
        # Done is announced before the state is back to operational.
        wait_for(lambda: machine.getState() == comm.MachineCom.STATE_OPERATIONAL,
                 min(deadline, time.monotonic() + 5))
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
        shutil.rmtree(basedir, ignore_errors=True)


def wait_for(condition, deadline: float) -> bool:
    while not condition():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.05)
    return True


if __name__ == "__main__":
    sys.exit(main())
