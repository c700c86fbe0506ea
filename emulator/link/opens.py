"""Whether a host opened a pty, or only flushed it: inotify's IN_OPEN on the slave device.

A host's open() flushes its input, which reaches the pty master as a FLUSHREAD notice, the
pty's stand-in for the DTR reset of a real board. But a host may also flush a port it already
has open (binproto2's reader does, right after opening): the same notice, and no reset on a
board, which resets on DTR at open only. An open of the slave device since the last notice
tells the two apart.

One inotify instance serves the whole process, one watch per pty: a farm of 200 printers would
exceed the 128 instances a user may have. Where inotify cannot be had, watch() says None and
every notice counts as an open, as it did before.
"""

import ctypes
import os
import struct

IN_OPEN = 0x20
_EVENT = struct.Struct("iIII")  # struct inotify_event: wd, mask, cookie, len (then the name)


class OpenWatcher:
    def __init__(self) -> None:
        self._libc: ctypes.CDLL | None = None
        self._fd = -1
        self._opened: dict[int, bool] = {}  # watch -> an open since it was last asked
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            fd = libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC)
        except (OSError, AttributeError):
            return
        if fd >= 0:
            self._libc, self._fd = libc, fd

    def watch(self, path: str) -> int | None:
        """A watch on the device at `path`, or None if there can be none."""
        if self._libc is None:
            return None
        wd = self._libc.inotify_add_watch(self._fd, os.fsencode(path), IN_OPEN)
        if wd < 0:
            return None
        self._opened[wd] = False
        return int(wd)

    def forget(self, wd: int | None) -> None:
        if wd is not None and self._libc is not None and self._opened.pop(wd, None) is not None:
            self._libc.inotify_rm_watch(self._fd, wd)  # fails harmlessly once the pty is gone

    def opened(self, wd: int) -> bool:
        """Whether the device was opened since this was last asked (for this watch)."""
        self._read_events()
        opened = self._opened.get(wd, False)
        if opened:
            self._opened[wd] = False
        return opened

    def _read_events(self) -> None:
        while True:
            try:
                data = os.read(self._fd, 4096)
            except (BlockingIOError, OSError):
                return
            offset = 0
            while offset + _EVENT.size <= len(data):
                wd, mask, _cookie, length = _EVENT.unpack_from(data, offset)
                offset += _EVENT.size + length
                if mask & IN_OPEN and wd in self._opened:
                    self._opened[wd] = True


_watcher: OpenWatcher | None = None


def open_watcher() -> OpenWatcher:
    """The process's one watcher, made when the first pty needs it."""
    global _watcher
    if _watcher is None:
        _watcher = OpenWatcher()
    return _watcher
