"""The machine's limits a big farm meets, said before any printer starts: the kernel's ptys
(`kernel.pty.max`, 4,096 by default, shared by the whole machine) and this process's open files.
"""

import errno
import resource
from pathlib import Path

_PTY = Path("/proc/sys/kernel/pty")
_SPARE_FILES = 64  # the interpreter's own, sockets of the control channel, the web view


def pty_room() -> tuple[int, int] | None:
    """(kernel.pty.max, ptys open now on the machine), or None where Linux does not say."""
    try:
        return int((_PTY / "max").read_text()), int((_PTY / "nr").read_text())
    except (OSError, ValueError):
        return None


def pty_problem(count: int) -> str | None:
    """Why `count` more ptys cannot be had, or None if they can (as far as the kernel says)."""
    room = pty_room()
    if room is None or count <= room[0] - room[1]:
        return None
    most, used = room
    return (f"{count:,} printers on ptys need {count:,} ptys, but the kernel has room for "
            f"{max(0, most - used):,} more (sysctl kernel.pty.max = {most:,}, {used:,} in use): "
            f"serve them on TCP (--tcp PORT), or raise the limit as root: "
            f"sysctl -w kernel.pty.max={used + count + 1024}")


def files_needed(ptys: int, sockets: int, files: int) -> int:
    """Open files a process of these printers holds: a pty's master, our own slave end and its
    inotify watch's share; a listening socket and its host; journals, traces and the like."""
    return 2 * ptys + 2 * sockets + files + _SPARE_FILES


def raise_file_limit(needed: int) -> str | None:
    """Raise this process's open-file limit to `needed` if it is lower; why it cannot, or None."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY or needed <= soft:
        return None
    if hard != resource.RLIM_INFINITY and needed > hard:
        return (f"these printers need about {needed:,} open files, but a process here may open "
                f"at most {hard:,} (ulimit -Hn): spread them over more processes (--processes K) "
                f"or raise the hard limit")
    try:
        resource.setrlimit(resource.RLIMIT_NOFILE, (needed, hard))
    except (ValueError, OSError) as error:
        return f"cannot raise the open-file limit to {needed:,}: {error}"
    return None


def explain(error: OSError) -> str | None:
    """What to do about an OSError that means a limit, or None for any other."""
    if error.errno == errno.ENOSPC or error.errno == errno.EAGAIN and not error.filename:
        room = pty_room()
        if room is not None:
            return (f"the kernel has no pty left (sysctl kernel.pty.max = {room[0]:,}, "
                    f"{room[1]:,} in use): serve printers on TCP (--tcp PORT) or raise it")
    if error.errno in (errno.EMFILE, errno.ENFILE):
        soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
        return (f"too many open files (this process may open {soft:,}; ulimit -n): spread the "
                "printers over more processes (--processes K)")
    return None
