#!/usr/bin/env bash
# Prints the directory of the test data, getting it first if need be.
# The tests read three public images: brick.png and grass.png (CC0
# scikit-image sample data) and aero1.jpg (OpenCV's sample data). They are
# taken from $TEXSYN_DATA, else ../shared/data; when those lack them, from
# Debian's python3-skimage and opencv-doc packages (downloaded, unpacked into
# build/test-data, not installed). Every file is checked against the hash
# the golden outputs were made from: a test never runs on other bytes.
# Exits non-zero, saying what is missing and how to get it, when it cannot.
# With arguments (paths in the data directory, e.g. textures/brick.png),
# only those files are needed: `make demo` asks for brick.png alone.
# Usage: tests/test-data.sh [FILE...]
set -euo pipefail
cd "$(dirname "$0")/.."

# path in the data directory, sha256, Debian package, path in the package
FILES=(
  "textures/brick.png 7966caf324f6ba843118d98f7a07746d22f6a343430add0233eca5f6eaaa8fcf python3-skimage ./usr/lib/python3/dist-packages/skimage/data/brick.png"
  "textures/grass.png b6b6022426b38936c43a4ac09635cd78af074e90f42ffa8227ac8b7452d39f89 python3-skimage ./usr/lib/python3/dist-packages/skimage/data/grass.png"
  "aerial/aero1.jpg d9a69191f6e3642ea361bc3c62e677b2f40fe6534b78da540f4155e0734b59ef opencv-doc ./usr/share/doc/opencv-doc/examples/data/aero1.jpg"
)
if [ $# -gt 0 ]; then
  wanted=()
  for entry in "${FILES[@]}"; do
    for f in "$@"; do [ "${entry%% *}" = "$f" ] && wanted+=("$entry"); done
  done
  [ ${#wanted[@]} -eq $# ] || { echo "test-data: not a test image: $*" >&2; exit 1; }
  FILES=("${wanted[@]}")
fi
packages=$(for entry in "${FILES[@]}"; do echo "$entry" | cut -d' ' -f3; done | sort -u | tr '\n' ' ')
packages=${packages% }

# Whether directory $1 holds every file with its hash.
complete() {
  local entry rel sum _
  for entry in "${FILES[@]}"; do
    read -r rel sum _ <<<"$entry"
    [ -f "$1/$rel" ] || return 1
    [ "$(sha256sum "$1/$rel" | cut -d' ' -f1)" = "$sum" ] || return 1
  done
}

given=${TEXSYN_DATA:-../shared/data}
if complete "$given"; then
  (cd "$given" && pwd)
  exit 0
fi

out=build/test-data
if ! complete "$out"; then
  echo "test-data: $given lacks the test images; getting them from Debian's $packages into $out" >&2
  tmp=$(mktemp -d)
  trap 'rm -rf "$tmp"' EXIT
  # apt-get download as root writes as the _apt user: a directory it can use.
  chmod 777 "$tmp"
  # shellcheck disable=SC2086 # one word per package
  (cd "$tmp" && { apt-get download -qq $packages >/dev/null 2>&1 ||
    { apt-get update -qq && apt-get download -qq $packages >/dev/null 2>&1; }; }) || {
    echo "test-data: cannot download $packages from the Debian archive." >&2
    echo "  Put brick.png and grass.png in \$TEXSYN_DATA/textures and aero1.jpg in \$TEXSYN_DATA/aerial," >&2
    echo "  or clone the project next to ../shared (its data directory has them)." >&2
    exit 1
  }
  for entry in "${FILES[@]}"; do
    read -r rel sum pkg inner <<<"$entry"
    mkdir -p "$out/$(dirname "$rel")"
    dpkg-deb --fsys-tarfile "$tmp"/"${pkg}"_*.deb | tar -xO "$inner" >"$out/$rel" || {
      echo "test-data: $pkg has no $inner" >&2
      exit 1
    }
  done
fi
if ! complete "$out"; then
  for entry in "${FILES[@]}"; do
    read -r rel sum _ <<<"$entry"
    [ "$(sha256sum "$out/$rel" 2>/dev/null | cut -d' ' -f1)" = "$sum" ] ||
      echo "test-data: $out/$rel is not the image the tests were made for (sha256 $sum)" >&2
  done
  exit 1
fi
(cd "$out" && pwd)
