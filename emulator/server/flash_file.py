"""`--flash-file`: a printer's flash kept in a file across runs, as a board keeps it unpowered.

The file is the raw 256 KiB image, byte 0 first (what `avrdude -U flash:r:FILE:r` reads off a
board whose boot section is blank). Each flash page the bootloader writes goes to the file in
place before the host hears that it was written, so a printer killed mid-flash keeps exactly
the pages it had acknowledged, as a board that loses power mid-flash does.
"""

import os
import sys
import tempfile
from pathlib import Path

from fake_marlin.emulator.protocols.avr_memory import (
    ERASED,
    FLASH_SIZE,
    PAGE_SIZE,
    BoardMemory,
)


class FlashFileError(Exception):
    """A flash file that cannot be used; the message says which and why."""


class FlashFile:
    def __init__(self, path: Path, fd: int, memory: BoardMemory) -> None:
        self.path = path
        self.memory = memory
        self._fd = fd
        self._write_failed = False

    @classmethod
    def open(cls, path: str | os.PathLike[str]) -> "FlashFile":
        """The file's image in a BoardMemory; a missing file is created erased."""
        where = Path(path)
        try:
            if not where.exists():
                _create_erased(where)
            fd = os.open(where, os.O_RDWR)
        except OSError as error:
            raise FlashFileError(f"--flash-file {where}: {error.strerror or error}") from None
        try:
            size = os.fstat(fd).st_size
            if size != FLASH_SIZE:
                raise FlashFileError(
                    f"--flash-file {where}: {size} bytes, but an ATmega2560's flash image is "
                    f"{FLASH_SIZE} ({FLASH_SIZE // 1024} KiB); give another path to start erased"
                )
            image = os.pread(fd, FLASH_SIZE, 0)
            if len(image) != FLASH_SIZE:
                raise FlashFileError(f"--flash-file {where}: it shrank while it was read")
        except OSError as error:
            os.close(fd)
            raise FlashFileError(f"--flash-file {where}: {error.strerror or error}") from None
        except FlashFileError:
            os.close(fd)
            raise
        return cls(where, fd, BoardMemory(image))

    def save(self) -> None:
        """Write the pages changed since the last save to the file."""
        flash = self.memory.flash
        for page in self.memory.take_changed_pages():
            start = page * PAGE_SIZE
            try:
                os.pwrite(self._fd, flash[start:start + PAGE_SIZE], start)
            except OSError as error:
                if not self._write_failed:
                    print(f"fake-marlin: cannot write the flash file {self.path}: "
                          f"{error.strerror or error}; trying again at exit", file=sys.stderr)
                self._write_failed = True

    def close(self) -> None:
        """Save what is left, and the whole image once more if a page could not be written."""
        self.save()
        if self._write_failed:
            try:
                os.pwrite(self._fd, bytes(self.memory.flash), 0)
            except OSError as error:
                print(f"fake-marlin: the flash file {self.path} misses pages written since "
                      f"it failed: {error.strerror or error}", file=sys.stderr)
        os.close(self._fd)


def _create_erased(path: Path) -> None:
    """An erased image at `path`, whole or not at all: a crash leaves no short file behind."""
    fd, temporary = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)  # as open() would have made it, not mkstemp's 0600
        with os.fdopen(fd, "wb") as file:
            file.write(bytes([ERASED]) * FLASH_SIZE)
        os.replace(temporary, path)
    except BaseException:
        os.unlink(temporary)
        raise
