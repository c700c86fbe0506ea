"""`fake-marlin`'s command line: one parser, the printers without a command, and the commands
verify, scenario (run, fuzz), bench and report, each with its own --help and its own errors."""

import re
import subprocess
import sys
from pathlib import Path

import pytest
import trio

from fake_marlin import __version__
from fake_marlin.emulator.bench import cli as bench_cli
from fake_marlin.emulator.cli import report as report_cli
from fake_marlin.emulator.cli import scenario as scenario_cli
from fake_marlin.emulator.cli import verify as verify_cli
from fake_marlin.emulator.cli.links import Address
from fake_marlin.emulator.cli.main import build_parser, main
from fake_marlin.emulator.link.direct_wait import WAITS_VARIABLE, waits_in_use

BIN = Path(sys.executable).parent
COMMANDS = {
    "verify": "check that a --journal ran its G-code job exactly once",
    "scenario": "run scenario files (run) or random fault mixes (fuzz)",
    "bench": "measure fake-marlin and the hosts against references",
    "report": "turn a --trace file into one HTML page",
}


@pytest.fixture(autouse=True)
def _columns(monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")  # argparse wraps its help to the terminal's width


def run(capsys, *argv: str) -> tuple[int, str, str]:
    """main(argv) in this process: its exit code (returned or raised), stdout and stderr."""
    try:
        code = main(list(argv))
    except SystemExit as exited:
        code = exited.code  # type: ignore[assignment]
    out, err = capsys.readouterr()
    return code, out, err


def test_help_lists_each_command_on_a_line_of_its_own_and_says_what_none_does(capsys):
    code, out, err = run(capsys, "--help")
    assert code == 0 and err == ""
    for name, line in COMMANDS.items():
        assert re.search(rf"^ +{name} +{re.escape(line)}$", out, re.MULTILINE), name
    assert "fake-marlin [OPTION ...]              run printers" in out
    assert "fake-marlin COMMAND [ARGUMENT ...]   run a command" in out
    assert "Without a command, fake-marlin starts a virtual Marlin printer" in " ".join(out.split())
    printer_options = out.split("printer options (without a command):\n")[1]
    for option in ("--protocol", "--link PATH", "--printers N", "--tcp [HOST:]PORT", "--farm"):
        assert f"  {option}" in printer_options


@pytest.mark.parametrize("command, own", [
    (["verify"], ["JOB.gcode JOURNAL", "--strict", "--allow-undetectable", "--limit N"]),
    (["scenario"], ["run", "fuzz", "run scenario files (or every *.toml in a directory)"]),
    (["scenario", "run"], ["PATH", "--trace FILE", "--report OUTDIR", "--host {builtin}"]),
    (["scenario", "fuzz"], ["--protocol", "--runs RUNS", "--out DIR", "--keep-all"]),
    (["bench"], ["--quick", "--only SECTION[,SECTION]", "sections: hosts, cpu, baud"]),
    (["report"], ["TRACE", "-o FILE, --output FILE", "--job JOB.gcode"]),
])
@pytest.mark.parametrize("flag", ["--help", "-h"])
def test_each_command_has_its_own_help(capsys, command, own, flag):
    code, out, err = run(capsys, *command, flag)
    assert code == 0 and err == ""
    assert out.startswith(f"usage: fake-marlin {' '.join(command)} ")
    for text in own:
        assert text in out
    assert "--printers" not in out and "run printers" not in out  # none of the printer's


def test_the_version_says_which_waits_are_in_use(capsys, monkeypatch):
    monkeypatch.setenv(WAITS_VARIABLE, "trio")
    waits_in_use.cache_clear()
    try:
        assert run(capsys, "--version") == (
            0, f"fake-marlin {__version__}\ntrio {trio.__version__}: trio's own waits "
            f"({WAITS_VARIABLE}=trio)\n", "")
    finally:
        waits_in_use.cache_clear()


def test_without_a_command_the_parser_reads_the_printer_options():
    args = build_parser().parse_args(["--protocol", "marlin", "--printers", "3", "--tcp", "9000",
                                      "--speed", "10", "--fault", "to-host:drop-bytes=0.001"])
    assert args.command is None
    assert (args.protocol, args.printers, args.speed) == ("marlin", 3, 10.0)
    assert args.tcp == Address("127.0.0.1", 9000) and args.fault == ["to-host:drop-bytes=0.001"]
    args = build_parser().parse_args([])
    assert args.command is None and args.protocol == "auto" and args.printers == 1
    # A printer option's value that is a command's name is the value.
    args = build_parser().parse_args(["--link", "verify"])
    assert args.command is None and args.link == "verify"


@pytest.mark.parametrize("argv, message", [
    (["--speed", "0"], "argument --speed: must be a positive number, got '0'"),
    (["--protocol", "nope"], "argument --protocol: invalid choice: 'nope' (choose from 'auto', "
     "'marlin', 'ultimaker', 'repetier', 'commstack', 'g2core')"),
    (["--extruders", "x"], "argument --extruders: must be a whole number from 1 to 8, got 'x'"),
    (["--printers", "2", "--link", "/tmp/printer"], "argument --link: with --printers, put {n} "
     "in it (the printer's number, from 1), e.g. --link /tmp/printer-{n}"),
    (["--tcp", "9000", "--rfc2217", "9001"], "argument --rfc2217: not allowed with argument --tcp"),
    (["--tcp", "9000", "--link", "/tmp/printer"], "argument --link: there is no pty to link to "
     "with --tcp"),
])
def test_a_bad_printer_option_is_the_error_it_was(capsys, argv, message):
    code, out, err = run(capsys, *argv)
    assert code == 2 and out == ""
    assert err.endswith(f"\nfake-marlin: error: {message}\n")
    assert err.startswith("usage: fake-marlin [OPTION ...]")


@pytest.mark.parametrize("argv", [["frobnicate"], ["frobnicate", "--help"], ["verifyy", "a", "b"]])
def test_an_unknown_command_is_refused_with_the_choices(capsys, argv):
    code, out, err = run(capsys, *argv)
    assert code == 2 and out == ""
    assert err.endswith(f"fake-marlin: error: argument COMMAND: invalid choice: {argv[0]!r} "
                        "(choose from 'verify', 'scenario', 'bench', 'report')\n")


@pytest.mark.parametrize("argv", [
    ["--protocol", "marlin", "verify", "job.gcode", "journal"],
    ["--protocol", "marlin", "verify"],
    # The option's default value, and an option of the command's own name (--runs 0: were the
    # command to run, it would stop at once).
    ["--seed", "0", "scenario", "fuzz", "--protocol", "all", "--runs", "0", "--seed", "1",
     "--out", "out"],
    ["--printers", "1", "report", "trace.jsonl"],
])
def test_a_printer_option_before_a_command_is_refused_not_dropped(capsys, argv):
    code, out, err = run(capsys, *argv)
    command = next(word for word in argv if word in COMMANDS)
    assert code == 2 and out == ""
    assert err.endswith(
        f"fake-marlin: error: {argv[0]} is a printer option, and `fake-marlin {command}` runs no "
        f"printer: its own options go after its name (see fake-marlin {command} --help)\n")


@pytest.mark.parametrize("argv, error", [
    (["scenario"], "fake-marlin scenario: error: the following arguments are required: COMMAND"),
    (["scenario", "play"], "fake-marlin scenario: error: argument COMMAND: invalid choice: "
     "'play' (choose from 'run', 'fuzz')"),
    (["scenario", "run", "a.toml", "--bogus"],
     "fake-marlin scenario run: error: unrecognized arguments: --bogus"),
    (["verify", "job.gcode", "journal", "--bogus"],
     "fake-marlin verify: error: unrecognized arguments: --bogus"),
    (["verify", "job.gcode"], "fake-marlin verify: error: the following arguments are required: "
     "JOURNAL"),
    (["report", "trace", "--bogus"], "fake-marlin report: error: unrecognized arguments: --bogus"),
])
def test_a_command_tells_its_own_errors_with_its_own_usage(capsys, argv, error):
    code, out, err = run(capsys, *argv)
    assert code == 2 and out == ""
    assert err.startswith(f"usage: fake-marlin {argv[0]}") and err.endswith(f"\n{error}\n")
    assert "[OPTION ...]" not in err  # not the printer's usage


@pytest.mark.parametrize("argv, message", [
    (["--bogus"], "unrecognized arguments: --bogus"),
    (["--only", "hosts,nosuch"], "argument --only: unknown section 'nosuch'; choose from hosts, "
     "cpu, baud, latency, simhour, farm, lab"),
    (["--rounds", "0"], "argument --rounds: must be a whole number from 1 to 100, got '0'"),
])
def test_the_bench_errors_are_one_line(capsys, argv, message):
    code, out, err = run(capsys, "bench", *argv)
    assert code == 2 and out == ""
    assert err == f"fake-marlin bench: error: {message} (see fake-marlin bench --help)\n"


def test_each_command_parses_its_own_arguments():
    parser = build_parser()
    args = parser.parse_args(["verify", "job.gcode", "journal", "--strict", "--limit", "0"])
    assert (args.command, args.job, args.journal, args.strict, args.limit) == (
        "verify", "job.gcode", "journal", True, 0)
    assert args.run is verify_cli.run
    args = parser.parse_args(["scenario", "run", "a.toml", "b", "--json"])
    assert (args.command, args.scenario_command, args.paths, args.json) == (
        "scenario", "run", ["a.toml", "b"], True)
    assert args.run is scenario_cli.run_scenarios
    args = parser.parse_args(["scenario", "fuzz", "--protocol", "marlin", "--runs", "2", "--seed",
                              "5", "--out", "out"])
    assert (args.scenario_command, args.protocol, args.runs, args.seed, args.out) == (
        "fuzz", "marlin", 2, 5, "out")
    args = parser.parse_args(["bench", "--only", "cpu,hosts"])
    assert args.command == "bench" and args.only == ("hosts", "cpu")  # the documented order
    assert args.run is bench_cli.run
    args = parser.parse_args(["report", "trace.jsonl", "-o", "page.html"])
    assert (args.trace, args.output, args.run) == ("trace.jsonl", "page.html", report_cli.run)


def test_a_command_runs_in_this_process(capsys, tmp_path):
    job, journal = tmp_path / "job.gcode", tmp_path / "journal"
    job.write_text("G28\nG1 X1\n")
    journal.write_text("G28\nG1 X1\n")
    assert main(["verify", str(job), str(journal)]) == 0
    assert capsys.readouterr().out.startswith("OK: each of the 2 job commands ran once")
    journal.write_text("G28\n")
    assert main(["verify", str(job), str(journal)]) == 1


@pytest.mark.parametrize("module, name", [
    (verify_cli, "verify"), (report_cli, "report"), (scenario_cli, "scenario"),
    (bench_cli, "bench"),
])
def test_the_commands_main_functions_are_the_command(capsys, module, name):
    with pytest.raises(SystemExit) as exited:
        module.main(["--help"])
    assert exited.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: fake-marlin {name} ")


def test_the_installed_program_lists_its_commands_and_refuses_an_unknown_one():
    listed = subprocess.run([BIN / "fake-marlin", "--help"], capture_output=True, text=True,
                            timeout=60, env={"COLUMNS": "80", "PATH": "/usr/bin:/bin"})
    assert listed.returncode == 0 and listed.stderr == ""
    assert all(re.search(rf"^ +{name} +", listed.stdout, re.MULTILINE) for name in COMMANDS)
    refused = subprocess.run([BIN / "fake-marlin", "frobnicate"], capture_output=True, text=True,
                             timeout=60)
    assert refused.returncode == 2 and refused.stdout == ""
    assert "invalid choice: 'frobnicate'" in refused.stderr and "Traceback" not in refused.stderr


def test_the_names_written_out_for_the_parser_are_those_the_code_runs():
    from fake_marlin.emulator.bench.measure import SECTIONS
    from fake_marlin.emulator.scenario.fuzz import PROTOCOLS

    assert bench_cli.SECTIONS == tuple(SECTIONS)
    assert scenario_cli.FUZZ_PROTOCOLS == PROTOCOLS


def test_building_the_parser_imports_none_of_what_the_commands_run():
    # In a fresh interpreter: this one has imported them all by now.
    code = ("import sys; from fake_marlin.emulator.cli.main import build_parser; build_parser(); "
            "print('\\n'.join(sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded = set(done.stdout.split())
    assert "fake_marlin.emulator.cli.printers" in loaded
    for heavy in ("fake_marlin.emulator.bench.measure", "fake_marlin.emulator.scenario.run",
                  "fake_marlin.emulator.scenario.campaign", "fake_marlin.emulator.journal.verify",
                  "fake_marlin.emulator.report.build", "matplotlib", "pytest"):
        assert heavy not in loaded
