"""The SD card, backed by a directory: M20-M30, M524, stating what Marlin says of each.

Files are shown under FAT 8.3 names (`TEST~1.GCO`) as Marlin's SdFat does, and with their long
names where EXTENDED_M20 asks for them. M23 accepts either.

Every command set reads and writes the card through SdCard (stat, listing, files_below, read,
create, delete, inside): a file that cannot be read, a name the system refuses (too long, a NUL
in it) or a symlink loop is then a file that is not there, not an exception out of the server.
"""

import re
import stat as stat_mode
import time
from dataclasses import dataclass
from pathlib import Path

from fake_marlin.emulator.printer import gcode, host_actions
from fake_marlin.emulator.printer.gcode import Command
from fake_marlin.emulator.printer.statements import Statement, state
from fake_marlin.emulator.printer.steps import reply
from fake_marlin.wire.gcode import strip_comment

_SHORT_OK = re.compile(r"[A-Z0-9_$%'\-@~`!(){}^#&]+")


def _short_names(names: list[str]) -> dict[str, str]:
    """Long name -> 8.3 name, with ~N tails where a name does not fit, unique per directory."""
    result, taken = {}, set()
    for name in sorted(names):
        base, dot, ext = name.rpartition(".") if "." in name else (name, "", "")
        upper_base, upper_ext = base.upper(), ext.upper()
        if len(base) <= 8 and len(ext) <= 3 and _SHORT_OK.fullmatch(upper_base or "?") and (
            not ext or _SHORT_OK.fullmatch(upper_ext)
        ) and upper_base + dot + upper_ext not in taken:
            short = upper_base + dot + upper_ext
        else:
            stem = re.sub(r"[^A-Z0-9_]", "", upper_base)[:6] or "FILE"
            tail = re.sub(r"[^A-Z0-9_]", "", upper_ext)[:3]
            number = 1
            while (short := f"{stem}~{number}" + (f".{tail}" if tail else "")) in taken:
                number += 1
        taken.add(short)
        result[name] = short
    return result


_FAT_FIRST = ((0 << 9) | (1 << 5) | 1, 0)  # 1980-01-01 00:00:00
_FAT_LAST = ((127 << 9) | (12 << 5) | 31, (23 << 11) | (59 << 5) | 29)  # 2107-12-31 23:59:58


