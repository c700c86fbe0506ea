"""The bare ok-responder: the least a Marlin printer on a pty can be, as the bench's reference.

    python -m fake_marlin.emulator.bench.responder      # prints its /dev/pts path, then serves
    python -m fake_marlin.emulator.bench.responder --trio   # the same, waiting as fake-marlin does

Every line a host sends is answered at once with `ok`, so a host's throughput against it is
what the host and the pty alone allow, and its CPU per command what a pty program cannot go
below. Just enough more that real hosts go online and finish a job:
- opening the port (a FLUSHREAD notice in packet mode, as the emulator's PtyLink sees it) is a
  reset: the line counter goes back to 0 and `start` greets the host (OctoPrint and printcore
  wait for it or for an ok; our host waits up to half a second for a greeting before sending);
- M105 says `ok T:20.0 /0.0 B:20.0 /0.0`, M115 a firmware name and one `Cap:` line (OctoPrint
  waits for the end of the capability report);
- numbered lines move the counter, M110 sets it, and a numbered line with a wrong or missing
  checksum draws Marlin's `Error:`/`Resend:`/`ok` naming it: our Marlin host reads the
  counter that way (its probe, `N0 M105 M110*256`, is refused by design) before it starts and
  before it ends a job;
- blank lines get no answer, as in Marlin: our host puts a line feed before its probe, and an
  `ok` for it would acknowledge the wrong line.
Nothing else: no planner, no time, no line-number policing. Plain blocking I/O without trio, so
that the reference costs as little as it can.
"""

import errno
import fcntl
import os
import re
import select
import signal
import struct
import sys
import termios
import tty

# Loaded before the pty's path is printed, also by the plain variant, which does not use them:
# imported after it, trio's 0.2 s of CPU fell into the trio variant's first run, which the bench
# counted as some 85 µs a command.
import trio

from fake_marlin.emulator.link.direct_wait import DirectWait
from fake_marlin.wire.checksums import xor8

_TIOCPKT_DATA = 0
_TIOCPKT_FLUSHREAD = 1
_LINE = re.compile(rb"\s*(?:[Nn](-?\d+)\s*)?(.*?)(?:\*(\d*))?\s*")
_M110_NUMBER = re.compile(rb"[Nn](-?\d+)")
M105_OK = b"ok T:20.0 /0.0 B:20.0 /0.0 @:0 B@:0\n"
M115_REPLY = (
    b"FIRMWARE_NAME:Marlin bare-ok-responder SOURCE_CODE_URL:- PROTOCOL_VERSION:1.0 "
    b"MACHINE_TYPE:bench EXTRUDER_COUNT:1\nCap:AUTOREPORT_TEMP:0\nok\n"
)


class _Stop(Exception):
    """SIGTERM, SIGHUP or Ctrl-C: leave the loop and close the pty."""


def _stop(signum: int, frame: object) -> None:
    raise _Stop


class Responder:
    """The line logic, apart from the pty so that it can be tested on bytes alone."""

    def __init__(self) -> None:
        self.last_line = 0  # Marlin's counter: the last numbered line accepted
        self.lines = 0  # lines answered, for whoever is curious
        self._buffer = b""

    def reset(self) -> bytes:
        self.last_line = 0
        self._buffer = b""
        return b"start\n"

    def receive(self, data: bytes) -> bytes:
        """What to answer to these bytes: one reply per complete line."""
        *lines, self._buffer = (self._buffer + data).split(b"\n")
        return b"".join(self._answer(line) for line in lines)

    def _answer(self, line: bytes) -> bytes:
        match = _LINE.fullmatch(line)
        if match is None or not match[2] and match[1] is None:
            return b""  # blank (or only "\r"): Marlin says nothing
        self.lines += 1
        number, command, checksum = match[1], match[2], match[3]
        if number is not None:
            body = line[: line.rindex(b"*")] if checksum is not None else b""
            if checksum is None or not checksum or xor8(body.lstrip()) != int(checksum):
                kind = b"No Checksum with line number" if checksum is None else b"checksum mismatch"
                return b"Error:%s, Last Line: %d\nResend: %d\nok\n" % (
                    kind, self.last_line, self.last_line + 1)
            self.last_line = int(number)
        word = command.split(None, 1)[0].upper() if command.strip() else b""
        if word == b"M110":
            given = _M110_NUMBER.search(command[4:])
            if given:
                self.last_line = int(given[1])
        elif word == b"M105":
            return M105_OK
        elif word == b"M115":
            return M115_REPLY
        return b"ok\n"


def serve(master: int, responder: Responder) -> None:
    while True:
        select.select([master], [], [])
        try:
            packet = os.read(master, 65536)
        except BlockingIOError:
            continue
        _write_reply(master, _answer_packet(responder, packet))


def _write_reply(master: int, reply: bytes) -> None:
    if not reply:
        return
    try:
        os.write(master, reply)
    except OSError as error:
        # Nobody reads the port and its buffer is full: the bytes are lost, as on a wire nobody
        # listens to (a host never streams without reading).
        if error.errno not in (errno.EAGAIN, errno.EIO):
            raise


def _answer_packet(responder: Responder, packet: bytes) -> bytes:
    if packet and packet[0] == _TIOCPKT_DATA:
        return responder.receive(packet[1:])
    if packet and packet[0] & _TIOCPKT_FLUSHREAD:
        return responder.reset()
    return b""


async def serve_on_trio(master: int, responder: Responder) -> None:
    """The same loop on trio, waiting for the pty as the emulator does (link/direct_wait.py):
    what the least a printer on trio pays per command costs beside `serve`."""
    readable = DirectWait(master)
    while True:
        await readable.readable()
        try:
            packet = os.read(master, 65536)
        except BlockingIOError:
            continue
        _write_reply(master, _answer_packet(responder, packet))


async def _serve_on_trio_until_signalled(master: int) -> None:
    with trio.open_signal_receiver(signal.SIGTERM, signal.SIGHUP, signal.SIGINT) as signals:
        async with trio.open_nursery() as nursery:
            nursery.start_soon(serve_on_trio, master, Responder())
            async for _ in signals:
                nursery.cancel_scope.cancel()


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if args not in ([], ["--trio"]):
        print("usage: python -m fake_marlin.emulator.bench.responder [--trio]", file=sys.stderr)
        return 2
    on_trio = args == ["--trio"]
    for signum in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT):
        signal.signal(signum, _stop)
    master, slave = os.openpty()
    try:
        tty.setraw(slave)  # bytes pass as they are, as on a USB serial adapter
        # Packet mode tells us when a host opens the port (it flushes its input); keeping our own
        # slave fd open keeps the master readable while no host has the port open.
        fcntl.ioctl(master, termios.TIOCPKT, struct.pack("i", 1))
        os.set_blocking(master, False)
        print(os.ttyname(slave), flush=True)
        if on_trio:
            trio.run(_serve_on_trio_until_signalled, master)
        else:
            serve(master, Responder())
    except (_Stop, KeyboardInterrupt):
        pass
    finally:
        os.close(master)
        os.close(slave)
    return 0


if __name__ == "__main__":
    sys.exit(main())
