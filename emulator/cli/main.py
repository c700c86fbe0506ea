"""`fake-marlin`: run a virtual printer on a pseudo-terminal (printers.py), or one of its commands."""

import sys

from fake_marlin.emulator.cli.printers import main as printers_main


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["verify"]:
        from fake_marlin.emulator.cli.verify import main as verify_main
        return verify_main(argv[1:])
    if argv[:1] == ["scenario"]:
        from fake_marlin.emulator.cli.scenario import main as scenario_main
        return scenario_main(argv[1:])
    if argv[:1] == ["bench"]:
        from fake_marlin.emulator.bench.cli import main as bench_main
        return bench_main(argv[1:])
    if argv[:1] == ["report"]:
        from fake_marlin.emulator.cli.report import main as report_main
        return report_main(argv[1:])
    return printers_main(argv)


if __name__ == "__main__":
    sys.exit(main())
