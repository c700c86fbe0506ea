"""The command line `fake-marlin` (main.py): printers without a command (printers.py), and the
commands verify, scenario, report (their modules here) and bench (emulator/bench/cli.py)."""
