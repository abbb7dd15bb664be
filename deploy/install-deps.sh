#!/usr/bin/env bash
# Installs the Debian packages texsyn needs, only those that are missing.
# Called by `make test`, `make demo`, `make bench`, `make test-deploy` and
# .ci/run; safe to rerun.
set -euo pipefail

PACKAGES=(
  build-essential pkg-config
  libopenimageio-dev openimageio-tools # image I/O (OpenImageIO) + oiiotool for tests
  libopencv-video-dev                  # optical flow (OpenCV's DIS) for texsyn flicker and video:
                                       # libtexsyn-flow.so, common/flow_cv.cpp
  libgdal-dev gdal-bin                 # GIS rasters and vectors (GDAL): GeoTIFF/COG class maps and
                                       # outputs, vector line layers; libtexsyn-gis.so, common/gis/;
                                       # gdalinfo for the tests
  libmodbus-dev mbpoll                 # Modbus TCP monitoring plane; mbpoll reads it in tests
  libsodium-dev                        # HMAC-SHA-256 connection authentication
  libmicrohttpd-dev                    # the operations page (texsyn-server --http)
  chromium python3-prometheus-client   # its tests: a headless browser, Prometheus' parser,
  openssl                              # and a self-signed certificate for its HTTPS
  libcmocka-dev                        # unit tests
  python3-pytest                       # integration tests
  man-db groff-base                    # make install's man pages; test_manual.py renders them
  valgrind                             # make test-valgrind
  clang                                # libFuzzer targets (make fuzz; 20 s each in make test)
  iproute2 nftables                    # network partitions in namespaces (test_partitions.py, make soak)
)
# Plots for `make bench` (bench/gnuplot.py); bench/netem.py's namespaces and
# RTT check.
[ "${1:-}" = "--bench" ] && PACKAGES+=(gnuplot-nox iproute2 iputils-ping)
# `make test-deploy` only: a single-node Slurm, systemd-analyze, the
# manifests' checks (python3-kubernetes' models; npm for kubernetes-models).
# Node and npm from Debian unless there already are (NodeSource's nodejs
# holds npm and conflicts with Debian's).
if [ "${1:-}" = "--deploy" ]; then
  PACKAGES+=(slurmctld slurmd slurm-client munge systemd python3-yaml python3-kubernetes)
  command -v node > /dev/null || PACKAGES+=(nodejs)
  command -v npm > /dev/null || PACKAGES+=(npm)
fi

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0

echo "install-deps: installing ${missing[*]}"
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
