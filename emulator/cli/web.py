"""`--web [HOST:]PORT`: the live view (emulator/web/) started beside the printers, its address
said on stderr (standard output is the printers' paths, which hosts read)."""

import sys

import trio

from fake_marlin.emulator.cli.links import Address


async def start_web(nursery: trio.Nursery, address: Address, source) -> str:
    """Serve the live view of `source` (a web.source.FarmSource) in `nursery`; its URL."""
    from fake_marlin.emulator.web.app import serve_web

    url: str = await nursery.start(serve_web, address.host, address.port, source)
    print(f"fake-marlin: live view at {url}", file=sys.stderr, flush=True)
    return url
