#!/usr/bin/env bash
# Integration tests: pytest (Debian's python3-pytest) driving the real
# binaries of BUILD_DIR. Extra arguments go to pytest (e.g. -m sanitize).
# Usage: tests/run-integration.sh BUILD_DIR [pytest args]
set -u
build=${1:-build}; shift || true
export TEXSYN_BUILD=$(cd "$build" && pwd)
py=/usr/bin/python3
$py -m pytest -q -p no:cacheprovider --durations=12 tests/integration "$@"
rc=$?
# pytest exits 5 when a marker selects no test; that is not a failure here.
[ $rc -eq 5 ] && rc=0
exit $rc
