"""The trio client for Ultimaker's binary protocol: the shared shell around the go-back-N core
(fake_marlin.host.cores.ultimaker)."""

from fake_marlin.host.codecs.ultimaker import check_command
from fake_marlin.host.cores.ultimaker import UltimakerCore
from fake_marlin.wire.ultimaker_variants import variants_of
from fake_marlin.host.shell import ClientOptions, StreamingClient


class UltimakerClient(StreamingClient):
    protocol = "ultimaker"
    check_command = staticmethod(check_command)

    def _open(self, options: ClientOptions) -> None:
        self._core = UltimakerCore(
            window=options.window,
            timeout=options.timeout,
            long_timeout=options.long_timeout,
            received_timeout=options.received_timeout,
            max_transmissions=options.max_transmissions,
            variants=variants_of(options.variants),
        )
