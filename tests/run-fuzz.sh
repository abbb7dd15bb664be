#!/usr/bin/env bash
# The libFuzzer targets (tests/fuzz/fuzz_*.c) in the suite, two ways:
#
#   tests/run-fuzz.sh replay BUILD_DIR   feeds every committed seed and crash
#       regression (tests/fuzz/{seeds,regress}/<target>) once to each target,
#       built by the normal compiler as BUILD_DIR/tests/replay_<target>
#   tests/run-fuzz.sh fuzz SECONDS [SEED]  runs each libFuzzer build (make
#       fuzz-build, clang) for SECONDS on build-fuzz/corpus-<target>, one
#       target at a time, single process; findings go to build-fuzz/artifacts/.
#       With a SEED the mutations are the same on every run (the suite
#       passes one, so a clean clone tries the same inputs each time, up to
#       how many fit in the time); without, each run explores new ones.
#
# One line per target and a closing "N passed, N failed" line.
set -u
cd "$(dirname "$0")/.."
mode=${1:-}
targets=$(sed -n "s/^FUZZ_TARGETS = //p" Makefile) # declared once, in the Makefile
pass=0; fail=0
inputs() { # the committed inputs of target $1 that exist
  local d
  for d in tests/fuzz/seeds/$1 tests/fuzz/regress/$1; do [ -d "$d" ] && echo "$d"; done
}
report() { # target ok(0/1) log
  if [ "$2" -eq 0 ]; then
    pass=$((pass + 1)); echo "ok   $1 $(tail -n 1 "$3")"
  else
    fail=$((fail + 1)); echo "FAIL $1"; tail -n 40 "$3" | sed 's/^/     | /'
  fi
}
# OpenImageIO's PNG reader leaks a string when libpng longjmps out of a
# truncated file (tests/lsan.supp explains); only the slow unwinder sees the
# frame the suppression names, so the image target gets it. Other leaks
# still fail.
export LSAN_OPTIONS="suppressions=$PWD/tests/lsan.supp"
asan_for() { # ASAN_OPTIONS for target $1: the caller's when replaying,
  # libFuzzer's defaults when fuzzing (the slow unwinder costs ~10x speed)
  local o=${ASAN_OPTIONS:-}
  [ "$mode" = fuzz ] && o=""
  [ "$1" = image ] && o="${o:+$o:}fast_unwind_on_malloc=0"
  echo "$o"
}
log=$(mktemp)
case "$mode" in
replay)
  build=${2:-build}
  # The replay binaries sit in BUILD/tests/, not next to the image library
  # (the libFuzzer builds find theirs next to them).
  export TEXSYN_IMAGE_LIB=$(cd "$build" && pwd)/libtexsyn-image.so
  for t in $targets; do
    bin=$build/tests/replay_$t
    if [ ! -x "$bin" ]; then
      echo "$bin is missing: run make" >"$log"; report "$t" 1 "$log"; continue
    fi
    # shellcheck disable=SC2046
    ASAN_OPTIONS=$(asan_for "$t") timeout 300 "$bin" $(inputs "$t") >"$log" 2>&1; report "$t" $? "$log"
  done
  echo "fuzz replay ($build): $pass passed, $fail failed"
  ;;
fuzz)
  secs=${2:-30}
  seed=${3:+-seed=$3}
  mkdir -p build-fuzz/artifacts
  for t in $targets; do
    bin=build-fuzz/fuzz_$t
    mkdir -p "build-fuzz/corpus-$t"
    if [ ! -x "$bin" ]; then
      echo "$bin is missing: run make fuzz-build" >"$log"; report "$t" 1 "$log"; continue
    fi
    start=$(date +%s)
    # shellcheck disable=SC2046
    ASAN_OPTIONS=$(asan_for "$t") "$bin" $seed -max_total_time="$secs" -timeout=30 -rss_limit_mb=2560 -print_final_stats=1 \
      -artifact_prefix="build-fuzz/artifacts/$t-" "build-fuzz/corpus-$t" $(inputs "$t") >"$log" 2>&1
    rc=$?
    runs=$(grep -oE 'stat::number_of_executed_units: *[0-9]+' "$log" | grep -oE '[0-9]+$')
    echo "${runs:-?} runs in $(( $(date +%s) - start )) s, corpus $(ls "build-fuzz/corpus-$t" | wc -l)" >>"$log"
    report "$t" $rc "$log"
  done
  echo "fuzz (${secs} s per target): $pass passed, $fail failed"
  ;;
*)
  echo "usage: $0 replay BUILD_DIR | fuzz SECONDS [SEED]" >&2; rm -f "$log"; exit 2 ;;
esac
rm -f "$log"
[ "$fail" -eq 0 ]
