"""`--web [HOST:]PORT`: the live view (emulator/web/) started beside the printers, its address
said on stderr (standard output is the printers' paths, which hosts read)."""

import sys

import trio

from fake_marlin.emulator.cli.links import Address


class WebUnavailable(Exception):
    """The live view cannot be served (its port is taken, say): the message says why."""


async def start_web(nursery: trio.Nursery, address: Address, source) -> str:
    """Serve the live view of `source` (a web.source.FarmSource) in `nursery`; its URL."""
    from fake_marlin.emulator.web.app import serve_web

    try:
        url: str = await nursery.start(serve_web, address.host, address.port, source)
    except OSError as error:
        raise WebUnavailable(error.strerror or str(error)) from None
    print(f"fake-marlin: live view at {url}", file=sys.stderr, flush=True)
    return url


def said(group: BaseExceptionGroup) -> int:
    """`except* WebUnavailable`: say why on stderr, as every start-up problem is; exit code 2."""
    for error in group.exceptions:
        print(f"fake-marlin: {error}", file=sys.stderr)
    return 2

