# One farm node: M virtual printers on consecutive TCP ports (see docs/farm.md).
#   docker build -t fake-marlin .
#   docker run --rm -p 9000-9019:9000-9019 fake-marlin
# Each printer is then socket://DOCKER_HOST:9000 ... :9019.
#
# With no network in the build: put wheels of the dependencies (and setuptools) in wheels/ and
# build with --build-arg OFFLINE=1, which installs from them alone (what the test suite does:
# tests/hosts/docker.py). Without wheels/ the dependencies come from the package index.
FROM python:3.11-slim

# .dockerignore lets in only what the package is built from (fake_marlin/ and the folders its
# symlinks point to) and wheels/.
WORKDIR /src
COPY . ./
ARG OFFLINE=
RUN pip install --no-cache-dir --disable-pip-version-check --root-user-action=ignore \
        $(test -d wheels && echo --find-links wheels) ${OFFLINE:+--no-index} . \
    && rm -rf /src

WORKDIR /
# Printers need no privileges; fake-marlin exits cleanly on SIGTERM (docker stop).
USER nobody
EXPOSE 9000-9019
ENTRYPOINT ["fake-marlin"]
# 0.0.0.0 inside the container, so that the published ports reach the printers. Override the
# whole command to change M, the first port, the first printer number (--first-number, so that
# printers of different containers differ in UUID, serial and name) or the printers' settings.
CMD ["--printers", "20", "--tcp", "0.0.0.0:9000", "--protocol", "marlin"]
