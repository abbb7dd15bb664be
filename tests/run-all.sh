#!/usr/bin/env bash
# The whole suite, as `make test` runs it: unit tests (each test in its own
# process) on the normal build, integration tests driving the real binaries,
# then the unit tests and a short integration subset under ASan+UBSan; the
# fuzz targets' seeds and crash regressions replayed on both builds; each
# libFuzzer target for TEXSYN_FUZZ_SECONDS (10) seconds.
# Ends with one "N passed, N failed" line over everything.
set -u
cd "$(dirname "$0")/.."
total_pass=0; total_fail=0
tally() { # reads a runner's closing "... N passed, N failed" line
  local line; line=$(grep -E '[0-9]+ passed' "$1" | tail -n 1)
  local p f
  p=$(echo "$line" | grep -oE '[0-9]+ passed' | grep -oE '[0-9]+' || echo 0)
  f=$(echo "$line" | grep -oE '[0-9]+ failed' | grep -oE '[0-9]+' || echo 0)
  total_pass=$((total_pass + ${p:-0})); total_fail=$((total_fail + ${f:-0}))
}
log=$(mktemp)
status=0
stage() { # runs one runner, tallies its closing line, says how long it took
  local t0=$SECONDS
  "$@" | tee "$log"; [ "${PIPESTATUS[0]}" -eq 0 ] || status=1; tally "$log"
  echo "(stage took $((SECONDS - t0)) s)"
}
stage bash tests/run-unit.sh build
stage bash tests/run-fuzz.sh replay build
stage bash tests/run-integration.sh build
# The fast unwinder (ASan's default): the slow one made the sanitized stages
# a fifth slower, and no report needs it (tests/lsan.supp).
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
export LSAN_OPTIONS="suppressions=$PWD/tests/lsan.supp"
TEXSYN_TEST_TIMEOUT_MULTIPLIER=4 stage bash tests/run-unit.sh build-asan
stage bash tests/run-fuzz.sh replay build-asan
TEXSYN_SANITIZED=1 stage bash tests/run-integration.sh build-asan -m sanitize
# Each libFuzzer target for a bounded time (make fuzz-build; clang).
stage bash tests/run-fuzz.sh fuzz "${TEXSYN_FUZZ_SECONDS:-10}" "${TEXSYN_FUZZ_SEED:-2004}"
rm -f "$log"
if [ $status -ne 0 ] && [ $total_fail -eq 0 ]; then total_fail=1; fi
echo "all tests: $total_pass passed, $total_fail failed"
exit $status