def fat_stamp(mtime: float) -> tuple[int, int]:
    """A modification time as a FAT directory entry keeps it: (date, time), each 16 bits.

    FAT has no time zone: the card holds the clock of the machine that wrote it. The model
    says it in UTC, so that M20 T says the same on any machine; before 1980 and after 2107,
    which FAT cannot hold, the nearest it can (as Linux's vfat does)."""
    try:
        stamp = time.gmtime(mtime)
    except (OverflowError, OSError, ValueError):  # beyond what the C library's time_t holds
        return _FAT_FIRST if mtime < 0 else _FAT_LAST
    if stamp.tm_year < 1980:
        return _FAT_FIRST
    if stamp.tm_year > 2107:
        return _FAT_LAST
    date = ((stamp.tm_year - 1980) << 9) | (stamp.tm_mon << 5) | stamp.tm_mday
    clock = (stamp.tm_hour << 11) | (stamp.tm_min << 5) | (stamp.tm_sec // 2)
    return date, clock


@dataclass(frozen=True)
class CardEntry:
    """A file or folder of the card, as a listing sees it (its stat, symlinks followed)."""

    name: str
    path: Path
    is_dir: bool
    is_file: bool  # a regular file (neither: a device, a FIFO...)
    size: int  # bytes (what the system says of a folder: callers say 0)
    mtime: float  # seconds since the epoch


# What a path of the card can raise besides OSError: ValueError for a NUL in a name,
# RuntimeError for a symlink loop (Path.resolve()).
_PATH_ERRORS = (OSError, ValueError, RuntimeError)


@dataclass
class OpenFile:
    path: Path
    short: str
    data: bytes
    position: int = 0


class SdCard:
    # What ends each line M28 writes: Marlin's card.write_command() "\r\n"; a command set
    # that writes otherwise sets its own (RepRapFirmware's "\n").
    line_end = "\r\n"

    def __init__(self, root: Path | None) -> None:
        self.root = root
        self.reset()

    def reset(self) -> None:
        self.mounted = self.inserted()
        self.selected: OpenFile | None = None
        self.printing = False
        self.saving: Path | None = None
        self.binary_mode = False  # M28 B1 asked for the binary protocol (the session takes it)

    # -- reading and writing the directory ------------------------------------------------
    def inserted(self) -> bool:
        """Whether there is a card: the card's directory is there (mounted or not)."""
        entry = self.stat(self.root)
        return entry is not None and entry.is_dir

    def stat(self, path: Path | None) -> CardEntry | None:
        """The file or folder at `path`; None where there is none (or it cannot be looked at)."""
        if path is None:
            return None
        try:
            info = path.stat()
        except _PATH_ERRORS:
            return None
        return CardEntry(path.name, path, stat_mode.S_ISDIR(info.st_mode),
                         stat_mode.S_ISREG(info.st_mode), info.st_size, info.st_mtime)

    def listing(self, directory: Path | None = None) -> list[CardEntry] | None:
        """What a folder holds (the card's own directory by default), by name, hidden entries
        (a leading dot) too: each command set leaves out and orders what its firmware does.
        None where the folder is not there, or is no folder."""
        folder = self.root if directory is None else directory
        if folder is None:
            return None
        try:
            names = sorted(child.name for child in folder.iterdir())
        except _PATH_ERRORS:
            return None
        entries = (self.stat(folder / name) for name in names)
        return [entry for entry in entries if entry is not None]

    def files_below(self, directory: Path | None = None) -> list[tuple[str, CardEntry]]:
        """Every file in a folder and the folders in it, at any depth (the folders a symlink
        leads to not entered): its path from the folder, with `/`, and its entry. In no
        order: the caller's firmware orders them."""
        folder = self.root if directory is None else directory
        if folder is None:
            return []
        found = []
        try:
            for path in folder.rglob("*"):
                entry = self.stat(path)
                if entry is not None and entry.is_file:
                    found.append((path.relative_to(folder).as_posix(), entry))
        except _PATH_ERRORS:
            pass  # a folder that went, or cannot be read: what was found so far
        return found

    def read(self, path: Path) -> bytes | None:
        """The bytes of a file; None if it cannot be read."""
        try:
            return path.read_bytes()
        except _PATH_ERRORS:
            return None

    def create(self, path: Path, data: bytes = b"", make_folders: bool = False) -> bool:
        """A file made (or emptied) holding `data`, with the folders on its way where
        `make_folders` says so; False if it cannot be."""
        try:
            if make_folders:
                path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
        except _PATH_ERRORS:
            return False
        return True

    def delete(self, path: Path) -> bool:
        """A file deleted; False if it cannot be (not there, a folder, not allowed)."""
        try:
            path.unlink()
        except _PATH_ERRORS:
            return False
        return True

    def inside(self, path: Path, root_too: bool = False) -> Path | None:
        """`path` with its symlinks and `..` resolved, if that is on the card (the card's
        directory itself only with `root_too`); None for a path that would leave it, one the
        system cannot resolve, or no card."""
        if self.root is None:
            return None
        try:
            root = self.root.resolve()
            resolved = path.resolve()
        except _PATH_ERRORS:
            return None
        if root in resolved.parents or (root_too and resolved == root):
            return resolved
        return None

    # -- the directory as Marlin sees it ---------------------------------------------------
    def entries(self) -> list[tuple[str, str, Path]]:
        """(8.3 path, long path, file) for every file, depth first, as M20 lists them."""
        found = []

        def walk(directory: Path, short_prefix: str, long_prefix: str) -> None:
            children = [entry for entry in self.listing(directory) or ()
                        if not entry.name.startswith(".")]
            shorts = _short_names([entry.name for entry in children])
            for child in children:
                short, long = short_prefix + shorts[child.name], long_prefix + child.name
                if child.is_dir:
                    walk(child.path, short + "/", long + "/")
                elif child.is_file:
                    found.append((short, long, child.path))

        if self.mounted and self.root is not None:
            walk(self.root, "", "")
        return found

    def find(self, name: str) -> tuple[str, Path] | None:
        wanted = name.strip().lstrip("/")
        for short, long, path in self.entries():
            if wanted in (short, long) or wanted.upper() == short:
                return short, path
        return None

    def path_on_card(self, name: str) -> Path | None:
        """Where a file called `name` goes on the card; None for a name like ../x that would
        reach outside it, or with no card."""
        if self.root is None:
            return None
        return self.inside(self.root / name.strip().lstrip("/"))

    # -- printing ----------------------------------------------------------------------
    def next_line(self) -> str | None:
        """The next command of the file being printed, or None at its end."""
        selected = self.selected
        while selected is not None and selected.position < len(selected.data):
            end = selected.data.find(b"\n", selected.position)
            end = len(selected.data) if end < 0 else end + 1
            raw = selected.data[selected.position:end]
            selected.position = end
            command = strip_comment(raw.decode("ascii", "replace"))
            if command:
                return command
        return None

    def open_for_write(self, name: str) -> tuple[Path, str] | None:
        """The file `name` created, or emptied, for writing (M28, a binary transfer's OPEN):
        its path and the name `Writing to file:` shows; None if it cannot be."""
        found = self.find(name)
        path = found[1] if found else self.path_on_card(name)
        if path is None or not self.create(path, make_folders=True):
            return None
        return path, found[0] if found else name.strip()

    def append(self, path: Path, data: bytes) -> bool:
        try:
            with open(path, "ab") as target:
                target.write(data)
        except OSError:
            return False
        return True

    def remove(self, path: Path) -> str | None:
        """Delete a file of the card; its 8.3 name, or None if it was not there."""
        short = next((short for short, _, entry in self.entries() if entry == path), None)
        if not self.delete(path):
            return None
        return short or path.name

    def write_line(self, text: str) -> None:
        if self.saving is None:
            raise RuntimeError("no file is open for writing (M28)")
        with open(self.saving, "a", encoding="ascii", errors="replace", newline="") as target:
            target.write(text + self.line_end)

    def status(self) -> Statement:
        if self.selected is not None and self.printing:
            return state("sd_printing_byte", position=self.selected.position,
                         size=len(self.selected.data))
        return state("not_sd_printing")


def _no_media(printer) -> bool:
    return not printer.sd.mounted


def list_files(printer, command: Command, now: float):
    if _no_media(printer):
        return reply(state("no_media"))
    with_long = "L" in command.string_argument.upper()
    with_time = "T" in command.string_argument.upper()
    key = "file_entry" + ("_long" if with_long else "") + ("_time" if with_time else "")
    lines = [state("file_list_begin")]
    for short, long, path in printer.sd.entries():
        info = printer.sd.stat(path)
        if info is None:  # gone since the listing
            continue
        fat_date, fat_time = fat_stamp(info.mtime)
        lines.append(state(key, short=short, size=info.size, long=long,
                           stamp=f"0x{fat_date:04X}{fat_time:04X}"))
    lines.append(state("file_list_end"))
    return reply(*lines)


def mount(printer, command: Command, now: float):
    printer.sd.reset()
    return reply(state("sd_ok" if printer.sd.mounted else "sd_init_fail"))


def release(printer, command: Command, now: float):
    printer.sd.reset()
    printer.sd.mounted = False
    return reply(state("sd_released"))


def select_file(printer, command: Command, now: float):
    name = command.string_argument
    if _no_media(printer):
        return reply(state("no_media"))
    found = printer.sd.find(name)
    if found is None:
        return reply(state("open_failed", name=name))
    short, path = found
    data = printer.sd.read(path)
    if data is None:
        return reply(state("open_failed", name=name))
    printer.sd.selected = OpenFile(path, short, data)
    printer.sd.printing = False
    return reply(state("file_opened", name=short, size=len(printer.sd.selected.data), long=path.name),
                 state("file_selected"))


def start_print(printer, command: Command, now: float):
    if printer.sd.selected is not None:
        printer.sd.printing = True
    return reply(*host_actions.sd_resumed(printer))  # M24 says so, printing or not


def pause_print(printer, command: Command, now: float):
    printer.sd.printing = False
    return reply(*host_actions.sd_paused(printer))


def set_position(printer, command: Command, now: float):
    if printer.sd.selected is not None:  # setIndex(parser.value_long()): strtol's range
        printer.sd.selected.position = max(0, gcode.whole(command.value("S", 0.0)))
    return reply()


def report_status(printer, command: Command, now: float):
    if command.has("S"):
        printer.auto_reports.sd_status = max(0.0, command.value("S", 0.0))
        return reply()
    if command.has("C"):
        selected = printer.sd.selected
        if selected is None:
            return reply(state("no_current_file"))
        return reply(state("current_file", short=selected.short, long=selected.path.name))
    return reply(printer.sd.status())


_BINARY_FLAG = re.compile(r"B(\d) *")  # M28_M29.cpp: `B` and a digit first


def begin_write(printer, command: Command, now: float):
    name = command.string_argument
    if printer.config.capability("BINARY_FILE_TRANSFER") and (flag := _BINARY_FLAG.match(name)):
        if flag[1] > "0":  # M28 B1: the session hands the line to the binary protocol
            printer.sd.binary_mode = True
            return reply(state("switching_to_binary"))
        name = name[flag.end():]
    if _no_media(printer):
        return reply(state("no_media"))
    opened = printer.sd.open_for_write(name)
    if opened is None:
        return reply(state("open_failed", name=name))
    printer.sd.saving, shown = opened
    return reply(state("writing_to_file", name=shown))


def end_write(printer, command: Command, now: float):
    if printer.sd.saving is None:
        return reply()
    printer.sd.saving = None
    return reply(state("done_saving"))


def delete_file(printer, command: Command, now: float):
    name = command.string_argument
    found = None if _no_media(printer) else printer.sd.find(name)
    if found is None:
        return reply(state("deletion_failed", name=name))
    short, path = found
    if not printer.sd.delete(path):
        return reply(state("deletion_failed", name=name))
    if printer.sd.selected is not None and printer.sd.selected.path == path:
        printer.sd.selected = None
        printer.sd.printing = False
    return reply(state("file_deleted", name=short))


def abort_print(printer, command: Command, now: float):
    if printer.sd.printing or printer.sd.selected is not None:
        printer.sd.printing = False
        printer.sd.selected = None
    return reply()


HANDLERS = {
    "M20": list_files,
    "M21": mount,
    "M22": release,
    "M23": select_file,
    "M24": start_print,
    "M25": pause_print,
    "M26": set_position,
    "M27": report_status,
    "M28": begin_write,
    "M29": end_write,
    "M30": delete_file,
    "M524": abort_print,
}
