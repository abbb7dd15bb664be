#!/usr/bin/env bash
# `make bench` (quick, under 10 minutes on 2 cores) and `make bench-full`
# (everything, full sizes and repetitions): runs the benchmark scripts, each
# writing its tables (.md/.json) and plots (.png, gnuplot) into
# bench/results/, stamps each one's date and commit, and assembles
# bench/results/RESULTS.md (bench/results_md.py).
#   quick: kernels + roofline, Table 3.3 column by column, scaling over
#          1, 2, 4 and 16 workers (aerial 2048^2), cluster overhead, the
#          copy-map shortcut, LBG; the rest keep the figures of their
#          last run, marked with its date and commit in RESULTS.md;
#   full:  all of it at full size, plus the cluster under added network
#          latency (bench/netem.py, root; also `make bench-netem`), wire,
#          latency, sequence, segmentation, aerial scenes, mixing pictures,
#          the operations page, and the blend between video keys.
# texsyn stylize against Ebsynth runs (in both modes) only when
# TEXSYN_EBSYNTH names the peer's binary (../shared/peers/build-ebsynth.sh DIR
# builds DIR/ebsynth); in full mode so does texsyn video against it.
# Usage: [TEXSYN_EBSYNTH=PATH] bench/run.sh BUILD_DIR [--quick|--full]
set -euo pipefail
build=${1:-build}; shift || true
mode=quick
case "${1:-}" in
--quick) mode=quick; shift ;;
--full) mode=full; shift ;;
"") ;;
*) echo "usage: $0 BUILD_DIR [--quick|--full]" >&2; exit 2 ;;
esac
quick=()
[ "$mode" = quick ] && quick=(--quick)
cd "$(dirname "$0")/.."
out=bench/results
mkdir -p "$out"
bash deploy/install-deps.sh --bench
start=$SECONDS

# step NAME CMD...: runs one benchmark, then stamps NAME's results as made now.
step() {
  local name=$1; shift
  local t0=$SECONDS
  echo "== $name"
  "$@"
  /usr/bin/python3 bench/results_md.py --out "$out" --stamp "$name" --mode "$mode"
  echo "== $name: $((SECONDS - t0)) s"
}
py() { /usr/bin/python3 "bench/$1" --build "$build" --out "$out" "${quick[@]}"; }
kernels() {
  "$build"/bench/bench_kernels --csv "$out/kernels.csv" "${quick[@]}" | tee "$out/kernels.txt"
  /usr/bin/python3 bench/roofline.py --out "$out"
}

step roofline kernels
step table33 py table33.py
step scaling py scaling.py
step cluster py cluster.py
step copy_accel py copy_accel.py
step lbg py lbg.py
if [ "$mode" = full ]; then
  step netem /usr/bin/python3 bench/netem.py --build "$build" --out "$out"
  step wire py wire.py
  step latency py latency.py
  step sequence py sequence.py
  step segment py segment.py
  step aerial py aerial.py
  step mix py mix.py
  step ops_page py ops_page.py
  step video_blend env TEXSYN_BUILD="$build" /usr/bin/python3 bench/video_blend.py --out "$out/video-blend"
  step bigtiff /usr/bin/python3 bench/bigtiff.py --build "$build" --out "$out"
fi
if [ -n "${TEXSYN_EBSYNTH:-}" ] && [ -x "$TEXSYN_EBSYNTH" ]; then
  step stylize /usr/bin/python3 bench/stylize.py --build "$build" --out "$out" --ebsynth "$TEXSYN_EBSYNTH" \
    "${quick[@]}"
  if [ "$mode" = full ]; then
    step video /usr/bin/python3 bench/video.py --build "$build" --out "$out" --ebsynth "$TEXSYN_EBSYNTH" --pool
  fi
else
  echo "== stylize against Ebsynth skipped: no Ebsynth binary; build it with ../shared/peers/build-ebsynth.sh DIR" \
    "and run TEXSYN_EBSYNTH=DIR/ebsynth make bench"
fi
/usr/bin/python3 bench/results_md.py --out "$out"
echo "== bench ($mode): $((SECONDS - start)) s"
