#!/usr/bin/env bash
# Runs every cmocka test of every unit-test binary in its own process, with a
# timeout (scaled by TEXSYN_TEST_TIMEOUT_MULTIPLIER for slow or sanitized
# builds), TEXSYN_TEST_JOBS (default: the CPUs) at a time. Prints one line
# per test, in a fixed order ("SKIP tests/unit/FILE.c::TEST: REASON" for a
# test that skipped itself, the reason from its "skipped: " line),
# and a closing "N passed, N failed, N skipped" line. The test images come
# from tests/test-data.sh (TEXSYN_DATA).
# Usage: tests/run-unit.sh BUILD_DIR
set -u
build=${1:-build}
TEXSYN_DATA=$(bash "$(dirname "$0")/test-data.sh") || exit 1
export TEXSYN_DATA
# The test binaries sit in BUILD/tests/, not next to the image library.
export TEXSYN_IMAGE_LIB=$(cd "$build" && pwd)/libtexsyn-image.so
export TEXSYN_FLOW_LIB=$(cd "$build" && pwd)/libtexsyn-flow.so
export TEXSYN_GIS_LIB=$(cd "$build" && pwd)/libtexsyn-gis.so
mult=${TEXSYN_TEST_TIMEOUT_MULTIPLIER:-1}
export timeout_s=$((120 * mult))
logdir=$(mktemp -d)
export logdir
list="$logdir/list"
for bin in "$build"/tests/test_*; do
  [ -x "$bin" ] || continue
  for name in $("$bin" --list); do echo "$bin $name"; done
done >"$list"
# One test: its output to <binary>.<test>.log, its verdict to .ok or .fail.
# TEXSYN_TEST_WRAPPER (e.g. valgrind ...) runs each test under a tool.
run_one() {
  local bin=$1 name=$2 log
  log="$logdir/$(basename "$bin").$name"
  if timeout "$timeout_s" ${TEXSYN_TEST_WRAPPER:-} "$bin" "$name" >"$log.log" 2>&1 &&
    grep -q "PASSED" "$log.log" && ! grep -q "FAILED" "$log.log"; then
    if grep -q "SKIPPED" "$log.log"; then touch "$log.skip"; else touch "$log.ok"; fi
  fi
}
export -f run_one
xargs -P "${TEXSYN_TEST_JOBS:-$(nproc)}" -L 1 bash -c 'run_one "$0" "$1"' <"$list"
pass=0; fail=0; skip=0
while read -r bin name; do
  log="$logdir/$(basename "$bin").$name"
  if [ -e "$log.ok" ]; then
    pass=$((pass + 1)); echo "ok   $(basename "$bin") $name"
  elif [ -e "$log.skip" ]; then
    skip=$((skip + 1))
    why=$(sed -n 's/^skipped: //p' "$log.log" | head -n 1)
    echo "SKIP tests/unit/$(basename "$bin").c::$name: ${why:-no reason given (ts_test_skip says one)}"
    sed 's/^/     | /' "$log.log"
  else
    fail=$((fail + 1)); echo "FAIL $(basename "$bin") $name"; sed 's/^/     | /' "$log.log"
  fi
done <"$list"
rm -rf "$logdir"
echo "unit ($build): $pass passed, $fail failed, $skip skipped"
[ "$fail" -eq 0 ]
