#!/usr/bin/env bash
# Integration tests: pytest (Debian's python3-pytest) driving the real
# binaries of BUILD_DIR. Extra arguments go to pytest (e.g. -m sanitize).
# Skipped tests are listed ("SKIPPED [n] FILE:LINE: reason", -rs) for
# tests/run-all.sh to hold against tests/skips.allow. The test images come
# from tests/test-data.sh (TEXSYN_DATA).
# Usage: tests/run-integration.sh BUILD_DIR [pytest args]
set -u
build=${1:-build}; shift || true
export TEXSYN_BUILD=$(cd "$build" && pwd)
TEXSYN_DATA=$(bash "$(dirname "$0")/test-data.sh") || exit 1
export TEXSYN_DATA
py=/usr/bin/python3
$py -m pytest -q -rs -p no:cacheprovider --durations=12 tests/integration "$@"
rc=$?
# pytest exits 5 when a marker selects no test; that is not a failure here.
[ $rc -eq 5 ] && rc=0
exit $rc
