#!/usr/bin/env bash
# shellcheck disable=SC2317  # the check_* functions are called by name
# The deployment files checked on this machine (`make test-deploy`; root, a
# minute or two, not part of `make test`):
#   slurm    a single-node Slurm (munged, slurmctld, slurmd) started in a
#            temporary directory runs deploy/slurm/texsyn.sbatch with
#            several worker tasks; its output must be byte-identical (cmp)
#            to the embedded run of the same job
#   systemd  `systemd-analyze verify` of deploy/systemd/*, with the build's
#            binaries in ExecStart; any message fails it
#   k8s      deploy/k8s/*.yaml: every field known to its Kubernetes type
#            (tests/deploy/k8s_fields.py) and every object valid against the
#            Kubernetes JSON schema (tests/deploy/k8s_schema.mjs, npm's
#            kubernetes-models, installed into the temporary directory)
#   flags    the coordinator and worker command lines of the units and of
#            the manifests run with the build's programs (tests/deploy/flags.py):
#            the worker joins, with the threads and name the file gives it
#   negatives  the systemd, k8s and flags checks fail on broken copies
# Prints PASS or FAIL per check, exits 1 if any failed. Everything it starts
# is stopped on exit, failure or not; it writes nothing outside its
# temporary directory but the packages deploy/install-deps.sh --deploy
# installs. Usage: tests/deploy/run.sh BUILD_DIR [CHECK...] (default: build,
# all five)
set -uo pipefail

here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
build=$(cd "${1:-build}" && pwd) || exit 1
data=$(bash "$root/tests/test-data.sh") || exit 1
# The job: a 512² texture made 256² at 4 levels, a few seconds of work.
job=(--ref "$data/textures/brick.png" --size 256x256 --levels 4 --seed 7)
workers=4
# Pinned: its validators are generated from a recent Kubernetes OpenAPI schema.
k8s_models=kubernetes-models@5.1.0

tmp=$(mktemp -d /tmp/texsyn-deploy.XXXXXX)
# shellcheck source=tests/deploy/slurm.sh
source "$here/slurm.sh"
cleanup() {
  slurm_stop
  rm -rf "$tmp"
}
trap cleanup EXIT
trap 'exit 143' TERM INT

failed=0
result() {
  if [ "$2" -eq 0 ]; then echo "PASS $1"; else echo "FAIL $1"; failed=1; fi
}

check_slurm() {
  slurm_start "$tmp/slurm" || return 1
  mkdir -p "$tmp/job"
  "$build/texsyn" synth --embedded --quiet "${job[@]}" -o "$tmp/embedded.png" || return 1
  # --overcommit: more worker tasks than the node's CPUs. The daemons'
  # extra options reach them: each starts its Modbus plane.
  (cd "$tmp/job" && TEXSYN_BIN=$build TEXSYN_WAIT=60 TEXSYN_SERVER_OPTS="--modbus 127.0.0.1:0" \
    TEXSYN_WORKER_OPTS="--modbus 127.0.0.1:0" slurm_run_job --time=5 \
    --ntasks="$workers" --overcommit --output=slurm-%j.out \
    "$root/deploy/slurm/texsyn.sbatch" "${job[@]}" -o slurm.png)
  local rc=$?
  echo "--- the Slurm job's output:"
  cat "$tmp"/job/slurm-*.out
  [ "$rc" -eq 0 ] || { echo "slurm: the batch job failed (exit status $rc)"; return 1; }
  # Every worker task took part: each was in the pool before the job began,
  # and answered batches of it (the last column of the pool after the job).
  local joined busy
  joined=$(grep -c ' ready: scans ' "$tmp"/job/texsyn-job-*/server.log)
  [ "$joined" -eq "$workers" ] || { echo "slurm: $joined of $workers workers joined"; return 1; }
  busy=$(sed -n '/the pool after the job/,$p' "$tmp"/job/slurm-*.out | awk '/ active / && $NF > 0' | wc -l)
  [ "$busy" -eq "$workers" ] || { echo "slurm: $busy of $workers workers answered batches"; return 1; }
  local planes
  planes=$(cat "$tmp"/job/texsyn-job-*/{server,worker-*}.log | grep -c 'modbus plane on')
  [ "$planes" -eq $((workers + 1)) ] || { echo "slurm: $planes of $((workers + 1)) daemons got their extra options"; return 1; }
  cmp "$tmp/embedded.png" "$tmp/job/slurm.png" || return 1
  echo "slurm: $workers workers, output byte-identical to the embedded run ($(stat -c %s "$tmp/job/slurm.png") bytes)"
  slurm_job_cleaned "$tmp/job" || return 1
  # A job that fails (a reference that does not exist) fails the batch job,
  # and is cleaned up the same way.
  mkdir -p "$tmp/failing"
  if (cd "$tmp/failing" && TEXSYN_BIN=$build TEXSYN_WAIT=60 slurm_run_job --time=5 \
    --ntasks=2 --overcommit --output=slurm-%j.out \
    "$root/deploy/slurm/texsyn.sbatch" --ref no-such.png --size 64x64 -o failing.png); then
    echo "slurm: a job on a missing reference succeeded"
    return 1
  fi
  grep -q 'no-such.png' "$tmp"/failing/slurm-*.out ||
    { cat "$tmp"/failing/slurm-*.out; echo "slurm: the failed job's output does not name the missing file"; return 1; }
  slurm_job_cleaned "$tmp/failing" || return 1
  echo "slurm: a failing job exits non-zero, names the missing reference, leaves nothing running"
}

