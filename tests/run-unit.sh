#!/usr/bin/env bash
# Runs every cmocka test of every unit-test binary in its own process, with a
# timeout (scaled by TEXSYN_TEST_TIMEOUT_MULTIPLIER for slow or sanitized
# builds). Prints one line per test and a closing "N passed, N failed" line.
# Usage: tests/run-unit.sh BUILD_DIR
set -u
build=${1:-build}
mult=${TEXSYN_TEST_TIMEOUT_MULTIPLIER:-1}
timeout_s=$((120 * mult))
pass=0; fail=0; failed=()
logdir=$(mktemp -d)
for bin in "$build"/tests/test_*; do
  [ -x "$bin" ] || continue
  for name in $("$bin" --list); do
    log="$logdir/$(basename "$bin").$name.log"
    # TEXSYN_TEST_WRAPPER (e.g. valgrind ...) runs each test under a tool.
    if timeout "$timeout_s" ${TEXSYN_TEST_WRAPPER:-} "$bin" "$name" >"$log" 2>&1 && grep -q "PASSED" "$log" && ! grep -q "FAILED" "$log"; then
      pass=$((pass + 1)); echo "ok   $(basename "$bin") $name"
    else
      fail=$((fail + 1)); failed+=("$(basename "$bin") $name")
      echo "FAIL $(basename "$bin") $name"; sed 's/^/     | /' "$log"
    fi
  done
done
rm -rf "$logdir"
echo "unit ($build): $pass passed, $fail failed"
[ "$fail" -eq 0 ]
