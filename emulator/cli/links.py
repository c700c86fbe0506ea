"""`fake-marlin --tcp` and `--rfc2217`: which link each printer gets, for emulator/cli/printers.py.

    add_link_arguments(parser)          # --tcp [HOST:]PORT | --rfc2217 [HOST:]PORT
    check_link_arguments(parser, args)  # after parse_args: options that need a pty
    link = make_link(plan.tcp, plan.rfc2217)   # a TcpLink, an Rfc2217Link, or None (a pty)

Printer n of --printers listens on PORT + n - 1 (PORT 0: each its own free port; the farm's
copies() gives each its address); its `path`, printed as the pty's is, is the URL a host opens
(socket://HOST:PORT, rfc2217://HOST:PORT). make_link binds at once, so a taken port is a
LinkError (say it and exit 2) before anything else starts.
"""

import argparse
import ipaddress
from dataclasses import dataclass

from fake_marlin.emulator.link.rfc2217 import Rfc2217Link
from fake_marlin.emulator.link.tcp import LinkError, TcpLink

DEFAULT_HOST = "127.0.0.1"  # only this machine, unless a host (0.0.0.0: every interface) is given

__all__ = [
    "Address", "LinkError", "add_link_arguments", "check_link_arguments", "make_link", "tcp_address",
]


@dataclass(frozen=True)
class Address:
    """Where a printer listens: HOST and PORT (0: a free port, chosen when it binds)."""

    host: str
    port: int

    def plus(self, offset: int) -> "Address":
        """The address of the printer `offset` places on: the next ports (or each a free one)."""
        return Address(self.host, self.port + offset if self.port else 0)


def tcp_address(text: str) -> Address:
    """[HOST:]PORT as (host, port): `8099`, `0.0.0.0:8099`, `localhost:0`, `[::1]:8099`."""
    expected = f"expected [HOST:]PORT, e.g. 8099 or 0.0.0.0:8099 ([::1]:8099 in IPv6), got {text!r}"
    host, colon, port = text.rpartition(":")
    if not colon:
        host = DEFAULT_HOST
    elif host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an IPv6 address: {host!r} in {text!r}") from None
    elif not host or ":" in host or "[" in host or "]" in host:
        raise argparse.ArgumentTypeError(expected)  # (a bare IPv6 address needs its brackets)
    if not (port.isascii() and port.isdigit()) or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(
            f"the port must be a number from 0 (any free port) to 65535, got {port!r} in {text!r}"
        )
    return Address(host, int(port))


def add_link_arguments(parser: argparse._ActionsContainer) -> None:
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--tcp", metavar="[HOST:]PORT", type=tcp_address,
        help="serve the printer on a TCP port (raw bytes, as ser2net does) instead of a pty, and "
        "print socket://HOST:PORT; HOST defaults to 127.0.0.1, PORT 0 picks a free port; "
        "with several printers, consecutive ports",
    )
    group.add_argument(
        "--rfc2217", metavar="[HOST:]PORT", type=tcp_address,
        help="the same over RFC 2217 (pyserial's rfc2217://HOST:PORT): the host's baud rate "
        "is known and a DTR pulse resets the printer",
    )


def check_link_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Options that make sense only with a pty."""
    network = "--tcp" if args.tcp else "--rfc2217" if args.rfc2217 else None
    if network and getattr(args, "link", None):
        parser.error(f"argument --link: there is no pty to link to with {network}")


def make_link(tcp: Address | None, rfc2217: Address | None) -> TcpLink | None:
    """The link for a printer served on TCP or RFC 2217, bound and listening; None: the
    default pty. Raises LinkError when it cannot listen (the port is taken, past 65535, an
    unknown host)."""
    if tcp is not None:
        return TcpLink(tcp.host, tcp.port)
    if rfc2217 is not None:
        return Rfc2217Link(rfc2217.host, rfc2217.port)
    return None
