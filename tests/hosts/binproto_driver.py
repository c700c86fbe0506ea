"""Upload a file to the printer's SD card with Marlin's own binary transfer client, binproto2
(PyPI marlin-binary-protocol, what OctoPrint-FirmwareUpdater's `marlinbft` method uses).

Run with the binproto venv's python:
`python binproto_driver.py PORT SOURCE DEST [--compress] [--response-ms MS] [--timeout S]`.
It does what binproto2's own transfer.py does (M28 B1, SYNC, QUERY, OPEN, WRITEs, CLOSE, back to
ASCII, M21), then asks M20 and M115 on the same connection (reopening the port would reset the
printer). Prints one JSON object as the last line of stdout (what binproto2 logged, the lines
the printer answered in ASCII, binproto2's error counts (resends and timeouts) in the handshake and
in the transfer, the transfer's time) and exits 0 only if the transfer completed.
"""

# binproto2 lives only in the host venv this driver runs under (tests/hosts/venvs.py), not in .venv.
# pyright: reportMissingImports=false

import argparse
import json
import os
import sys
import threading
import time

ASCII_TRIES = 5  # a command the line damaged is asked again


class Logger:
    """binproto2's logger interface, kept as transfer.py's ConsoleLogger prints it."""

    def __init__(self, lines: list[str]) -> None:
        self.lines = lines

    def _log(self, level: str, message: object) -> None:
        self.lines.append(f"{level}: {message}")

    def debug(self, message, *args, **kwargs):
        pass

    def info(self, message, *args, **kwargs):
        self._log("INFO", message)

    def warning(self, message, *args, **kwargs):
        self._log("WARNING", message)

    def error(self, message, *args, **kwargs):
        self._log("ERROR", message)

    def critical(self, message, *args, **kwargs):
        self._log("CRITICAL", message)

    def exception(self, message, *args, **kwargs):
        self._log("EXCEPTION", message)


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("port")
    parser.add_argument("source")
    parser.add_argument("destination")
    parser.add_argument("--compress", action="store_true")
    parser.add_argument("--response-ms", type=int, default=1000)  # transfer.py's -x default
    parser.add_argument("--timeout", type=float, default=120)
    args = parser.parse_args()
    summary = {"logged": [], "ascii": [], "errors": [], "handshake_errors": None,
               "protocol_errors": None, "elapsed": None, "listing": [], "capabilities": []}

    def give_up() -> None:
        summary["errors"].append(f"no end after {args.timeout} s")
        report(summary, 1)

    watchdog = threading.Timer(args.timeout, give_up)
    watchdog.daemon = True
    watchdog.start()
    try:
        done = drive(args, summary)
    except Exception as error:  # noqa: BLE001  # whatever binproto2 raises goes in the report
        summary["errors"].append(f"{type(error).__name__}: {error}")
        done = False
    report(summary, 0 if done and not summary["errors"] else 1)
    return 1


def report(summary: dict, code: int) -> None:
    print(json.dumps(summary))
    sys.stdout.flush()
    os._exit(code)  # binproto2's reader thread is no daemon


def drive(args, summary: dict) -> bool:
    import binproto2 as mbp

    logger = Logger(summary["logged"])
    protocol = mbp.Protocol(args.port, 250000, 512, args.response_ms, logger)
    try:
        mbp.EchoProtocol(protocol, logger)
        protocol.connect()
        summary["handshake_errors"] = protocol.errors  # M28B1 unanswered while the board boots
        transfer = mbp.FileTransferProtocol(protocol, None, logger)
        # Every line no one else takes (registered last, as dispatch goes in order).
        protocol.register([""], lambda token_and_line: summary["ascii"].append(token_and_line[1]))
        started = time.monotonic()
        transfer.copy(args.source, args.destination, args.compress, False)
        summary["elapsed"] = round(time.monotonic() - started, 3)
        protocol.disconnect()
        summary["protocol_errors"] = protocol.errors - summary["handshake_errors"]
        summary["listing"] = ask(protocol, summary["ascii"], ("M21", "M20"),
                                 lambda lines: "End file list" in lines)
        summary["capabilities"] = [line for line in ask(
            protocol, summary["ascii"], ("M115",), lambda lines: any(
                line.startswith("Cap:BINARY_FILE_TRANSFER") for line in lines))
            if line.startswith("Cap:")]
        return True
    finally:
        closer = threading.Thread(target=protocol.shutdown, daemon=True)
        closer.start()
        closer.join(3)


def ask(protocol, heard: list[str], commands: tuple[str, ...], answered) -> list[str]:
    """Send `commands` in ASCII until the lines heard after them satisfy `answered`."""
    for _ in range(ASCII_TRIES):
        start = len(heard)
        for command in commands:
            protocol.send_ascii(command)
        lines = heard[start:]
        if answered(lines):
            return lines
    return []


if __name__ == "__main__":
    sys.exit(main())
