"""The SD card (printer/sdcard.py): the one way the command sets read and write its directory,
where what cannot be read is a file that is not there; and M20 T's FAT time stamps, the same
in any time zone."""

import os
import time
from pathlib import Path

import pytest

from fake_marlin.emulator.printer.model import Printer, PrinterConfig
from fake_marlin.emulator.printer.sdcard import SdCard, fat_stamp
from fake_marlin.testing import memory_printer
from tests.terminal import Terminal


@pytest.fixture
def card(tmp_path) -> SdCard:
    root = tmp_path / "sd"
    root.mkdir()
    (root / "b.gcode").write_text("G28\n")
    (root / "A.gcode").write_text("G1 X1\n")
    (root / ".hidden").write_text("x")
    (root / "sub").mkdir()
    (root / "sub" / "in.gcode").write_text("G1\n")
    (root / "gone.gcode").symlink_to(root / "nowhere")
    (root / "loop.gcode").symlink_to(root / "loop.gcode")
    (root / "sub" / "up").symlink_to(root)  # a folder loop: not entered
    return SdCard(root)


def test_a_listing_is_by_name_hidden_entries_too_and_what_cannot_be_stated_is_left_out(card):
    entries = card.listing()
    assert [entry.name for entry in entries] == [".hidden", "A.gcode", "b.gcode", "sub"]
    assert [(entry.is_dir, entry.is_file, entry.size) for entry in entries[1:3]] == [
        (False, True, 6), (False, True, 4)]
    assert entries[3].is_dir and not entries[3].is_file
    assert card.listing(card.root / "b.gcode") is None  # no folder
    assert card.listing(card.root / "missing") is None
    assert SdCard(None).listing() is None


def test_files_below_are_at_any_depth_without_following_a_folder_link(card):
    assert sorted(name for name, _ in card.files_below()) == [
        ".hidden", "A.gcode", "b.gcode", "sub/in.gcode"]


@pytest.mark.parametrize("name", ["missing", "gone.gcode", "loop.gcode", "x" * 300, "a\x00b"])
def test_a_file_not_there_or_the_system_refuses_is_none_not_an_exception(card, name):
    path = card.root / name
    assert card.stat(path) is None
    assert card.read(path) is None
    assert card.create(path / "x") is False
    assert card.listing(path) is None
    if name != "loop.gcode":
        assert card.inside(path) == (None if "\x00" in name else path.resolve())


@pytest.mark.parametrize("name", ["missing", "x" * 300, "a\x00b"])
def test_what_is_not_there_cannot_be_deleted(card, name):
    assert card.delete(card.root / name) is False


def test_create_read_and_delete(card):
    path = card.root / "new" / "up.gcode"
    assert card.create(path, b"G28\n") is False  # its folder is not there
    assert card.create(path, b"G28\n", make_folders=True)
    assert card.read(path) == b"G28\n" and card.stat(path).size == 4
    assert card.create(card.root / "sub", b"") is False  # a folder
    assert card.delete(path) and card.stat(path) is None
    assert card.delete(card.root / "sub") is False


def test_inside_is_the_card_and_nothing_out_of_it(card):
    root = card.root.resolve()
    assert card.inside(card.root / "sub" / ".." / "b.gcode") == root / "b.gcode"
    assert card.inside(card.root / ".." / "b.gcode") is None
    assert card.inside(card.root) is None
    assert card.inside(card.root, root_too=True) == root
    assert card.inside(card.root / "sub" / "up" / "A.gcode") == root / "A.gcode"
    assert SdCard(None).inside(Path("/tmp")) is None


def test_fat_stamps_are_utc_and_within_what_fat_holds():
    assert fat_stamp(1_700_000_000) == (0x576E, 0xB1AA)  # 2023-11-14 22:13:20 UTC
    assert fat_stamp(0) == fat_stamp(-1e30) == (0x0021, 0)  # before 1980: 1980-01-01 00:00
    assert fat_stamp(1e12) == fat_stamp(1e300) == (0xFF9F, 0xBF7D)  # 2107-12-31 23:59:58


async def test_marlins_m20_t_is_the_same_in_any_time_zone(autojump_clock, tmp_path, monkeypatch):
    (tmp_path / "cube.gcode").write_text("G28\n")
    os.utime(tmp_path / "cube.gcode", (1_700_000_000, 1_700_000_000))
    monkeypatch.setenv("TZ", "JST-9")
    time.tzset()
    try:
        async with memory_printer(firmware="marlin", protocol="marlin",
                                  sd_dir=tmp_path) as printer:
            terminal = Terminal(printer.open())
            await terminal.read_until(lambda line: line == "//action:prompt_end")
            assert await terminal.command("M20 T") == [
                "Begin file list", "CUBE~1.GCO 4 0x576EB1AA", "End file list", "ok"]
    finally:
        monkeypatch.undo()
        time.tzset()



def test_marlins_m26_takes_a_position_too_large_for_a_float_as_strtol_would(tmp_path):
    # (400 digits pass Marlin's parse as infinity, and int() of it raised OverflowError.)
    (tmp_path / "cube.gcode").write_text("G28\n")
    printer = Printer(PrinterConfig(sd_dir=tmp_path))
    for line in ("M23 cube.gcode", "M26 S" + "9" * 400):
        with pytest.raises(StopIteration):
            next(printer.execute(line, 0.0))  # answered at once
    assert printer.sd.selected is not None and printer.sd.selected.position == 2 ** 31 - 1
