# shellcheck shell=bash
# A single-node Slurm (munged, slurmctld, slurmd from Debian) in one
# directory, for tests/deploy/run.sh; sourced, not run.
#
#   slurm_start DIR    write DIR/slurm.conf, start the three daemons with all
#                      their state, sockets, pids and logs in DIR, wait until
#                      this host's node is idle; exports SLURM_CONF
#   slurm_run_job ARGS...  sbatch ARGS, wait for the job, return its status
#   slurm_stop         stop what slurm_start started (safe to call twice)
#
# What works in this sandbox (a VM without systemd as PID 1, no delegated
# cgroup tree), found by trying:
# * munged runs as root only with --force, in the foreground (-F) so its pid
#   is ours; slurm finds its socket through AuthInfo=socket=... (auth and
#   credentials alike), so the system's /run/munge is never touched.
# * The cgroup plugins cannot work here: proctrack/linuxproc (process tree),
#   task/none and jobacct_gather/none need no cgroup.conf.
# * The node is declared as `slurmd -C` sees it (CPUs=2 here): a larger CPU
#   count drains the node ("Low socket*core*thread count"). Jobs with more
#   tasks than CPUs ask for them with --overcommit instead (run.sh does).
# * SlurmUser/SlurmdUser root: the daemons run as the root we are, and the
#   state directories stay ours.

slurm_pids=()

# Two free TCP ports from the kernel (bound to port 0, then released; another
# process taking one in between makes a daemon fail to start, loudly).
slurm_free_ports() {
  /usr/bin/python3 - <<'EOF'
import socket
socks = [socket.socket() for _ in range(2)]
for s in socks:
    s.bind(("127.0.0.1", 0))
print(" ".join(str(s.getsockname()[1]) for s in socks))
EOF
}

slurm_write_conf() {
  local dir=$1 node=$2 ctld_port=$3 slurmd_port=$4
  # The node's hardware line as slurmd measures it, under our node name.
  local hw
  hw=$(slurmd -C | head -n 1 | sed "s/^NodeName=[^ ]*/NodeName=$node/")
  cat > "$dir/slurm.conf" <<EOF
ClusterName=texsyntest
SlurmctldHost=$node(127.0.0.1)
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge/munge.socket
StateSaveLocation=$dir/ctld
SlurmdSpoolDir=$dir/slurmd
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
MpiDefault=none
ReturnToService=2
$hw NodeAddr=127.0.0.1 State=UNKNOWN
PartitionName=test Nodes=$node Default=YES MaxTime=30 State=UP
EOF
}

# Waits up to $2 seconds (default 60) for `sinfo` to show node $1 idle.
slurm_wait_idle() {
  local node=$1 secs=${2:-60} state=
  for _ in $(seq 1 $((secs * 4))); do
    state=$(sinfo -h -N -n "$node" -o %T 2>/dev/null || true)
    [ "$state" = idle ] && return 0
    sleep 0.25
  done
  echo "slurm: node $node is '${state:-unknown}', not idle, after ${secs} s" >&2
  return 1
}

slurm_start() {
  local dir=$1 node
  node=$(hostname -s)
  mkdir -p "$dir/munge" "$dir/ctld" "$dir/slurmd"
  chmod 700 "$dir/munge"
  mungekey --create --keyfile="$dir/munge/munge.key" || return 1
  munged -F --force --socket="$dir/munge/munge.socket" --key-file="$dir/munge/munge.key" \
    --pid-file="$dir/munge/munged.pid" --log-file="$dir/munge/munged.log" \
    --seed-file="$dir/munge/munged.seed" 2> "$dir/munge/munged.err" &
  slurm_pids+=($!)
  local ports
  ports=$(slurm_free_ports) || return 1
  # shellcheck disable=SC2086  # two words, the two ports
  slurm_write_conf "$dir" "$node" $ports
  export SLURM_CONF=$dir/slurm.conf
  for _ in $(seq 1 40); do
    [ -S "$dir/munge/munge.socket" ] && break
    sleep 0.25
  done
  [ -S "$dir/munge/munge.socket" ] || { echo "slurm: munged did not start:" >&2; cat "$dir/munge/munged.err" >&2; return 1; }
  slurmctld -D -c -f "$SLURM_CONF" 2> "$dir/slurmctld.err" &
  slurm_pids+=($!)
  slurmd -D -N "$node" -f "$SLURM_CONF" 2> "$dir/slurmd.err" &
  slurm_pids+=($!)
  slurm_wait_idle "$node" 60 || { tail -n 20 "$dir"/slurm*.log "$dir"/slurm*.err >&2; return 1; }
}

# sbatch ARGS..., then waits (up to 5 min) for the job to end; returns its
# exit status, 1 if it ended otherwise (cancelled, timed out). sbatch --wait
# polls at growing intervals, which added up to 30 s per job here.
slurm_run_job() {
  local id line state code
  id=$(sbatch --parsable "$@") || return 1
  id=${id%%;*}
  for _ in $(seq 1 1200); do
    line=$(scontrol -o show job "$id" 2>/dev/null)
    state=$(sed -n 's/.* JobState=\([A-Z_]*\).*/\1/p' <<< "$line")
    case $state in
      PENDING | CONFIGURING | RUNNING | COMPLETING | "") sleep 0.25 ;;
      *)
        code=$(sed -n 's/.* ExitCode=\([0-9]*\):.*/\1/p' <<< "$line")
        [ "$state" = COMPLETED ] && return "${code:-1}"
        echo "slurm: job $id ended $state (exit status ${code:-?})" >&2
        [ "${code:-0}" -ne 0 ] && return "$code"
        return 1 ;;
    esac
  done
  echo "slurm: job $id still '$state' after 5 min" >&2
  return 1
}

# Jobs still there (a check that failed half-way) are cancelled first and
# given 30 s to end: Slurm ends their processes, which stopping slurmd
# would not. Then slurmd, the controller, munged; each gets 10 s after
# SIGTERM before SIGKILL.
slurm_stop() {
  local i pid
  if [ ${#slurm_pids[@]} -gt 0 ] && [ -n "$(squeue -h -o %i 2>/dev/null)" ]; then
    scancel --user="$(id -un)" 2>/dev/null
    for _ in $(seq 1 120); do
      [ -z "$(squeue -h -o %i 2>/dev/null)" ] && break
      sleep 0.25
    done
  fi
  for ((i = ${#slurm_pids[@]} - 1; i >= 0; i--)); do
    pid=${slurm_pids[$i]}
    kill "$pid" 2>/dev/null || continue
    for _ in $(seq 1 40); do kill -0 "$pid" 2>/dev/null || break; sleep 0.25; done
    kill -9 "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
  done
  slurm_pids=()
}
