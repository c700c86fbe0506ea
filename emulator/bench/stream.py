"""Our host streaming one job to one printer or many at once, as a process of its own:

    python -m fake_marlin.emulator.bench.stream --protocol marlin --job JOB.gcode PORT [PORT...]

It prints one JSON object on its last line: per port the host's PrintSummary (or its error),
and the wall time from the common start to the last printer done.

A process of its own so that the host's CPU time never mixes with the bench's or a printer's.
Each client first opens its port and sends one M105: the greeting, our Marlin host's reading of
the line counter and the port's settling are then behind it, and the timed part is the job
alone. With many ports the clients start their jobs together, once all are connected.
"""

import argparse
import json
import sys
import time

import trio

from fake_marlin.host import ClientOptions, HostError, open_printer


async def _client(port: str, protocol: str, job: list[str], options: ClientOptions,
                  connected: "_Countdown", go: trio.Event, result: dict) -> None:
    try:
        async with open_printer(port, protocol=protocol, options=options) as client:
            await client.send("M105")
            connected.done()
            await go.wait()
            summary = await client.print_commands(job)
            result.update(summary.as_dict())
    except HostError as error:
        result["error"] = f"{type(error).__name__}: {error}"
    finally:
        connected.done()  # a client that failed to connect must not hold up the others
        result["finished_at"] = trio.current_time()


class _Countdown:
    def __init__(self, count: int, event: trio.Event) -> None:
        self._left = count
        self._counted: set[int] = set()
        self._event = event

    def done(self) -> None:
        task = id(trio.lowlevel.current_task())
        if task in self._counted:
            return
        self._counted.add(task)
        self._left -= 1
        if self._left <= 0:
            self._event.set()


async def _run(args: argparse.Namespace, job: list[str]) -> dict:
    options = ClientOptions(window=args.window) if args.window else ClientOptions()
    results: list[dict] = [{"port": port, "commands": 0, "error": None} for port in args.ports]
    go = trio.Event()
    connected = _Countdown(len(args.ports), go)
    started = None
    with trio.move_on_after(args.timeout) as timer:
        async with trio.open_nursery() as nursery:
            for port, result in zip(args.ports, results):
                nursery.start_soon(_client, port, args.protocol, job, options, connected, go,
                                   result)
            await go.wait()
            started = trio.current_time()
    for result in results:
        if timer.cancelled_caught and result["error"] is None and result["commands"] == 0:
            result["error"] = f"not done within {args.timeout:.0f} s"
        result["finished_at"] = round(result.get("finished_at", 0.0) - (started or 0.0), 6)
    wall = max((r["finished_at"] for r in results), default=0.0)
    return {"job": len(job), "clients": results, "wall": wall}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m fake_marlin.emulator.bench.stream")
    parser.add_argument("ports", nargs="+", metavar="PORT")
    parser.add_argument("--protocol", default="marlin")
    parser.add_argument("--job", required=True, help="one command per line")
    parser.add_argument("--window", type=int, default=0, help="Ultimaker window (0: default)")
    parser.add_argument("--timeout", type=float, default=600.0)
    args = parser.parse_args(argv)
    with open(args.job) as file:
        job = [line.strip() for line in file if line.strip()]
    cpu = time.process_time()
    report = trio.run(_run, args, job)
    report["cpu_seconds"] = time.process_time() - cpu
    print(json.dumps(report), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
