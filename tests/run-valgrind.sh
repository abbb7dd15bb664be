#!/usr/bin/env bash
# Runs every unit test under valgrind's memcheck, each in its own process
# (tests/run-unit.sh with a wrapper). Valgrind does not emulate AVX-512, so
# the kernels dispatch to AVX2 at most there (common/search/l1.c checks what the
# CPU, as valgrind presents it, supports).
# Usage: tests/run-valgrind.sh BUILD_DIR
set -u
build=${1:-build}
export TEXSYN_TEST_WRAPPER="valgrind -q --error-exitcode=99 --leak-check=full --errors-for-leak-kinds=definite --suppressions=$(dirname "$0")/valgrind.supp"
export TEXSYN_TEST_TIMEOUT_MULTIPLIER=${TEXSYN_TEST_TIMEOUT_MULTIPLIER:-10}
exec bash "$(dirname "$0")/run-unit.sh" "$build"
