#!/usr/bin/env bash
# A coordinator and N workers on loopback, for tests, benchmarks and users.
#
#   deploy/local-cluster.sh start N [--threads T] [-- extra texsyn-server options]
#   deploy/local-cluster.sh stop
#   deploy/local-cluster.sh status
#
# Ports are chosen by the kernel (port 0); the run directory (TEXSYN_RUN,
# default ./texsyn-run) holds server.addr, the pids, every log and the
# spool. `start` prints `export TEXSYN_SERVER=HOST:PORT`, for the shell to
# evaluate:   eval "$(deploy/local-cluster.sh start 2)"
# (exported, so that the texsyn commands the shell starts see it: a plain
# assignment would leave them running in-process).
# Binaries come from TEXSYN_BUILD (default: build/ beside deploy/).
set -euo pipefail

run=${TEXSYN_RUN:-texsyn-run}
bin=${TEXSYN_BUILD:-$(dirname "$0")/../build}

die() { echo "local-cluster: $*" >&2; exit 1; }

# Waits for a daemon's "listening on HOST:PORT" line; prints HOST:PORT.
wait_addr() {
  local out=$1 pid=$2
  for _ in $(seq 1 200); do
    if grep -q 'listening on' "$out" 2>/dev/null; then
      sed -n 's/.*listening on \([^ ]*\).*/\1/p' "$out" | head -n 1
      return 0
    fi
    kill -0 "$pid" 2>/dev/null || { cat "${out%.out}.log" >&2 || true; die "daemon $pid exited"; }
    sleep 0.05
  done
  die "no 'listening on' line in $out after 10 s"
}

start() {
  local n=${1:-}; shift || true
  [[ "$n" =~ ^[0-9]+$ ]] || die "usage: start N [--threads T] [-- server options]"
  local threads=1 extra=()
  while [ $# -gt 0 ]; do
    case $1 in
      --threads) threads=$2; shift 2 ;;
      --) shift; extra=("$@"); break ;;
      *) die "unknown option $1" ;;
    esac
  done
  [ -x "$bin/texsyn-server" ] && [ -x "$bin/texsyn-worker" ] || die "build first (make): $bin/texsyn-server missing"
  [ -f "$run/pids" ] && die "$run already holds a cluster (stop it first)"
  mkdir -p "$run"
  : > "$run/pids"
  local workers=()
  for i in $(seq 1 "$n"); do
    "$bin/texsyn-worker" --listen 127.0.0.1:0 --threads "$threads" --name "w$i" \
      > "$run/worker$i.out" 2> "$run/worker$i.log" &
    echo "$! worker$i" >> "$run/pids"
    workers+=("$(wait_addr "$run/worker$i.out" $!)")
  done
  local list
  list=$(IFS=,; echo "${workers[*]:-}")
  local args=(--listen 127.0.0.1:0 --spool "$run/spool")
  [ -n "$list" ] && args+=(--workers "$list")
  "$bin/texsyn-server" "${args[@]}" "${extra[@]}" > "$run/server.out" 2> "$run/server.log" &
  echo "$! server" >> "$run/pids"
  local addr
  addr=$(wait_addr "$run/server.out" $!)
  echo "$addr" > "$run/server.addr"
  # Ready when every worker is calibrated.
  for _ in $(seq 1 200); do
    local ready
    ready=$(TEXSYN_SERVER=$addr "$bin/texsyn" workers 2>/dev/null | grep -c ' active ' || true)
    [ "$ready" -ge "$n" ] && break
    sleep 0.05
  done
  echo "export TEXSYN_SERVER=$addr"
}

stop() {
  [ -f "$run/pids" ] || { echo "local-cluster: nothing running in $run"; return 0; }
  while read -r pid name; do
    kill "$pid" 2>/dev/null || true
  done < "$run/pids"
  while read -r pid name; do
    for _ in $(seq 1 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.05; done
    kill -9 "$pid" 2>/dev/null || true
  done < "$run/pids"
  rm -f "$run/pids" "$run/server.addr"
  echo "local-cluster: stopped"
}

status() {
  [ -f "$run/pids" ] || { echo "local-cluster: nothing running in $run"; return 1; }
  while read -r pid name; do
    if kill -0 "$pid" 2>/dev/null; then echo "$name pid $pid running"; else echo "$name pid $pid DEAD"; fi
  done < "$run/pids"
  TEXSYN_SERVER=$(cat "$run/server.addr") "$bin/texsyn" workers || true
}

case ${1:-} in
  start) shift; start "$@" ;;
  stop) stop ;;
  status) status ;;
  *) die "usage: $0 start N [--threads T] [-- server options] | stop | status" ;;
esac