# After a job run in directory $1: no process of it left (each has its job
# directory on its command line), the secret and the spool removed.
slurm_job_cleaned() {
  local left
  left=$(pgrep -af "$1/texsyn-job-" || true)
  [ -z "$left" ] || { echo "slurm: left running after the job: $left"; return 1; }
  if compgen -G "$1/texsyn-job-*/secret" > /dev/null || compgen -G "$1/texsyn-job-*/spool" > /dev/null; then
    echo "slurm: the job's secret or spool was not removed"
    return 1
  fi
}

# systemd-analyze verify needs every ExecStart binary to exist: it checks
# copies of the units (of directory $1, default deploy/systemd) with
# /usr/local/bin/ replaced by the build directory. A template is verified as
# instance "i". It exits 0 on unknown keys or bad values (it only logs
# them), so any output is a failure.
check_systemd() {
  local src=${1:-$root/deploy/systemd} dir out rc
  dir=$(mktemp -d "$tmp/systemd.XXXX")
  for unit in "$src"/*; do
    sed "s|/usr/local/bin/|$build/|g" "$unit" > "$dir/$(basename "$unit")"
  done
  out=$(cd "$dir" && systemd-analyze verify --man=no ./* 2>&1)
  rc=$?
  [ -n "$out" ] && echo "$out"
  [ "$rc" -eq 0 ] && [ -z "$out" ] || return 1
  echo "systemd: $(cd "$dir" && echo ./*) verified"
}

# The manifests given (default deploy/k8s/*.yaml): fields, then schema.
check_k8s() {
  local npm=$tmp/npm
  [ $# -gt 0 ] || set -- "$root"/deploy/k8s/*.yaml
  if [ ! -d "$npm/node_modules/kubernetes-models" ]; then
    mkdir -p "$npm"
    # The npm cache in the temporary directory too.
    npm_config_cache=$tmp/npm-cache npm install --prefix "$npm" --no-audit --no-fund \
      --no-update-notifier --loglevel=error "$k8s_models" > "$tmp/npm.log" 2>&1 ||
      { cat "$tmp/npm.log"; echo "k8s: npm install $k8s_models failed"; return 1; }
  fi
  /usr/bin/python3 "$here/k8s_fields.py" "$tmp/k8s.json" "$@" || return 1
  node "$here/k8s_schema.mjs" "$npm/node_modules" "$tmp/k8s.json" || return 1
}

# The coordinator and worker command lines of the units and manifests, run
# (tests/deploy/flags.py; ROOT $1, default this tree).
check_flags() {
  /usr/bin/python3 "$here/flags.py" "${1:-$root}" "$build" "$(mktemp -d "$tmp/flags.XXXX")"
}

# The checks above fail on a broken copy of what they passed: a
# misspelt unit key; a misspelt field (the field check's); a value the
# schema forbids (the schema check's: a field check cannot see it); an
# option the worker does not have, in the unit and in the manifest.
check_negatives() {
  local bad=$tmp/bad ok=0
  mkdir -p "$bad/systemd" "$bad/root/deploy"
  cp "$root"/deploy/systemd/* "$bad/systemd/"
  sed -i 's/^Restart=always/Restrat=always/' "$bad/systemd/texsyn-worker@.service"
  cp -r "$root/deploy/systemd" "$root/deploy/k8s" "$bad/root/deploy/"
  sed -i 's/--join /--joint /' "$bad/root/deploy/systemd/texsyn-worker@.service"
  sed -i 's/--threads=/--treads=/' "$bad/root/deploy/k8s/worker.yaml"
  sed 's/readinessProbe:/readinesProbe:/' "$root/deploy/k8s/server.yaml" > "$bad/field.yaml"
  sed 's/type: Recreate/type: Recreated/' "$root/deploy/k8s/server.yaml" > "$bad/schema.yaml"
  check_systemd "$bad/systemd" > "$bad/out" 2>&1 && { echo "systemd check passed a misspelt key"; ok=1; }
  check_k8s "$bad/field.yaml" > "$bad/out" 2>&1 && { echo "k8s check passed a misspelt field"; ok=1; }
  grep -q 'readinesProbe: unknown field' "$bad/out" || { echo "k8s field check: no line for the misspelt field"; ok=1; }
  check_k8s "$bad/schema.yaml" > "$bad/out" 2>&1 && { echo "k8s check passed a strategy type of no such kind"; ok=1; }
  grep -q 'FAIL .*strategy/type must be equal to one of the allowed values' "$bad/out" ||
    { echo "k8s schema check: no line for the strategy type"; ok=1; }
  check_flags "$bad/root" > "$bad/out" 2>&1 && { echo "flags check passed options the worker lacks"; ok=1; }
  [ "$(grep -c '^FAIL' "$bad/out")" -eq 2 ] || { cat "$bad/out"; echo "flags check: not both files failed"; ok=1; }
  [ "$ok" -eq 0 ] && echo "negatives: each check failed its broken copy"
  return "$ok"
}

bash "$root/deploy/install-deps.sh" --deploy || exit 1
checks=("${@:2}")
[ ${#checks[@]} -gt 0 ] || checks=(slurm systemd k8s flags negatives)
for check in "${checks[@]}"; do
  declare -F "check_$check" > /dev/null || { echo "FAIL $check: no such check"; failed=1; continue; }
  echo "=== $check"
  "check_$check"
  result "$check" $?
done
exit $failed
