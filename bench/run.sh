#!/usr/bin/env bash
# `make bench`: writes bench/results/ - kernel throughput per SIMD variant
# next to the measured memory bandwidth, the seed's Table 3.3 job, quality
# figures and example pictures. Every figure of one run is measured side by
# side on the same machine; medians of repeated runs.
# texsyn stylize against Ebsynth runs only when TEXSYN_EBSYNTH names the peer's
# binary (../shared/peers/build-ebsynth.sh DIR builds DIR/ebsynth).
# Usage: [TEXSYN_EBSYNTH=PATH] bench/run.sh BUILD_DIR [--quick]
set -euo pipefail
build=${1:-build}; shift || true
cd "$(dirname "$0")/.."
out=bench/results
mkdir -p "$out"
bash deploy/install-deps.sh --bench
{
  echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ //'), $(nproc) cores"
  # The model name of a cloud CPU can hide its generation (AMD EPYC: family
  # 25 is Zen 3/4, which splits 512-bit ops in two; family 26 is Zen 5).
  echo "cpu: family $(grep -m1 '^cpu family' /proc/cpuinfo | cut -d: -f2 | tr -d ' ')," \
    "model $(grep -m1 '^model[[:space:]]*:' /proc/cpuinfo | cut -d: -f2 | tr -d ' ')," \
    "flags: $(grep -m1 '^flags' /proc/cpuinfo | grep -oE 'avx512bw|avx512_vnni|avx2' | sort -u | tr '\n' ' ')"
  echo "date: $(date -u +%Y-%m-%dT%H:%MZ)"
  echo "commit: $(git rev-parse --short HEAD 2>/dev/null || echo unknown)"
} > "$out/machine.txt"
echo "== kernels"
"$build"/bench/bench_kernels --csv "$out/kernels.csv" "$@" | tee "$out/kernels.txt"
echo "== Table 3.3 job and quality"
/usr/bin/python3 bench/table33.py --build "$build" --out "$out" "$@"
echo "== the copy-map shortcut on the Table 3.3 job"
/usr/bin/python3 bench/copy_accel.py --build "$build" --out "$out" "$@"
echo "== texture mixing pictures"
/usr/bin/python3 bench/mix.py --build "$build" --out "$out" "$@"
echo "== lossy LBG partitioning against the exact search"
/usr/bin/python3 bench/lbg.py --build "$build" --out "$out" "$@"
echo "== cluster overhead"
/usr/bin/python3 bench/cluster.py --build "$build" --out "$out" "$@"
echo "== bytes on the wire per query"
/usr/bin/python3 bench/wire.py --build "$build" --out "$out" "$@"
echo "== answer times under load"
/usr/bin/python3 bench/latency.py --build "$build" --out "$out" "$@"
echo "== a stylization sequence against separate jobs"
/usr/bin/python3 bench/sequence.py --build "$build" --out "$out" "$@"
echo "== texture segmentation: accuracy and time"
/usr/bin/python3 bench/segment.py --build "$build" --out "$out" "$@"
echo "== the operations page: screenshot during a job, answer times"
/usr/bin/python3 bench/ops_page.py --build "$build" --out "$out" "$@"
echo "== stylize against Ebsynth"
if [ -n "${TEXSYN_EBSYNTH:-}" ] && [ -x "$TEXSYN_EBSYNTH" ]; then
  /usr/bin/python3 bench/stylize.py --build "$build" --out "$out" --ebsynth "$TEXSYN_EBSYNTH" "$@"
else
  echo "skipped: no Ebsynth binary; build it with ../shared/peers/build-ebsynth.sh DIR and run" \
    "TEXSYN_EBSYNTH=DIR/ebsynth make bench"
fi
