"""`fake-marlin bench`: how fast the emulator and the hosts are, each against a reference.

This machine's speed drifts several-fold within a day, so no figure stands alone: each is
measured side by side with a reference in the same run (a bare ok-responder, the wire's limit,
another protocol, one printer alone) and reported as a ratio to it.

- `cli`: the command line, `fake-marlin bench` (`configure(commands)`, `run(args)`).
- `measure`: the sections (hosts, cpu, baud, latency, simhour, farm).
- `procs`: the subprocesses, their CPU and memory from /proc, and stopping them all.
- `report`: the Markdown tables and the JSON object.
- `jobs`: the G-code jobs.
- `responder`: the bare ok-responder, a pty program of its own (`python -m`).
- `stream`: our host streaming a job to one port or many, in a process of its own (`python -m`).
- `octoprint_host`, `printcore_host`: the same for OctoPrint and printcore, run with the
  interpreters of their own venvs (they import nothing from fake_marlin).

Kept light on purpose: the responder imports this package, and its start-up is no benchmark.
"""
