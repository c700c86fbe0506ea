# One farm node: M virtual printers on consecutive TCP ports (see docs/farm.md).
#   docker build -t fake-marlin .
#   docker run --rm -p 9000-9007:9000-9007 fake-marlin
# Each printer is then socket://DOCKER_HOST:9000 ... :9007.
FROM python:3.11-slim

WORKDIR /src
# Only what the package is built from: fake_marlin/ and the folders its symlinks point to.
COPY pyproject.toml README.md ./
COPY fake_marlin ./fake_marlin
COPY emulator ./emulator
COPY host ./host
COPY wire ./wire
RUN pip install --no-cache-dir . && rm -rf /src

WORKDIR /
# Printers need no privileges; fake-marlin exits cleanly on SIGTERM (docker stop).
USER nobody
EXPOSE 9000-9007
ENTRYPOINT ["fake-marlin"]
# 0.0.0.0 inside the container, so that the published ports reach the printers. Override the
# whole command to change M, the first port or the printers' settings (keep EXPOSE and the
# published range in step with M).
CMD ["--printers", "8", "--tcp", "0.0.0.0:9000", "--protocol", "marlin"]
