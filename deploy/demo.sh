#!/usr/bin/env bash
# `make demo`: an embedded synthesis of a real texture - the seed's Table 3.3
# job (brick.png 512x512 -> 1024x1024, L=5, W_N=7, W_B=3, parity on) - with
# the copy map, usage map and report next to it in demo/.
# The texture comes from tests/test-data.sh: ../shared/data, or on a machine
# without it Debian's python3-skimage package (CC0 scikit-image sample data).
set -euo pipefail
build=${1:-build}
cd "$(dirname "$0")/.."
ref=$(bash tests/test-data.sh textures/brick.png)/textures/brick.png
mkdir -p demo
"$build"/texsyn synth --ref "$ref" -o demo/brick-1024.png --size 1024x1024 \
  --levels 5 --wn 7 --wb 3 --parity --threads "$(nproc)" \
  --copy-map demo/brick-1024-copymap.png --usage-map demo/brick-1024-usage.png \
  --report demo/brick-1024.json
echo "demo: wrote demo/brick-1024.png (and copy map, usage map, report) from $ref"
