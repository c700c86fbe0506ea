"""Firmware profiles: shipped and a user's own, extending one; identities per printer."""

import subprocess
import sys
from pathlib import Path

import pytest

from fake_marlin.emulator.firmware import Firmware, ProfileError, load_profile, shipped
from fake_marlin.emulator.firmware.identity import make_identity
from fake_marlin.emulator.printer.statements import state

SHIPPED = ("g2core", "klipper", "marlin", "marlin-1.1", "prusa", "reprapfirmware", "repetier",
           "smoothieware", "ultimaker2")


@pytest.mark.parametrize("name", shipped())
def test_every_shipped_profile_loads_and_names_itself(name):
    profile = load_profile(name)
    assert profile.name == name and profile.title and profile.source
    words = Firmware.make(profile).words
    assert words.say(state("firmware_info", extruders=1))  # every firmware answers M115


def test_the_shipped_firmwares_are_the_ones_the_docs_name():
    assert set(shipped()) >= {"marlin", "repetier"}
    assert set(shipped()) <= set(SHIPPED)


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_a_profile_extending_marlin_changes_only_what_it_says(tmp_path):
    mine = write(tmp_path / "mine.toml", """
extends = "marlin"
name = "mine"
[identity]
version = "9.9.9"
[capabilities]
EEPROM = false
[quirks]
ok_before_output = true
""")
    profile, marlin = load_profile(str(mine)), load_profile("marlin")
    assert profile.version == "9.9.9" and profile.date == marlin.date
    assert profile.capability("EEPROM") is False
    assert len(profile.capabilities) == len(marlin.capabilities)  # merged, not replaced
    assert profile.quirks.ok_before_output and not marlin.quirks.ok_before_output
    assert profile.templates["unknown_command"] == marlin.templates["unknown_command"]


def test_replace_makes_a_table_the_new_profiles_own(tmp_path):
    mine = write(tmp_path / "mine.toml", """
extends = "marlin"
replace = ["capabilities"]
name = "mine"
[capabilities]
AUTOREPORT_TEMP = true
""")
    assert load_profile(str(mine)).capabilities == (("AUTOREPORT_TEMP", True),)


def test_a_profile_may_extend_another_file_beside_it(tmp_path):
    write(tmp_path / "base.toml", 'extends = "marlin"\nname = "base"\n[identity]\nversion = "1.2.3"\n')
    child = write(tmp_path / "child.toml", 'extends = "base.toml"\nname = "child"\n')
    assert load_profile(str(child)).version == "1.2.3"


@pytest.mark.parametrize("text, words", [
    ('extends = "marlin"\nname = "x"\n[messages]\nunknown_command = "Unknown {cmd}"\n',
     "unknown_command: 'Unknown {cmd}' names {cmd}, which is not one of its values"),
    ('extends = "marlin"\nname = "x"\n[messages]\nno_such_statement = "x"\n',
     "no_such_statement: is not a key this table knows"),
    ('extends = "marlin"\nname = "x"\n[quirks]\ndrop_ok_every = -1\n', "must be at least 0"),
    ('extends = "marlin"\nname = "x"\n[quirks]\nlocked = true\n', "needs a password"),
    ('extends = "marlin"\nname = "x"\nprotocols = ["bogus"]\n', "'bogus' is not one of"),
    ('extends = "nope"\nname = "x"\n', "no firmware 'nope'"),
    ('extends = "self.toml"\nname = "x"\n', "more than 8 profiles deep"),
    ('name = "x"\n[lines]\nchecksum = "sometimes"\n', "checksum: must be one of"),
    ("name = [\n", "not valid TOML"),
])
def test_a_broken_profile_is_refused_naming_the_key(tmp_path, text, words):
    path = write(tmp_path / "self.toml", text)
    with pytest.raises(ProfileError) as refused:
        load_profile(str(path))
    assert words in str(refused.value) and str(path) in str(refused.value)


def test_a_missing_profile_file_is_refused():
    with pytest.raises(ProfileError, match="cannot read"):
        load_profile("/nonexistent/printer.toml")


def test_identities_differ_per_printer_and_repeat_per_seed():
    profile = load_profile("marlin")
    ids = [make_identity(7, n, profile.uuid, profile.serial, profile.machine_name)
           for n in range(1, 200)]
    assert len({i.uuid for i in ids}) == len({i.serial for i in ids}) == 199
    assert len({i.machine_name for i in ids}) == 199
    again = make_identity(7, 5, profile.uuid, profile.serial, profile.machine_name)
    assert again == ids[4]
    other_seed = make_identity(8, 5, profile.uuid, profile.serial, profile.machine_name)
    assert other_seed.uuid != ids[4].uuid


def test_firmware_list_names_every_shipped_profile():
    done = subprocess.run([sys.executable, "-m", "fake_marlin.emulator.cli", "--firmware", "list"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0
    listed = [line.split()[0] for line in done.stdout.splitlines() if line and line[0] != " "
              and not line.startswith("Or ")]
    assert listed == shipped()


@pytest.mark.parametrize("args, words", [
    (["--firmware", "nope"], "no firmware 'nope'"),
    (["--quirk", "nope"], "no quirk 'nope'"),
    (["--quirk", "drop_ok_every=-2"], "must be at least 0"),
    (["--firmware", "repetier", "--protocol", "marlin"], "speaks repetier, not marlin"),
    (["--farm", "farm.toml", "--firmware", "prusa"], "--firmware goes in the farm file"),
    (["--farm", "farm.toml", "--quirk", "no_m112"], "--quirk goes in the farm file"),
])
def test_wrong_firmware_flags_are_refused_with_a_message(args, words):
    done = subprocess.run([sys.executable, "-m", "fake_marlin.emulator.cli", *args],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and words in done.stderr and "Traceback" not in done.stderr


def test_a_quirk_that_takes_text_takes_it_as_typed():
    from fake_marlin.emulator.cli.printers import _quirk

    assert _quirk("password=1234") == ("password", "1234")  # docs/cli.md's example
    assert _quirk("password=0042") == ("password", "0042")
    assert _quirk("drop_ok_every=40") == ("drop_ok_every", 40)
    assert _quirk("no_m112") == ("no_m112", True)
