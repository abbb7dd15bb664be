#!/usr/bin/env bash
# The whole suite, as `make test` runs it: unit tests (each test in its own
# process) on the normal build and under ASan+UBSan, the fuzz targets' seeds
# and crash regressions replayed on both builds, each libFuzzer target for
# TEXSYN_FUZZ_SECONDS (10) seconds beside them; then integration tests
# driving the real binaries, and a subset of them under ASan+UBSan.
# A skip is not a pass: every skipped test is listed ("SKIP FILE::TEST:
# REASON" from run-unit.sh and the integration tests' conftest), and the
# suite fails if one is not allowed by tests/skips.allow, test by test.
# Ends with one line over everything: the distinct tests, the reruns under
# the sanitizers, and how many passed, failed and skipped.
set -u
cd "$(dirname "$0")/.."
total_pass=0; total_fail=0; total_skip=0; distinct=0; reruns=0; unnamed=0
skips=$(mktemp)
count() { # "N word" out of a runner's closing line
  echo "$1" | grep -oE "[0-9]+ $2" | grep -oE '[0-9]+' || echo 0
}
tally() { # $1: the stage's log, $2: 1 when it reruns tests of an earlier stage
  local line p f s e listed
  line=$(grep -E '[0-9]+ passed' "$1" | tail -n 1)
  # pytest counts a test whose teardown failed (a daemon that crashed or
  # left a sanitizer report: conftest.check_daemons) as passed and as an
  # error: the error is a failure, not another test.
  p=$(count "$line" passed); f=$(count "$line" failed); s=$(count "$line" skipped); e=$(count "$line" error)
  total_pass=$((total_pass + p)); total_fail=$((total_fail + f + e)); total_skip=$((total_skip + s))
  if [ "$2" = 1 ]; then reruns=$((reruns + p + f + s)); else distinct=$((distinct + p + f + s)); fi
  # Each skip counted must be listed by name, or it escapes the allow-list.
  listed=$(grep -cE '^SKIP [^ ]+::' "$1")
  grep -E '^SKIP [^ ]+::' "$1" >>"$skips"
  if [ "$listed" -lt "$s" ]; then
    echo "$s tests skipped but $listed named on SKIP lines: each skip must name its test and reason"
    unnamed=$((unnamed + s - listed))
  fi
}
log=$(mktemp)
status=0
stage() { # $1: 1 for a rerun stage; then the runner; tallies it, says how long it took
  local rerun=$1 t0=$SECONDS
  shift
  "$@" | tee "$log"; [ "${PIPESTATUS[0]}" -eq 0 ] || status=1; tally "$log" "$rerun"
  echo "(stage took $((SECONDS - t0)) s)"
}
asan() { # runs "$@" with the sanitizers' options. ASan's fast unwinder: the
  # slow one made the sanitized stages a fifth slower, and no report needs
  # it (tests/lsan.supp). print_suppressions=0: a suppressed leak (OpenImageIO's,
  # for a movie) leaves stderr as the program wrote it, which tests assert on.
  ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1} \
    UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1} \
    LSAN_OPTIONS="suppressions=$PWD/tests/lsan.supp:print_suppressions=0" "$@"
}
# Each libFuzzer target for a bounded time (make fuzz-build; clang), beside
# the unit and replay stages: all are CPU-bound and untimed, a fuzz target
# takes one core for a fixed time, and the two together end when the fuzz
# runs do. Their lines follow the replay's.
fuzz_out=$(mktemp)
fuzz_t0=$SECONDS
bash tests/run-fuzz.sh fuzz "${TEXSYN_FUZZ_SECONDS:-7}" "${TEXSYN_FUZZ_SEED:-2004}" >"$fuzz_out" 2>&1 &
fuzz_pid=$!
stage 0 bash tests/run-unit.sh build
stage 0 bash tests/run-fuzz.sh replay build
stage 1 asan env TEXSYN_TEST_TIMEOUT_MULTIPLIER=4 bash tests/run-unit.sh build-asan
stage 1 asan bash tests/run-fuzz.sh replay build-asan
wait "$fuzz_pid" || status=1
tee "$log" <"$fuzz_out"; tally "$log" 0
echo "(fuzz runs took $((SECONDS - fuzz_t0)) s, beside the stages above)"
rm -f "$fuzz_out"
stage 0 bash tests/run-integration.sh build
stage 1 asan env TEXSYN_SANITIZED=1 bash tests/run-integration.sh build-asan -m sanitize
# A skip "SKIP DIR/FILE::TEST[PARAMS]: REASON" is allowed by the entry
# "FILE::TEST: REASON" (tests/skips.allow): the same file and test (any
# parameters), and the same reason, whole.
allowed_skip() {
  local rest=${1#SKIP } id file test why entry
  id=${rest%%: *}; why=${rest#*: }
  file=${id%%::*}; file=${file##*/}; test=${id#*::}; test=${test%%[*}
  while IFS= read -r entry; do
    case "$entry" in '' | '#'*) continue ;; esac
    [ "${entry%%: *}" = "$file::$test" ] && [ "${entry#*: }" = "$why" ] && return 0
  done <tests/skips.allow
  return 1
}
unlisted=0
while IFS= read -r skip; do
  if allowed_skip "$skip"; then
    echo "skipped (allowed by tests/skips.allow): $skip"
  else
    unlisted=$((unlisted + 1)); echo "skipped, and not in tests/skips.allow: $skip"
  fi
done <"$skips"
rm -f "$log" "$skips"
# A runner that failed without counting a failure (it crashed) counts one.
if [ $status -ne 0 ] && [ $total_fail -eq 0 ]; then total_fail=1; fi
[ $unlisted -eq 0 ] && [ $unnamed -eq 0 ] || status=1
echo "all tests: $distinct distinct tests and $reruns reruns under ASan+UBSan; $total_pass passed," \
  "$total_fail failed, $total_skip skipped ($unlisted not allowed)"
exit $status
