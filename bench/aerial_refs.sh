#!/usr/bin/env bash
# Cuts the reference textures of an aerial catalogue (seed 002 §5.1) out of
# aero1.jpg, the 640x480 oblique colour aerial photograph of the test data,
# and writes OUTDIR/catalogue.json beside them (the format of
# server/cli/catalogue.h). The class ids are bench/mkscene's: 1 forest,
# 2 water, 3 town, 4 sand; the line colours are for mkscene's road raster
# (255 roads, 128 paths). Together they make a complete aerial input:
#
#   build/bench/mkscene --size 1024 --seed 7 -o demo/scene
#   bench/aerial_refs.sh demo
#
# demo/catalogue.json then names forest.png ... and, as its line raster,
# scene-roads.png (--roads NAME names another, relative to OUTDIR).
#
# Each box is the largest rectangle found, by looking at the photograph
# enlarged, that holds one land-use class only. The photograph is hazy, so
# every colour is lifted towards grey; that is the catalogue's look, as the
# seed notes for its own references (colour casts are reproduced).
#
# --grow N grows every crop into an N x N reference with texsyn synth (3
# levels, colour search, the usage penalty against repeats): a catalogue of
# the size one cut from a real orthophoto would have - a forest stand at
# 1 m/pixel is hundreds of pixels across, while the photograph's clean
# rectangles are 32 to 104 pixels high. The scan per query grows with the
# reference, so this is the catalogue of the scaling benchmark's large
# aerial job (bench/scaling.py). --texsyn PATH names the binary (default
# build/texsyn).
# Usage: bench/aerial_refs.sh OUTDIR [--roads NAME] [--grow N [--texsyn PATH]]
set -euo pipefail
usage() {
  echo "usage: $0 OUTDIR [--roads NAME] [--grow N [--texsyn PATH]]  (NAME: the line raster, relative to OUTDIR)" >&2
  exit 2
}
[ $# -ge 1 ] || usage
out=$1; shift
roads=scene-roads.png
grow=0
here=$(cd "$(dirname "$0")/.." && pwd)
texsyn=$here/build/texsyn
while [ $# -gt 0 ]; do
  case "$1" in
  --roads) [ $# -ge 2 ] || usage; roads=$2; shift 2 ;;
  --grow) [ $# -ge 2 ] && [[ $2 =~ ^[1-9][0-9]{1,3}$ ]] || usage; grow=$2; shift 2 ;;
  --texsyn) [ $# -ge 2 ] || usage; texsyn=$2; shift 2 ;;
  *) usage ;;
  esac
done
case "$roads" in *'"'* | *'\'*) echo "$0: --roads $roads: no quotes or backslashes in the name" >&2; exit 2 ;; esac
[ "$grow" -eq 0 ] || [ -x "$texsyn" ] || { echo "$0: --grow needs texsyn: $texsyn is missing (make, or --texsyn PATH)" >&2; exit 1; }
data=$(bash "$here/tests/test-data.sh" aerial/aero1.jpg)
photo=$data/aerial/aero1.jpg
command -v oiiotool >/dev/null || { echo "$0: oiiotool is missing (apt-get install openimageio-tools)" >&2; exit 1; }
mkdir -p "$out"

# name  box (WxH+X+Y in aero1.jpg)  what the box shows
crops=(
  # Dense mixed forest, bottom right: closed dark green canopy, no clearing,
  # below the industrial strip and right of the sand pit.
  "forest 112x68+528+308"
  # The pond at the bottom: calm dark grey-blue water. It is the only dark
  # water in the picture, and its largest clean rectangle is this small; the
  # lakes at the top are washed out by glare and haze to near white.
  "water 80x32+192+432"
  # Apartment blocks of the upper left: five- to nine-storey slabs and
  # towers with courtyard trees and streets; a structured texture.
  "town 160x104+64+128"
  # The sand pit, bottom right: bare light-brown ground with tyre tracks,
  # between the forest above and the grass at the right edge.
  "sand 96x52+476+424"
)
for c in "${crops[@]}"; do
  read -r name box <<<"$c"
  oiiotool "$photo" --cut "$box" -o "$out/$name.png"
  if [ "$grow" -gt 0 ]; then
    mv "$out/$name.png" "$out/$name-crop.png"
    "$texsyn" synth --ref "$out/$name-crop.png" --size "${grow}x$grow" --levels 3 --rgb-search --usage-weight 1 \
      --seed 7 --quiet -o "$out/$name.png"
  fi
done

# Roads: the main road's surface in the middle of the photograph averages
# (182, 179, 187) - asphalt lifted by the haze; paths: the sandy tracks at
# the lower left, (188, 172, 160).
cat >"$out/catalogue.json" <<EOF
{"classes": [
   {"id": 1, "name": "forest", "reference": "forest.png", "kind": "stochastic", "usage_weight": 1.0},
   {"id": 2, "name": "water",  "reference": "water.png",  "kind": "stochastic", "usage_weight": 1.0},
   {"id": 3, "name": "town",   "reference": "town.png",   "kind": "structured", "usage_weight": 0.2},
   {"id": 4, "name": "sand",   "reference": "sand.png",   "kind": "stochastic", "usage_weight": 1.0}],
 "lines": {"raster": "$roads", "colours": {"255": [182, 179, 187], "128": [188, 172, 160]}}}
EOF
echo "$out: forest.png water.png town.png sand.png catalogue.json (lines: $roads)"
