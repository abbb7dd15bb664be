#!/usr/bin/env bash
# The integration tests that drive the cluster's threads (the coordinator's
# job, exchange, supervision, Modbus and HTTP threads; the workers' scan
# pools and planes; the client; a tiled aerial job's tile threads and their
# search sessions) on the ThreadSanitizer build (make
# test-tsan, build-tsan/). A daemon's race report fails its test
# (conftest.check_daemons reads "WARNING: ThreadSanitizer" in its log), a
# client's makes it exit 66. The jobs are the sanitized stage's smaller ones
# (TEXSYN_SANITIZED=1), the tests of ASan's planted faults left out.
# halt_on_error=1 stops a process at its first race; to list them all:
#   TSAN_OPTIONS=halt_on_error=0 tests/run-tsan.sh
# Extra arguments go to pytest (e.g. -k cancel).
# Usage: tests/run-tsan.sh [BUILD_DIR] [pytest args]
set -u
cd "$(dirname "$0")/.."
build=${1:-build-tsan}; shift || true
export TEXSYN_BUILD=$(cd "$build" && pwd)
TEXSYN_DATA=$(bash tests/test-data.sh) || exit 1
export TEXSYN_DATA TEXSYN_SANITIZED=1
# Library-internal false positives only (tests/tsan.supp says why, each).
export TSAN_OPTIONS="halt_on_error=1:exitcode=66:second_deadlock_stack=1:suppressions=$PWD/tests/tsan.supp:${TSAN_OPTIONS:-}"
t=tests/integration
# Left out: the two tests that measure scan rates (a throttled worker's
# calibration, a spike below the rebalance threshold). TSan's overhead is
# not the scans' (the L1 kernels are uninstrumented, Makefile) and swamps
# the throttle; they test arithmetic on rates, not threads.
/usr/bin/python3 -m pytest -q -rs -p no:cacheprovider --durations=8 -m "not asan_only" \
  -k "not test_slow_worker_gets_a_proportionally_smaller_slice and not test_one_second_spike_does_not_rebalance" \
  $t/test_cluster.py $t/test_faults.py $t/test_local_cluster.py $t/test_redispatch.py $t/test_wrong_answers.py \
  $t/test_lifecycle.py $t/test_modbus.py $t/test_http.py $t/test_aerial_tiles.py "$@"
