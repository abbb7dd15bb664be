#!/usr/bin/python3
"""Soak: hundreds of small jobs for --minutes (10) against a coordinator with
3 workers, while a chaos thread kills, stalls, partitions and replaces
workers, kills the coordinator itself and breaks its spool's disk. Not part
of `make test`; `make soak SOAK_MINUTES=N` runs it (as root).

What runs (in a temporary directory):
  * Network namespaces (tests/integration/netns.py): the coordinator in one,
    each of the 3 worker slots in its own, joined to the coordinator's by a
    veth pair of its own, so one worker's link can be cut. Clients run in the
    coordinator's namespace and reach it on its loopback; the peers share a
    secret (they are not on loopback).
  * texsyn-server --workers SLOT0,SLOT1,SLOT2 with its default options
    (heartbeat 2 s, batch timeout 2 s, 2 jobs at once): the soak tests the
    daemon as deployed. Its spool is on a tmpfs of its own (SPOOL_FS_MIB), so
    the disk can be filled or made read-only under it.
  * 3 texsyn-worker --listen --threads 1 --modbus (their register map says
    how many reference vectors they hold; the coordinator supervises them
    over it too). w0 is the sentinel: it may be stalled or cut off but is
    never killed, so at least one worker lives from the warm-up sample to
    the end and its fds and RSS can be compared. The daemons run with a fixed
    glibc mmap threshold (DAEMON_ENV, see the bounds below) so that RSS
    measures what they hold, not what the allocator keeps for reuse.
  * --clients (4) clients, each a thread running the real CLI as its own
    user (USER=soakN): even clients run `texsyn synth --server` and wait for
    the result; odd ones submit 1 to 4 jobs with --detach, then `watch`,
    `fetch` each. Every client then `texsyn delete`s the job it fetched, as a
    real client would, so the spool must stay small. A command cut by a fault
    is followed up as a client would: a job whose id the client has (or finds
    in the coordinator's log as queued for its user: the coordinator died
    before the id reached it) is watched again once the coordinator is back;
    a submission that was not queued was not accepted, and must have been
    refused with a reason while a fault was on.
  * Jobs are drawn from a pool of --combos (40) distinct small jobs: brick,
    grass or aero1 (tests/test-data.sh), 64x48 to 128x96, 2 or 3 levels,
    W_N 5 or 7, random seeds, --rgb-search, --parity, a usage penalty and a
    raw copy map on some. A verifier thread runs each distinct job once with
    `texsyn synth --embedded` (cached by its parameters) and compares every
    fetched output, image and raw copy map, byte for byte.
  * A chaos thread, every 4 to 16 s, one fault at a time (the first of each
    kind early, then drawn by FAULT_WEIGHTS):
      worker_kill   SIGKILL a worker (not w0); a replacement 0.5 to 4 s later
                    on its address (dialled again) or by --join;
      stall         SIGSTOP a worker for 1 to 6 s (past the 2 s batch
                    deadline it is dropped, and dialled again);
      partition     cut one worker's link for 1 to 10 s, both ways or one
                    way (netns.py: dropped on arrival, silently), then heal:
                    shorter than the deadlines it is ridden out, longer the
                    worker is dropped and dialled again;
      half_open     cut a worker (not w0) both ways, SIGKILL it (its FIN and
                    RST are lost) and delete its namespace: the coordinator
                    hears nothing and must notice by its deadlines; the host
                    comes back (a fresh worker) 8 to 12 s later;
      coordinator_kill  SIGKILL the coordinator while a job runs, start it
                    again 0.5 to 3 s later on the same spool and port; only
                    in the first COORD_KILL_UNTIL of the run, so that the
                    last coordinator lives through several samples;
      disk_full     fill the spool's filesystem for 3 to 10 s;
      disk_ro       remount it read-only for 3 to 10 s (retried while a file
                    is open for writing; if it never gets its moment, the
                    disk is filled instead, and the report says so).
    --no-chaos: none; --no-partitions (no namespaces: all on loopback),
    --no-disk-faults, --no-coordinator-kills leave one kind out.

Measured at quiescent points, after the warm-up, every --sample-every
seconds and at the end: the clients and the chaos thread are paused, every
job has ended and has been deleted, and the pool has its 3 workers ready
again. Then the coordinator's and every surviving worker's open fds
(/proc/PID/fd) and RSS (/proc/PID/status VmRSS), the vectors each worker
holds (must come to 0) and the spool's size are taken. Each process's last
sample is held to its first plus the bounds below, and its slope (per 100
jobs, least squares over its samples) is reported. A monitor thread also
samples the coordinator every second and prints a progress line every 30 s.

The history check, from the coordinator's log (all its lives) and the
clients' records: every job the coordinator accepted (logged queued, or
whose id a client got) must be done exactly once with the embedded run's
bytes, or failed with a reason while a disk fault explains it; anything
else pending at the end is lost. The run fails (exit status 1, the reasons
listed) on a lost, different or twice-done job, a failure or refusal no
fault explains, a client command that fails or hangs for no fault, a daemon
we did not kill exiting, the pool not coming back to 3 ready workers, or a
bound exceeded. A hard time bound ends it whatever hangs: --minutes +
HARD_MARGIN seconds after the start it kills what still runs and reports,
counting every accepted job not ended as lost.

Writes OUT/soak.json and OUT/soak.txt (default bench/results).
Usage: bench/soak.py [--minutes 10] [--build build] [--out bench/results]
"""
import argparse
import errno
import hashlib
import json
import os
import queue
import random
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "integration"))
import netns  # noqa: E402  (the namespaces the partition tests use too)

MiB = 1 << 20

# ---- the bounds -------------------------------------------------------------
#
# Two samples of one process are taken at quiescent points with the same
# pool (3 workers connected, no job queued or running, no client connected
# but the sampler's), so a daemon that frees what it is done with has the
# same set of fds at both. The only legitimate differences are transient: a
# dial of a dead --workers address in flight (at most one per address the
# coordinator was started with, 3), a connection whose peer has closed and
# that the daemon has not reaped yet, a checkpoint or result file being
# written. FD_SLACK = 8 covers those with room to spare, while a leak of one
# fd per job (hundreds between the samples) or per worker failure (dozens in
# 10 minutes) overshoots it by far.
FD_SLACK = 8
# RSS. glibc raises its mmap threshold each time a large block is freed, so
# buffers that were their own mappings (a worker's slice vectors, a level's
# planes) later come from the heap, and freed heap memory stays in the
# process for reuse. Under the default allocator the workers' RSS at a
# quiescent point is therefore their allocator's high-water mark: it climbs
# in steps whenever a worker is handed a bigger share than before (a 3-minute
# run without chaos: 59 -> 112 MiB, then flat; with chaos, one worker holding
# every slice of two colour jobs peaks at 230 MiB) and says nothing about
# leaks. So the daemons run with DAEMON_ENV, a fixed mmap threshold of
# 128 KiB (glibc's default starting value; a documented tunable, no code
# change): every block of 128 KiB or more is its own mapping, returned to
# the kernel when freed, and the RSS of a quiescent daemon is what it still
# holds - its code, the live heap and the small-block fragmentation. Measured
# that way the RSS drifted by under 1 MiB over 160 jobs (coordinator
# 128.8 -> 129.2 MiB, most of it OpenImageIO's code; workers 4.9 -> 5.9 MiB).
# RSS_SLACK = 16 MiB is 16x that drift, while keeping one decoded reference
# (brick and grass: 256 KiB grey, aero1: 225 KiB RGB), a level's planes, a
# slice or a query image per job - 50 KiB to a few MiB - over the hundreds
# of jobs between the samples overshoots it. The bound is first + 16 MiB.
RSS_SLACK = 16 * MiB
DAEMON_ENV = {"MALLOC_MMAP_THRESHOLD_": "131072"}
# The spool: at both samples every job has been deleted, so the spool holds
# its bookkeeping only (last-id, an empty jobs/). Its bytes may differ by the
# width of the last id; SPOOL_SLACK = 64 KiB. During the run, at most every
# client's outstanding jobs (1 for a waiting client, up to DETACH_MAX for a
# detached one) can be in the spool at once; the max seen is checked too.
SPOOL_SLACK = 64 * 1024
DETACH_MAX = 4
# A worker's slices belong to its connection. A one-way partition can leave
# the worker's end open after the coordinator dropped it (the coordinator's
# FIN was lost); TCP retransmits that FIN with backoff (0.2 s doubling), so
# the worker hears of it at most ~13 s after a 10 s partition heals and
# frees the slices. A sample waits up to VECTORS_WAIT for them to go.
VECTORS_WAIT = 40

WORKERS = 3
CHAOS_EVERY = (4.0, 16.0)      # seconds between chaos events
STALL_SECONDS = (1.0, 6.0)     # SIGSTOP .. SIGCONT
REPLACE_AFTER = (0.5, 4.0)     # a killed worker's replacement starts this much later
PARTITION_SECONDS = (1.0, 10.0)
HALF_OPEN_BACK = (8.0, 12.0)   # past the 2 s heartbeat + 2S+1 s answer: noticed before the host is back
COORD_BACK = (0.5, 3.0)        # the coordinator starts again this much after its SIGKILL
COORD_KILL_UNTIL = 0.5         # share of the run in which the coordinator may be killed
DISK_SECONDS = (3.0, 10.0)
DISK_GRACE = 5.0               # a failure this soon after a disk fault ended is still its doing
SPOOL_FS_MIB = 64              # the spool's tmpfs: a few times what the clients can have in it
RO_TRIES_S = 3.0               # remount,ro retried this long while a file is open for writing
FAULT_WEIGHTS = {"worker_kill": 0.22, "stall": 0.13, "partition": 0.25, "half_open": 0.10,
                 "coordinator_kill": 0.12, "disk_full": 0.09, "disk_ro": 0.09}
FIRST_FAULTS = ["worker_kill", "stall", "partition", "coordinator_kill", "disk_full", "half_open", "disk_ro"]
POOL_TIMEOUT = 90              # seconds for the pool to have its workers ready again
CMD_TIMEOUT = 600              # seconds for one client command: past it, the job counts as hung
HARD_MARGIN = 300              # seconds past --minutes at which the soak ends and reports whatever hangs
PROGRESS_EVERY = 30

TEXTURES = ["textures/brick.png", "textures/grass.png", "aerial/aero1.jpg"]
SIZES = [(64, 48), (80, 64), (96, 72), (96, 96), (112, 80), (128, 96)]


def log(msg):
    print(msg, flush=True)


# ---- processes ----------------------------------------------------------------

def proc_fds(pid):
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None


def proc_mem(pid, field="VmRSS"):
    """A /proc/PID/status memory figure (VmRSS, VmHWM, RssAnon) in bytes,
    None if the process is gone."""
    try:
        m = re.search(rf"{field}:\s+(\d+) kB", Path(f"/proc/{pid}/status").read_text())
    except OSError:
        return None
    return int(m.group(1)) * 1024 if m else None


def fd_kinds(pid):
    """{kind: count} of a process's open fds: socket, pipe, anon_inode, or
    the file's path (to tell what leaked)."""
    kinds = {}
    try:
        for fd in os.listdir(f"/proc/{pid}/fd"):
            try:
                t = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            k = t.split(":", 1)[0] if re.match(r"^(socket|pipe|anon_inode):", t) else t
            kinds[k] = kinds.get(k, 0) + 1
    except OSError:
        pass
    return kinds


def proc_info(pid):
    return {"pid": pid, "fds": proc_fds(pid), "fd_kinds": fd_kinds(pid), "rss": proc_mem(pid),
            "rss_anon": proc_mem(pid, "RssAnon"), "hwm": proc_mem(pid, "VmHWM")}


def start_daemon(args, log_path, want=r"listening on (\S+)"):
    """Starts a daemon and reads its first line of stdout ('listening on
    ADDR (modbus ADDR)', or 'modbus on ADDR' for a --join worker); returns
    (Popen, ADDR, MODBUS ADDR or None) or (None, reason, None)."""
    env = dict(os.environ)
    env.update(DAEMON_ENV)
    with open(log_path, "a") as err:
        p = subprocess.Popen([str(a) for a in args], stdout=subprocess.PIPE, stderr=err, text=True, env=env)
    line = p.stdout.readline()
    m = re.search(want, line)
    if not m:
        p.kill()
        p.wait()
        p.stdout.close()
        return None, f"{Path(str(args[4] if args[0] == 'ip' else args[0])).name} did not start: {line!r}, " \
                     f"see {log_path}", None
    mb = re.search(r"modbus (?:on )?([0-9.]+:\d+)", line)
    return p, m.group(1), mb.group(1) if mb else None


def slope(points):
    """Least-squares slope of [(x, y)], None when x does not vary."""
    if len(points) < 2:
        return None
    mx = statistics.mean(x for x, _ in points)
    my = statistics.mean(y for _, y in points)
    sxx = sum((x - mx) ** 2 for x, _ in points)
    return None if sxx == 0 else sum((x - mx) * (y - my) for x, y in points) / sxx


class Worker:
    def __init__(self, name, slot, proc, mode, addr, modbus, log_path, sentinel=False):
        self.name, self.slot, self.proc, self.mode, self.addr = name, slot, proc, mode, addr
        self.log_path = log_path
        self.modbus = modbus     # its Modbus plane: the register map says what it holds
        self.sentinel = sentinel
        self.killed = False      # by the chaos thread
        self.started = time.time()

    def alive(self):
        return self.proc.poll() is None

    def stop(self):
        if self.proc.poll() is None:
            try:
                self.proc.send_signal(signal.SIGCONT)
                self.proc.send_signal(signal.SIGTERM)
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stdout:
            self.proc.stdout.close()


# ---- the gate: clients and chaos pause for the samples -------------------------

class Gate:
    """Clients call enter() before each unit of work (a job, or a batch of
    detached jobs); drain() closes the gate and returns once every client
    thread still running waits at it (or its deadline passed)."""

    def __init__(self):
        self.cv = threading.Condition()
        self.open = True
        self.waiting = 0
        self.active = 0
        self.finish = False

    def enter(self):
        """False once the soak is over."""
        with self.cv:
            while not self.open and not self.finish:
                self.waiting += 1
                self.cv.notify_all()
                self.cv.wait()
                self.waiting -= 1
            return not self.finish

    def leave_for_good(self):
        with self.cv:
            self.active -= 1
            self.cv.notify_all()

    def drain(self, deadline):
        """True once every client waits; False if deadline came first."""
        with self.cv:
            self.open = False
            while self.waiting < self.active:
                left = deadline - time.time()
                if left <= 0:
                    return False
                self.cv.wait(timeout=left)
            return True

    def reopen(self):
        with self.cv:
            self.open = True
            self.cv.notify_all()

    def end(self):
        with self.cv:
            self.finish = True
            self.cv.notify_all()


class HardStop(Exception):
    """The soak's hard time bound passed."""


# ---- the soak -----------------------------------------------------------------
class Soak:
    def __init__(self, a):
        self.a = a
        self.start_time = time.time()
        self.hard_deadline = self.start_time + a.minutes * 60 + a.hard_margin
        self.hard = False                  # the hard time bound passed
        self.build = Path(a.build).resolve()
        self.texsyn = self.build / "texsyn"
        self.rng = random.Random(a.seed)
        self.tmp = Path(tempfile.mkdtemp(prefix="texsyn-soak-"))
        self.net = None                    # netns.Net with --partitions
        self.spool_fs = None               # the spool's tmpfs with disk faults
        self.spool = self.tmp / "spool"
        self.secret = self.tmp / "secret"
        self.lock = threading.Lock()
        self.gate = Gate()
        self.chaos_lock = threading.Lock()
        self.done = threading.Event()      # the soak's time is up
        self.children = set()              # client commands running, for the hard stop
        self.workers = []                  # every Worker ever started
        self.slot_addr = [None] * WORKERS  # each slot's --listen address (in the coordinator's --workers)
        self.next_worker = 0
        # The coordinator: its lives, whether it is up, and a count of its
        # kills (a command that saw the count change was cut by one).
        self.server = None
        self.server_addr = None
        self.coord_port = 0
        self.coord_lives = 0
        self.coord_gen = 0
        self.coord_up = threading.Event()
        # Disk faults: whether the spool's disk is well, a count of faults,
        # and their windows [start, end] in seconds of the run.
        self.disk_ok = threading.Event()
        self.disk_ok.set()
        self.disk_gen = 0
        self.disk_windows = []
        self.jobs = {}                     # id -> record
        self.errors = []                   # client-side failures (strings)
        self.problems = []                 # unexpected daemon exits etc.
        self.mismatches = []
        self.refusals = []                 # submissions not accepted while a fault was on
        self.refs = {}                     # combo key -> (png sha, raw sha or None)
        self.ref_lock = threading.Lock()
        self.verify_q = queue.Queue()
        self.verified = 0
        self.embedded_runs = 0
        self.counts = {k: 0 for k in FAULT_WEIGHTS}
        self.counts.update({"stall_seconds": 0.0, "restarts_same_addr": 0, "joins": 0, "ro_busy": 0})
        self.faults = []                   # one record per fault, for the report
        self.events = []                   # (t, what)
        self.samples = []                  # coordinator timeline
        self.max_fds = (0, 0.0)
        self.max_rss = (0, 0.0)
        self.max_spool_jobs = 0
        self.latencies = []                # client-side seconds, submit to result
        self.measure = {}
        self.final_status = None
        self.wall = None
        self.chaos_thread = None

    def t(self):
        return time.time() - self.start_time

    def hard_left(self):
        return self.hard_deadline - time.time()

    def event(self, what):
        with self.lock:
            self.events.append((self.t(), what))
        log(f"[{self.t():5.0f} s] {what}")

    # ---- setup

    def data_dir(self):
        p = subprocess.run(["bash", "tests/test-data.sh", *TEXTURES], cwd=REPO, capture_output=True, text=True)
        if p.returncode != 0:
            sys.exit(f"soak: tests/test-data.sh failed:\n{p.stderr}")
        return Path(p.stdout.strip().splitlines()[-1])

    def make_combos(self, data):
        combos = []
        for i in range(self.a.combos):
            tex = TEXTURES[i % len(TEXTURES)]
            w, h = self.rng.choice(SIZES)
            levels = self.rng.choice([2, 3, 3])
            wn = self.rng.choice([5, 7, 7])
            opts = []
            if self.rng.random() < (0.5 if "aero" in tex else 0.25):
                opts.append("--rgb-search")
            if self.rng.random() < 0.3:
                opts.append("--parity")
            if self.rng.random() < 0.2:
                opts += ["--usage-weight", "2"]
            raw = self.rng.random() < 0.5
            seed = self.rng.randrange(1, 1 << 31)
            args = ["--ref", str(data / tex), "--size", f"{w}x{h}", "--levels", str(levels), "--wn", str(wn),
                    "--seed", str(seed), *opts]
            combos.append({"key": " ".join([tex, *args[2:]]) + (" raw" if raw else ""), "args": args, "raw": raw})
        return combos

    def setup_host(self):
        """The namespaces and the spool's own filesystem."""
        self.secret.write_text(os.urandom(16).hex())
        self.secret.chmod(0o600)
        if self.a.partitions:
            self.net = netns.Net(WORKERS, tag=f"sk{os.getpid() % 100000}").create()
        if self.a.disk_faults:
            self.spool_fs = self.tmp / "spoolfs"
            self.spool_fs.mkdir()
            netns.sh("mount", "-t", "tmpfs", "-o", f"size={SPOOL_FS_MIB}m,mode=0700", "texsyn-soak", self.spool_fs)
            self.spool = self.spool_fs / "spool"

    def teardown_host(self):
        if self.spool_fs is not None:
            self.disk_heal()
            if netns.sh("umount", self.spool_fs, check=False).returncode != 0:
                netns.sh("umount", "-l", self.spool_fs, check=False)
            self.spool_fs = None
        if self.net is not None:
            self.net.close()
            self.net = None

    # ---- where things run

    def in_coord(self, *argv):
        return self.net.in_coord(*argv) if self.net else [str(a) for a in argv]

    def in_slot(self, slot, *argv):
        return self.net.in_worker(slot, *argv) if self.net else [str(a) for a in argv]

    def worker_host(self, slot):
        return self.net.worker_ip(slot) if self.net else "127.0.0.1"

    def join_addr(self, slot):
        """The coordinator's address as slot's workers reach it."""
        return f"{self.net.coord_ip(slot) if self.net else '127.0.0.1'}:{self.coord_port}"

    # ---- daemons

    def start_worker(self, slot, mode, sentinel=False):
        """A listen worker (on its slot's address, once it has one) or a
        join worker in the slot; None if it did not start."""
        name = f"w{self.next_worker}"
        self.next_worker += 1
        log_path = self.tmp / f"{name}.log"
        host = self.worker_host(slot)
        where = (["--listen", self.slot_addr[slot] or f"{host}:0"] if mode == "listen"
                 else ["--join", self.join_addr(slot)])
        args = self.in_slot(slot, self.build / "texsyn-worker", *where, "--threads", 1, "--name", name,
                            "--secret-file", self.secret, "--modbus", f"{host}:0",
                            "--modbus-allow", self.join_addr(slot).rsplit(":", 1)[0])
        want = r"listening on (\S+)" if mode == "listen" else r"modbus on (\S+)"
        p, got, modbus = start_daemon(args, log_path, want)
        if p is None:
            self.event(f"{name}: {got}")
            return None
        if mode == "listen" and self.slot_addr[slot] is None:
            self.slot_addr[slot] = got
        w = Worker(name, slot, p, mode, got if mode == "listen" else None, modbus, log_path, sentinel)
        with self.lock:
            self.workers.append(w)
        return w

    def start_coordinator(self):
        """A coordinator on the spool, on the first one's port once there
        was one; False if it did not start (the problem is recorded)."""
        bind = "0.0.0.0" if self.net else "127.0.0.1"
        args = self.in_coord(self.build / "texsyn-server", "--listen", f"{bind}:{self.coord_port}", "--spool",
                             self.spool, "--secret-file", self.secret, "--workers", ",".join(self.slot_addr))
        why = None
        for _ in range(10):  # a restart may find the port still held for a moment
            p, addr, _ = start_daemon(args, self.server_log)
            if p is not None:
                break
            why = addr
            time.sleep(0.5)
        else:
            self.problems.append(f"the coordinator did not start (life {self.coord_lives + 1}): {why}")
            return False
        with self.lock:
            self.server = p
            self.coord_lives += 1
        self.coord_port = int(addr.rsplit(":", 1)[1])
        self.server_addr = f"127.0.0.1:{self.coord_port}"
        self.coord_up.set()
        return True

    def start_cluster(self):
        first = [self.start_worker(i, "listen", sentinel=(i == 0)) for i in range(WORKERS)]
        if None in first:
            sys.exit(f"soak: a worker did not start: {self.events}")
        self.server_log = self.tmp / "server.log"
        if not self.start_coordinator():
            sys.exit(f"soak: {self.problems[-1]}")
        self.wait_pool(WORKERS, "at start")

    # ---- commands

    def run_cmd(self, argv, timeout, env=None):
        """Runs a command (killed at the hard bound); a CompletedProcess,
        returncode -1 if it hung past timeout."""
        timeout = max(1.0, min(timeout, self.hard_left()))
        p = subprocess.Popen([str(a) for a in argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             env=env)
        with self.lock:
            self.children.add(p)
        try:
            out, err = p.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:  # the child is killed; the caller reports a hang
            p.kill()
            out, err = p.communicate()
            return subprocess.CompletedProcess(argv, -1, out, f"{err}no answer within {timeout:.0f} s (hung)")
        finally:
            with self.lock:
                self.children.discard(p)
        if self.hard:
            raise HardStop()
        return subprocess.CompletedProcess(argv, p.returncode, out, err)

    def cli(self, client, *args, timeout=CMD_TIMEOUT):
        env = dict(os.environ)
        env.pop("TEXSYN_SERVER", None)
        env["USER"] = f"soak{client}"
        env["TEXSYN_SECRET_FILE"] = str(self.secret)
        return self.run_cmd(self.in_coord(self.texsyn, *map(str, args), "--server", self.server_addr), timeout, env)

    def pool(self):
        """[(addr, state)] from `texsyn workers`; None if the call failed."""
        p = self.cli("-", "workers", timeout=30)
        if p.returncode != 0:
            return None
        rows = []
        for line in p.stdout.splitlines()[1:]:
            f = line.split()
            if len(f) >= 9 and f[2].isdigit():
                rows.append((f[1], f[7]))
        return rows

    def status(self, client="-", jid=None):
        """{id: state} of every job the coordinator lists (or of one); None
        on failure."""
        p = self.cli(client, "status", *([jid] if jid is not None else []), timeout=30)
        if p.returncode != 0:
            return None
        return {int(f[0]): f[1] for f in (l.split() for l in p.stdout.splitlines()) if f and f[0].isdigit()}

    def wait_pool(self, n, when):
        deadline = min(time.time() + POOL_TIMEOUT, self.hard_deadline)
        rows = None
        while time.time() < deadline:
            rows = self.pool()
            if rows is not None and sum(1 for _, s in rows if s == "active") >= n:
                return True
            time.sleep(0.2)
        self.problems.append(f"{when}: the pool did not get {n} ready workers back within {POOL_TIMEOUT} s: {rows}")
        return False

    # ---- faults as the clients see them

    def fault_mark(self):
        """What a command started under: the kill and disk-fault counts, and
        whether all was well then."""
        return (self.coord_gen, self.disk_gen, self.coord_up.is_set() and self.disk_ok.is_set(), time.time())

    def fault_during(self, mark):
        """Whether a fault may explain a command's failure: one was on when
        it started or is on now, one came while it ran, or a disk fault
        ended less than DISK_GRACE before it started."""
        gen, dgen, ok, t0 = mark
        if not ok or gen != self.coord_gen or dgen != self.disk_gen:
            return True
        if not (self.coord_up.is_set() and self.disk_ok.is_set()):
            return True
        with self.lock:
            return any(e is not None and self.start_time + e > t0 - DISK_GRACE for _, e in self.disk_windows)

    def fault_name(self, mark):
        if mark[0] != self.coord_gen or not self.coord_up.is_set():
            return "coordinator kill"
        return "disk fault" if mark[1] != self.disk_gen or not self.disk_ok.is_set() else "a fault just before"

    def wait_well(self):
        """Waits until the coordinator is up and its disk is well (a client
        repeating a command cut by a fault waits, as a user would)."""
        for ev in (self.coord_up, self.disk_ok):
            if not ev.wait(timeout=max(0.0, self.hard_left())):
                raise HardStop()

    def retry(self, client, *args, timeout=CMD_TIMEOUT):
        """A command that may be repeated (watch, status, fetch, delete),
        repeated while a fault cut it; the last CompletedProcess."""
        for _ in range(30):
            self.wait_well()
            mark = self.fault_mark()
            p = self.cli(client, *args, timeout=timeout)
            if p.returncode == 0 or not self.fault_during(mark):
                return p
            time.sleep(0.2)
        return p

    # ---- client commands

    def client_error(self, client, what, p=None):
        msg = f"client {client}: {what}"
        if p is not None:
            msg += f" (exit {p.returncode}): {p.stderr.strip()[-500:]}"
        with self.lock:
            self.errors.append(msg)
        log(f"soak: ERROR {msg}")

    def record(self, jid, client, combo, t_submit, how="given"):
        with self.lock:
            if jid in self.jobs:
                self.errors.append(f"client {client}: job id {jid} given twice")
            self.jobs[jid] = {"client": client, "combo": combo["key"], "submitted": t_submit, "state": "accepted",
                              "how": how}

    def finished(self, jid, combo, out, raw, t_submit):
        with self.lock:
            self.jobs[jid]["state"] = "fetched"
            self.latencies.append(time.time() - t_submit)
        self.verify_q.put((jid, combo, out, raw))

    def outputs(self, client, combo, tag):
        out = self.tmp / "out" / f"c{client}-{tag}.png"
        raw = self.tmp / "out" / f"c{client}-{tag}.raw" if combo["raw"] else None
        return out, raw, ["-o", out] + (["--copy-map-raw", raw] if raw else [])

    def log_size(self):
        try:
            return self.server_log.stat().st_size
        except OSError:
            return 0

    def log_text(self, start=0):
        with open(self.server_log, "rb") as f:
            f.seek(start)
            return f.read().decode(errors="replace")

    def find_queued(self, client, since):
        """After a submission that gave no id: the job the coordinator
        queued for this client since log offset `since` that the client
        never heard of (it died, or the reply was lost, before the id came
        back; each client submits one job at a time), or None. A dead
        coordinator's log is complete: no need to wait for the next one."""
        for m in re.finditer(rf"job (\d+) queued from \S+ \(soak{client}@", self.log_text(since)):
            jid = int(m.group(1))
            with self.lock:
                if jid not in self.jobs:
                    return jid
        return None

    def not_accepted(self, client, combo, p, mark, t):
        """A submission that was not queued: fine if a fault was on and it
        says why (the CLI's message); a client error otherwise."""
        why = p.stderr.strip()
        if self.fault_during(mark) and why:
            with self.lock:
                self.refusals.append({"t": round(t - self.start_time, 1), "client": client, "combo": combo["key"],
                                      "why": why[-300:], "under": self.fault_name(mark)})
            # Not while the coordinator is down (each try would fail at
            # once); under a disk fault the next submission goes ahead.
            if not self.coord_up.wait(timeout=max(0.0, self.hard_left())):
                raise HardStop()
            time.sleep(0.2)
            return
        self.client_error(client, f"synth {combo['key']} was not accepted", p)

    def job_state(self, client, jid):
        p = self.retry(client, "status", jid, timeout=30)
        if p.returncode != 0:
            return None
        for line in p.stdout.splitlines():
            f = line.split()
            if f and f[0] == str(jid):
                return f[1]
        return None

    def ended(self, client, jid, state, t_submit):
        """A job that ended failed or canceled, as its client saw it."""
        with self.lock:
            self.jobs[jid].update(state=state, ended=time.time())
        self.delete(client, jid)

    def follow(self, client, jid, combo, tag, t_submit):
        """Watches a job to its end across faults, then fetches, verifies
        and deletes it."""
        for _ in range(30):
            self.wait_well()
            mark = self.fault_mark()
            p = self.cli(client, "watch", jid, "--quiet")
            if p.returncode == 0:
                break
            st = self.job_state(client, jid)
            if st == "done":
                break
            if st in ("failed", "canceled"):
                return self.ended(client, jid, st, t_submit)
            if st in ("queued", "running") and self.fault_during(mark):
                continue  # the watch was cut by a fault
            return self.client_error(client, f"watch {jid} ({combo['key']}) ended with the job {st}", p)
        else:
            return self.client_error(client, f"gave up watching {jid} after 30 faults")
        out, raw, outargs = self.outputs(client, combo, tag)
        p = self.retry(client, "fetch", jid, *outargs, timeout=120)
        if p.returncode != 0:
            return self.client_error(client, f"fetch {jid} failed", p)
        self.finished(jid, combo, out, raw, t_submit)
        self.delete(client, jid)

    def delete(self, client, jid):
        p = self.retry(client, "delete", jid, timeout=60)
        if p.returncode != 0 and "no job" in p.stderr and re.search(rf"job {jid} deleted by", self.log_text()):
            p = subprocess.CompletedProcess(p.args, 0, "", "")  # an earlier try, cut by a fault, did it
        if p.returncode != 0:
            return self.client_error(client, f"delete {jid} failed", p)
        with self.lock:
            if self.jobs[jid]["state"] in ("accepted", "fetched"):
                self.jobs[jid]["state"] = "deleted"

    def submit(self, client, combo, args, timeout=CMD_TIMEOUT):
        """Runs a submission; (CompletedProcess, fault mark, log offset, t)."""
        since, t = self.log_size(), time.time()
        mark = self.fault_mark()
        return self.cli(client, "synth", *combo["args"], *args, timeout=timeout), mark, since, t

    def sync_job(self, client, rng, k):
        combo = rng.choice(self.combos)
        out, raw, outargs = self.outputs(client, combo, k)
        p, mark, since, t = self.submit(client, combo, outargs)
        m = re.search(r"\(job (\d+) on ", p.stderr)
        if p.returncode == 0 and m:
            jid = int(m.group(1))
            self.record(jid, client, combo, t)
            self.finished(jid, combo, out, raw, t)
            return self.delete(client, jid)
        jid = self.find_queued(client, since)
        if jid is None:
            return self.not_accepted(client, combo, p, mark, t)
        if not self.fault_during(mark):
            self.client_error(client, f"synth {combo['key']} (job {jid}) failed with no fault on", p)
        self.record(jid, client, combo, t, how="followed")
        self.follow(client, jid, combo, k, t)

    def detached_batch(self, client, rng, k):
        batch = []
        for i in range(rng.randint(1, DETACH_MAX)):
            combo = rng.choice(self.combos)
            # The outputs are named at submission (the paths are the client's,
            # unused with --detach): a raw copy map is made only if asked for.
            raw = ["--copy-map-raw", self.tmp / "unused.raw"] if combo["raw"] else []
            p, mark, since, t = self.submit(client, combo, ["-o", self.tmp / "unused.png", *raw, "--detach"],
                                            timeout=120)
            if p.returncode == 0 and p.stdout.strip().isdigit():
                jid = int(p.stdout)
                self.record(jid, client, combo, t)
            else:
                jid = self.find_queued(client, since)
                if jid is None:
                    self.not_accepted(client, combo, p, mark, t)
                    continue
                self.record(jid, client, combo, t, how="found in the log")
            batch.append((jid, combo, t))
        for i, (jid, combo, t) in enumerate(batch):
            self.follow(client, jid, combo, f"{k}-{i}", t)

    def client(self, client):
        rng = random.Random(self.a.seed * 1000 + client)
        k = 0
        try:
            while self.gate.enter():
                if client % 2 == 0:
                    self.sync_job(client, rng, k)
                else:
                    self.detached_batch(client, rng, k)
                k += 1
                if len(self.errors) > 20:
                    log(f"soak: client {client} stops: too many errors")
                    break
        except HardStop:
            pass
        except Exception as e:  # a bug of the soak itself: report, do not hang the gate
            self.client_error(client, f"soak client crashed: {e!r}")
        finally:
            self.gate.leave_for_good()

    # ---- verification

    def sha(self, path):
        return hashlib.sha256(Path(path).read_bytes()).hexdigest() if path else None

    def reference(self, combo):
        with self.ref_lock:
            if combo["key"] in self.refs:
                return self.refs[combo["key"]]
            d = self.tmp / "embedded"
            d.mkdir(exist_ok=True)
            out, raw = d / "ref.png", (d / "ref.raw" if combo["raw"] else None)
            args = [self.texsyn, "synth", "--embedded", *combo["args"], "-o", out, "--quiet"]
            if raw:
                args += ["--copy-map-raw", raw]
            p = subprocess.run([str(a) for a in args], capture_output=True, text=True, timeout=CMD_TIMEOUT)
            if p.returncode != 0:
                self.problems.append(f"embedded run of {combo['key']} failed: {p.stderr.strip()}")
                ref = (None, None)
            else:
                ref = (self.sha(out), self.sha(raw))
            self.embedded_runs += 1
            self.refs[combo["key"]] = ref
            return ref

    def verifier(self):
        while True:
            item = self.verify_q.get()
            if item is None:
                self.verify_q.task_done()
                return
            jid, combo, out, raw = item
            try:
                want = self.reference(combo)
                got = (self.sha(out), self.sha(raw))
                if got != want:
                    keep = self.tmp / "mismatch"
                    keep.mkdir(exist_ok=True)
                    shutil.copy(out, keep / f"job{jid}.png")
                    if raw:
                        shutil.copy(raw, keep / f"job{jid}.raw")
                    with self.lock:
                        self.mismatches.append(f"job {jid} ({combo['key']}): sha256 {got} != embedded {want}; "
                                               f"kept in {keep}")
                    log(f"soak: MISMATCH job {jid} ({combo['key']})")
                else:
                    with self.lock:
                        self.verified += 1
                        self.jobs[jid]["verified"] = True
                out.unlink(missing_ok=True)
                if raw:
                    raw.unlink(missing_ok=True)
            except Exception as e:
                with self.lock:
                    self.mismatches.append(f"job {jid}: could not verify: {e!r}")
            finally:
                self.verify_q.task_done()

    # ---- chaos

    def live_workers(self):
        with self.lock:
            return [w for w in self.workers if not w.killed and w.alive()]

    def kinds(self):
        """The faults this run injects, with their weights."""
        off = set()
        if not self.a.partitions:
            off |= {"partition", "half_open"}
        if not self.a.disk_faults:
            off |= {"disk_full", "disk_ro"}
        if not self.a.coordinator_kills:
            off.add("coordinator_kill")
        return {k: w for k, w in FAULT_WEIGHTS.items() if k not in off}

    def chaos(self):
        rng = random.Random(self.a.seed * 7919)
        kinds = self.kinds()
        first = [k for k in FIRST_FAULTS if k in kinds]
        n = 0
        while not self.done.wait(rng.uniform(*CHAOS_EVERY)):
            with self.chaos_lock:
                if not self.gate.open or self.done.is_set():
                    continue
                kind = first[n] if n < len(first) else rng.choices(list(kinds), weights=list(kinds.values()))[0]
                if kind == "coordinator_kill" and self.t() > COORD_KILL_UNTIL * self.a.minutes * 60:
                    kind = "worker_kill"
                n += 1
                try:
                    getattr(self, "fault_" + kind)(rng)
                except HardStop:
                    return
                except Exception as e:  # a bug of the soak itself
                    self.problems.append(f"the {kind} fault crashed the chaos thread: {e!r}")
                    return

    def victim(self, rng, may_be_sentinel):
        live = [w for w in self.live_workers() if may_be_sentinel or not w.sentinel]
        return rng.choice(live) if live else None

    def replace(self, w, rng, why):
        """A worker in w's slot: on the slot's address (dialled again) or
        by --join."""
        new = None
        if self.slot_addr[w.slot] and rng.random() < 0.5:
            new = self.start_worker(w.slot, "listen")
            if new is not None:
                self.counts["restarts_same_addr"] += 1
        if new is None:
            new = self.start_worker(w.slot, "join")
            if new is None:
                self.problems.append(f"a replacement for {w.name} ({why}) did not start: {self.events[-1][1]}")
                return None
            self.counts["joins"] += 1
        if w.proc.stdout:
            w.proc.stdout.close()
        return new

    def fault_worker_kill(self, rng):
        w = self.victim(rng, False)
        if w is None:
            return
        w.killed = True
        w.proc.send_signal(signal.SIGKILL)
        w.proc.wait()
        self.counts["worker_kill"] += 1
        delay = rng.uniform(*REPLACE_AFTER)
        self.done.wait(delay)
        new = self.replace(w, rng, "killed")
        if new:
            self.event(f"kill {w.name}; {new.name} {'on ' + new.addr if new.mode == 'listen' else 'joins'} "
                       f"{delay:.1f} s later")

    def fault_stall(self, rng):
        w = self.victim(rng, True)
        if w is None:
            return
        secs = rng.uniform(*STALL_SECONDS)
        self.event(f"stall {w.name} for {secs:.1f} s")
        w.proc.send_signal(signal.SIGSTOP)
        self.done.wait(secs)
        w.proc.send_signal(signal.SIGCONT)
        self.counts["stall"] += 1
        self.counts["stall_seconds"] += secs

    def fault_partition(self, rng):
        w = self.victim(rng, True)
        if w is None:
            return
        direction = rng.choice(netns.DIRECTIONS)
        secs = rng.uniform(*PARTITION_SECONDS)
        rec = {"kind": "partition", "worker": w.name, "slot": w.slot, "host": self.worker_host(w.slot),
               "direction": direction, "seconds": round(secs, 1), "t": round(self.t(), 1), "log_at": self.log_size()}
        self.net.partition(w.slot, direction)
        self.done.wait(secs)
        rec["dropped_packets"] = self.net.dropped(w.slot)
        self.net.heal(w.slot)
        rec["log_end"] = self.log_size()
        self.counts["partition"] += 1
        self.faults.append(rec)
        self.event(f"partition {w.name} {direction} for {secs:.1f} s (packets dropped {rec['dropped_packets']})")

    def fault_half_open(self, rng):
        w = self.victim(rng, False)
        if w is None:
            return
        rec = {"kind": "half_open", "worker": w.name, "slot": w.slot, "host": self.worker_host(w.slot),
               "t": round(self.t(), 1), "log_at": self.log_size()}
        self.net.partition(w.slot, "both")
        w.killed = True
        w.proc.send_signal(signal.SIGKILL)
        w.proc.wait()
        self.net.vanish(w.slot)
        back = rng.uniform(*HALF_OPEN_BACK)
        self.done.wait(back)
        rec["log_end"] = self.log_size()  # what the coordinator said before the host came back
        self.net.add_slot(w.slot)
        new = self.replace(w, rng, "half-open")
        rec["back_after"] = round(back, 1)
        self.counts["half_open"] += 1
        self.faults.append(rec)
        if new:
            self.event(f"half-open {w.name}: cut, killed, its namespace deleted; the host back {back:.1f} s later "
                       f"with {new.name}")

    def fault_coordinator_kill(self, rng):
        # Mid-job: wait (a little) for a job to be running.
        running = []
        deadline = time.time() + 15
        while time.time() < deadline and not self.done.is_set():
            st = self.status()
            running = sorted(j for j, s in (st or {}).items() if s == "running")
            if running:
                break
            time.sleep(0.2)
        with self.lock:
            server = self.server
            self.coord_up.clear()
            self.coord_gen += 1
        server.send_signal(signal.SIGKILL)
        server.wait()
        if server.stdout:
            server.stdout.close()
        back = rng.uniform(*COORD_BACK)
        with open(self.server_log, "a") as f:
            f.write(f"soak: the coordinator (pid {server.pid}) SIGKILLed at {self.t():.1f} s with jobs {running} "
                    f"running; started again {back:.1f} s later\n")
        time.sleep(back)
        ok = self.start_coordinator()
        self.counts["coordinator_kill"] += 1
        self.faults.append({"kind": "coordinator_kill", "t": round(self.t(), 1), "running": running,
                            "down_s": round(back, 1), "restarted": ok})
        self.event(f"coordinator SIGKILLed with jobs {running} running; started again {back:.1f} s later")
        if not ok:
            self.done.set()

    def fill_disk(self):
        """Fills the spool's filesystem to the last byte (a filler file)."""
        filler = self.spool_fs / "filler"
        fd = os.open(filler, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        try:
            for chunk in (1 << 20, 4096, 1):
                buf = b"\0" * chunk
                try:
                    while os.write(fd, buf) > 0:
                        pass
                except OSError as e:
                    if e.errno != errno.ENOSPC:
                        raise
        finally:
            os.close(fd)
        return filler.stat().st_size

    def disk_heal(self):
        netns.sh("mount", "-o", "remount,rw", self.spool_fs, check=False)
        (self.spool_fs / "filler").unlink(missing_ok=True)

    def fault_disk(self, rng, kind):
        secs = rng.uniform(*DISK_SECONDS)
        rec = {"kind": kind, "t": round(self.t(), 1), "seconds": round(secs, 1)}
        with self.lock:
            self.disk_ok.clear()
            self.disk_gen += 1
            self.disk_windows.append([self.t(), None])
        how = None
        if kind == "disk_ro":
            until = time.time() + RO_TRIES_S
            while time.time() < until:
                if netns.sh("mount", "-o", "remount,ro", self.spool_fs, check=False).returncode == 0:
                    how = "read-only"
                    break
                time.sleep(0.01)
            else:
                self.counts["ro_busy"] += 1
        if how is None:
            how = f"full ({self.fill_disk() / MiB:.1f} MiB of filler)"
        rec["how"] = how
        self.done.wait(secs)
        self.disk_heal()
        with self.lock:
            self.disk_windows[-1][1] = self.t()
            self.disk_ok.set()
        self.counts[kind] += 1
        self.faults.append(rec)
        self.event(f"disk fault: the spool's filesystem {how} for {secs:.1f} s")

    def fault_disk_full(self, rng):
        self.fault_disk(rng, "disk_full")

    def fault_disk_ro(self, rng):
        self.fault_disk(rng, "disk_ro")

    # ---- monitoring

    def spool_jobs(self):
        try:
            return len(os.listdir(self.spool / "jobs"))
        except OSError:
            return 0

    def spool_bytes(self):
        total = 0
        for root, _, files in os.walk(self.spool):
            for f in files:
                try:
                    total += os.path.getsize(os.path.join(root, f))
                except OSError:
                    pass
        return total

    def monitor(self):
        last, last_sample = time.time(), -10.0
        reported_dead = set()
        while not self.done.wait(1.0):
            t = self.t()
            with self.lock:
                server, up = self.server, self.coord_up.is_set()
            fds, rss, sj = proc_fds(server.pid), proc_mem(server.pid), self.spool_jobs()
            if up and (fds is None or rss is None or server.poll() is not None):
                with self.lock:
                    still = self.server is server and self.coord_up.is_set()
                if still:  # not our kill
                    self.problems.append(f"the coordinator exited ({server.poll()}) at {t:.0f} s")
                    log(f"soak: ERROR the coordinator exited at {t:.0f} s")
                    self.done.set()
                    return
                continue
            with self.lock:
                if fds is not None and rss is not None:
                    self.max_fds = max(self.max_fds, (fds, t))
                    self.max_rss = max(self.max_rss, (rss, t))
                self.max_spool_jobs = max(self.max_spool_jobs, sj)
                if t - last_sample >= 10 and fds is not None:
                    last_sample = t
                    self.samples.append({"t": round(t, 1), "life": self.coord_lives, "fds": fds, "rss": rss,
                                         "spool_jobs": sj})
                for w in self.workers:
                    if not w.killed and not w.alive() and w.name not in reported_dead:
                        reported_dead.add(w.name)
                        self.problems.append(f"worker {w.name} exited on its own ({w.proc.returncode}) at {t:.0f} s,"
                                             f" see its log")
                        log(f"soak: ERROR worker {w.name} exited on its own ({w.proc.returncode})")
            if time.time() - last >= PROGRESS_EVERY and fds is not None:
                last = time.time()
                self.progress(fds, rss, sj)

    def progress(self, fds, rss, sj):
        with self.lock:
            states = [j["state"] for j in self.jobs.values()]
            live = sum(1 for w in self.workers if not w.killed and w.alive())
        c = self.counts
        log(f"[{self.t():5.0f} s] jobs {len(states)} accepted, {states.count('deleted') + states.count('fetched')} "
            f"finished, {self.verified} verified, {len(self.mismatches)} mismatched, {len(self.errors)} errors, "
            f"{len(self.refusals)} not accepted under a fault | kills {c['worker_kill']} stalls {c['stall']} "
            f"partitions {c['partition']} half-open {c['half_open']} coordinator kills {c['coordinator_kill']} disk "
            f"{c['disk_full'] + c['disk_ro']} | workers {live} | coordinator {fds} fds {rss / MiB:.1f} MiB | spool "
            f"{sj} jobs")

    # ---- quiescent samples

    def pause_and_sample(self, when):
        if self.quiesce(when):
            self.snapshot(when)
        self.chaos_lock.release()
        self.gate.reopen()

    def quiesce(self, when):
        """Pauses clients and chaos, then settles; False if the clients did
        not come to the gate in time."""
        if not self.gate.drain(min(time.time() + CMD_TIMEOUT, self.hard_deadline)):
            self.problems.append(f"{when}: the clients did not pause within {CMD_TIMEOUT} s")
            self.chaos_lock.acquire()
            return False
        self.chaos_lock.acquire()
        return self.settle(when) is not None

    def settle(self, when):
        """Waits until every job has ended and the pool has its workers
        ready, then until no worker holds vectors, then for heartbeats,
        reaps and closes; returns the jobs' states (None: not settled)."""
        t0 = time.time()
        deadline = min(t0 + POOL_TIMEOUT, self.hard_deadline)
        st = None
        while time.time() < deadline:
            st = self.status()
            if st is not None and not any(s in ("queued", "running") for s in st.values()):
                break
            time.sleep(0.2)
        else:
            self.problems.append(f"{when}: jobs still queued or running after {time.time() - t0:.0f} s: "
                                 f"{st if st is not None else '`texsyn status` did not answer'}")
            return None
        if not self.wait_pool(WORKERS, when):
            return None
        deadline = min(time.time() + VECTORS_WAIT, self.hard_deadline)
        while time.time() < deadline:
            held = {w.name: self.registers(w).get("vectors") for w in self.live_workers()}
            if all(v == "0" for v in held.values()):
                break
            time.sleep(0.5)
        time.sleep(2.0)
        return st

    def registers(self, w):
        """A worker's Modbus register map by name (`texsyn modbus`), {} on failure."""
        try:
            p = self.run_cmd(self.in_coord(self.texsyn, "modbus", w.modbus), 30)
        except HardStop:
            return {}
        return dict(l.split(None, 1) for l in p.stdout.splitlines() if len(l.split(None, 1)) == 2)

    def snapshot(self, when):
        st = self.status()
        procs = {f"coordinator#{self.coord_lives}": proc_info(self.server.pid)}
        for w in self.live_workers():
            reg = self.registers(w)
            procs[w.name] = dict(proc_info(w.proc.pid), mode=w.mode, sentinel=w.sentinel, vectors=reg.get("vectors"),
                                 state=reg.get("state"), batches=reg.get("batches"), errors=reg.get("errors"))
            if reg.get("vectors") != "0":
                self.problems.append(f"{when}: worker {w.name} holds {reg.get('vectors')} reference vectors with no "
                                     f"job queued or running {VECTORS_WAIT} s on (its slices were not freed), state "
                                     f"{reg.get('state')}")
        snap = {"t": round(self.t(), 1), "procs": procs, "spool_jobs": self.spool_jobs(),
                "spool_bytes": self.spool_bytes(), "jobs_listed": len(st) if st is not None else None,
                "jobs_accepted": len(self.jobs)}
        self.measure[when] = snap
        log(f"soak: {when} sample at {snap['t']:.0f} s: "
            + ", ".join(f"{n} {p['fds']} fds {p['rss'] / MiB:.1f} MiB"
                        + (f" {p['vectors']} vectors" if "vectors" in p else "") for n, p in procs.items())
            + f"; spool {snap['spool_jobs']} jobs, {snap['spool_bytes']} bytes")
        return snap

    # ---- the run

    def run(self):
        """Everything but the report; returns when the soak is over."""
        a = self.a
        data = self.data_dir()
        self.combos = self.make_combos(data)
        (self.tmp / "out").mkdir()
        self.machine = machine()
        self.setup_host()
        log(f"soak: {a.minutes} min, {WORKERS} workers, {a.clients} clients, {len(self.combos)} distinct jobs, "
            f"faults {', '.join(self.kinds()) if not a.no_chaos else 'none'}, seed {a.seed}, hard bound "
            f"{a.minutes * 60 + a.hard_margin:.0f} s, in {self.tmp}")
        self.start_cluster()
        self.load_start = self.t()
        duration = a.minutes * 60
        warmup = a.warmup if a.warmup is not None else min(120.0, max(20.0, 0.15 * duration))
        threads = [threading.Thread(target=self.verifier, daemon=True)]
        threads.append(threading.Thread(target=self.monitor, daemon=True))
        if not a.no_chaos:
            self.chaos_thread = threading.Thread(target=self.chaos, daemon=True)
            threads.append(self.chaos_thread)
        clients = [threading.Thread(target=self.client, args=(c,), daemon=True) for c in range(a.clients)]
        self.gate.active = len(clients)
        for t in threads + clients:
            t.start()
        # Warm-up, the first sample, then one every --sample-every seconds.
        if not self.done.wait(warmup):
            self.pause_and_sample("warm-up")
            self.warm_jobs = len(self.jobs)
        every = a.sample_every if a.sample_every is not None else min(120.0, max(30.0, duration / 5))
        while not self.done.is_set():
            nxt = self.t() + every if every > 0 else duration
            if nxt > duration - every / 2:
                self.done.wait(max(0.0, duration - self.t()))
                break
            if self.done.wait(nxt - self.t()):
                break
            self.pause_and_sample(f"{self.t():.0f} s")
        # The end: stop submitting, let every job end, sample.
        log(f"soak: {self.t():.0f} s: time is up; waiting for the clients' last jobs")
        drained = self.gate.drain(self.hard_deadline)
        self.done.set()
        self.chaos_lock.acquire()
        self.gate.end()
        for t in clients:
            t.join(timeout=max(0.0, self.hard_left()))
        if not drained or any(t.is_alive() for t in clients):
            self.problems.append("the clients did not finish their last jobs before the hard bound")
        if self.settle("end") is not None:
            self.snapshot("end")
        self.verify_q.join()
        self.verify_q.put(None)
        self.final_status = {}
        for c in range(a.clients):  # as each client: a job left behind is theirs
            st = self.status(c)
            if st is None:
                self.final_status = None
                break
            self.final_status.update(st)
        self.wall = self.t()

    def hard_stop(self):
        """The hard bound passed: kill every client command still running
        (the clients then stop); the report counts what is pending as lost."""
        self.hard = True
        self.done.set()
        self.gate.end()
        self.coord_up.set()   # nobody waits for a restart any more
        self.disk_ok.set()
        with self.lock:
            kids = list(self.children)
        for p in kids:
            try:
                p.kill()
            except OSError:
                pass
        self.wall = self.t()

    def stop(self):
        """Stops the daemons (at once past the hard bound) and removes the
        namespaces and the spool's filesystem, once the chaos thread has
        finished its fault (its waits end when the soak is done)."""
        if self.chaos_thread is not None:
            self.chaos_thread.join(timeout=20)
        server = self.server
        if server is not None and server.poll() is None:
            server.send_signal(signal.SIGCONT)
            server.send_signal(signal.SIGKILL if self.hard else signal.SIGTERM)
            try:
                server.wait(timeout=30)
            except subprocess.TimeoutExpired:
                server.kill()
                server.wait()
        if server is not None and server.stdout:
            server.stdout.close()
        for w in self.workers:
            if self.hard and w.alive():
                w.proc.kill()
            w.stop()
        self.teardown_host()

    # ---- the verdict

    def server_log_figures(self):
        text = self.server_log.read_text(errors="replace")
        queued = [int(x) for x in re.findall(r"job (\d+) queued from", text)]
        done = {}
        for j, s in re.findall(r"job (\d+) done in ([0-9.]+)s", text):
            done.setdefault(int(j), []).append(float(s))
        failed = {int(j): why for j, why in re.findall(r"job (\d+) failed(?:: (.*))?", text)}
        canceled = [int(j) for j in re.findall(r"job (\d+) canceled", text)]
        deleted = [int(x) for x in re.findall(r"job (\d+) deleted by", text)]
        refused = re.findall(r"refused a job from \S+: (.*)", text)
        drops = re.findall(r"worker \d+ \(\S+\) dropped: (.*)", text)
        reasons = {}
        for d in drops:
            key = re.sub(r"[0-9.]+", "N", d)[:80]
            reasons[key] = reasons.get(key, 0) + 1
        refusal_reasons = {}
        for r in refused:
            key = re.sub(r"[0-9]+", "N", r)[:100]
            refusal_reasons[key] = refusal_reasons.get(key, 0) + 1
        return {
            "queued": queued, "done": done, "failed": failed, "canceled": canceled,
            "deleted": deleted, "refused": len(refused), "refusal_reasons": refusal_reasons,
            "drops": len(drops), "drop_reasons": reasons,
            "ready": len(re.findall(r"\) ready: scans", text)),
            "joins": len(re.findall(r"worker joining from", text)),
            "rebalances": len(re.findall(r"rebalance \d+:", text)),
            "reslices": len(re.findall(r"set \d+ generation \d+ over", text)),
            "resumed": len(re.findall(r"resuming .* from its checkpoint", text)),
            "lives": len(re.findall(r"listening on", text)),
        }

    def fault_outcomes(self):
        """What the coordinator said of each partition and half-open victim
        (its log between the fault and the heal or the host's return)."""
        text = self.server_log.read_bytes()
        out = []
        for f in self.faults:
            if f["kind"] not in ("partition", "half_open"):
                out.append(f)
                continue
            part = text[f["log_at"]:f["log_end"]].decode(errors="replace")
            why = re.findall(rf"worker \d+ \({re.escape(f['host'])}:\d+\) dropped: (.*)", part)
            out.append(dict(f, victim_dropped=bool(why), why=why[:1]))
        return out

    def history(self, lg):
        """Every accepted job's outcome, from the log and the clients."""
        with self.lock:
            jobs = {j: dict(r) for j, r in self.jobs.items()}
        accepted = set(lg["queued"]) | set(jobs)
        h = {"accepted": len(accepted), "done_once": 0, "verified": 0, "lost": [], "done_twice": [],
             "done_and_failed": [], "unverified": [], "failed_explained": [], "failed_unexplained": [],
             "failed_no_reason": [], "canceled": [], "never_claimed": sorted(set(lg["queued"]) - set(jobs)),
             "followed": sorted(j for j, r in jobs.items() if r["how"] != "given")}
        with self.lock:
            windows = [(s, e if e is not None else self.t()) for s, e in self.disk_windows]
        for j in sorted(accepted):
            d, f = len(lg["done"].get(j, [])), j in lg["failed"]
            r = jobs.get(j)
            if d == 0 and not f and j not in lg["canceled"]:
                h["lost"].append(j)
            if d > 1:
                h["done_twice"].append(j)
            if d and f:
                h["done_and_failed"].append(j)
            if d == 1 and not f:
                h["done_once"] += 1
                if r and r.get("verified"):
                    h["verified"] += 1
                else:
                    h["unverified"].append(j)
            if j in lg["canceled"]:
                h["canceled"].append(j)
            if f:
                why = (lg["failed"][j] or "").strip()
                if not why:
                    h["failed_no_reason"].append(j)
                # Explained if its life (submission to the client seeing
                # its end) overlaps a disk fault, give or take DISK_GRACE.
                t0 = r["submitted"] - self.start_time if r else None
                t1 = (r.get("ended") or time.time()) - self.start_time if r else None
                hit = r is not None and any(t0 - DISK_GRACE <= e and s <= t1 + DISK_GRACE for s, e in windows)
                (h["failed_explained"] if hit else h["failed_unexplained"]).append({"job": j, "why": why[:200]})
        return h

    def flatness(self):
        """Per process sampled at least twice: first and last fds and RSS,
        the bounds, and the slopes per 100 jobs over its samples."""
        series = {}
        for when, smp in self.measure.items():
            for name, p in smp["procs"].items():
                if p["fds"] is not None and p["rss"] is not None:
                    series.setdefault(name, []).append((when, smp["jobs_accepted"], p["fds"], p["rss"]))
        out = []
        for name, pts in series.items():
            if len(pts) < 2:
                continue
            (w0, j0, f0, r0), (w1, j1, f1, r1) = pts[0], pts[-1]
            fs, rs = slope([(j, f) for _, j, f, _ in pts]), slope([(j, r) for _, j, _, r in pts])
            out.append({"process": name, "samples": len(pts), "first": w0, "last": w1, "jobs_between": j1 - j0,
                        "fds_first": f0, "fds_last": f1, "fds_bound": f0 + FD_SLACK,
                        "rss_first": r0, "rss_last": r1, "rss_bound": r0 + RSS_SLACK,
                        "fds_per_100_jobs": None if fs is None else round(100 * fs, 3),
                        "rss_kib_per_100_jobs": None if rs is None else round(100 * rs / 1024, 1),
                        "ok": f1 <= f0 + FD_SLACK and r1 <= r0 + RSS_SLACK})
        return out

    def report(self):
        lg = self.server_log_figures()
        h = self.history(lg)
        with self.lock:
            fails = list(self.problems)
            fails += [f"client error: {e}" for e in self.errors]
            fails += [f"output differs: {m}" for m in self.mismatches]
        if self.hard:
            fails.append(f"the soak hit its hard time bound ({self.a.minutes} min + {self.a.hard_margin:.0f} s): what "
                         f"was still pending counts as lost")
        if h["lost"]:
            fails.append(f"{len(h['lost'])} accepted jobs lost (neither done nor failed): {h['lost'][:20]}")
        if h["done_twice"]:
            fails.append(f"{len(h['done_twice'])} jobs done more than once: {h['done_twice'][:20]}")
        if h["done_and_failed"]:
            fails.append(f"{len(h['done_and_failed'])} jobs both done and failed: {h['done_and_failed'][:20]}")
        if h["unverified"]:
            fails.append(f"{len(h['unverified'])} done jobs have no verified output: {h['unverified'][:20]}")
        if h["failed_unexplained"]:
            fails.append(f"{len(h['failed_unexplained'])} jobs failed with no disk fault to explain it: "
                         f"{h['failed_unexplained'][:5]}")
        if h["failed_no_reason"]:
            fails.append(f"{len(h['failed_no_reason'])} jobs failed without a reason: {h['failed_no_reason'][:20]}")
        if h["canceled"]:
            fails.append(f"{len(h['canceled'])} jobs canceled (nobody cancels here): {h['canceled'][:10]}")
        if h["never_claimed"]:
            fails.append(f"{len(h['never_claimed'])} jobs queued that no client learned of: {h['never_claimed'][:10]}")
        if self.final_status is None and not self.hard:
            fails.append("`texsyn status` failed at the end")
        elif self.final_status:
            fails.append(f"jobs left in the coordinator after every client deleted its jobs: "
                         f"{dict(list(self.final_status.items())[:20])}")
        if not self.a.no_chaos:
            missing = [k for k in self.kinds() if self.counts[k] == 0]
            if missing:
                fails.append(f"the chaos thread never injected {', '.join(missing)}: run longer")

        checks = self.flatness()
        for c in checks:
            if c["fds_last"] > c["fds_bound"]:
                fails.append(f"{c['process']}: {c['fds_last']} open fds at the {c['last']} sample, {c['fds_first']} "
                             f"at the {c['first']} one (bound first + {FD_SLACK})")
            if c["rss_last"] > c["rss_bound"]:
                fails.append(f"{c['process']}: RSS {c['rss_last'] / MiB:.1f} MiB at the {c['last']} sample, "
                             f"{c['rss_first'] / MiB:.1f} MiB at the {c['first']} one (bound + {RSS_SLACK // MiB} MiB)")
        warm, end = self.measure.get("warm-up"), self.measure.get("end")
        if warm is None or end is None:
            fails.append("no warm-up or no end sample: the run was too short or ended early")
        else:
            if not any(c["process"] == "w0" and c["first"] == "warm-up" and c["last"] == "end" for c in checks):
                fails.append("the sentinel w0 was not sampled from the warm-up to the end")
            last_coord = f"coordinator#{self.coord_lives}"
            if not any(c["process"] == last_coord for c in checks):
                fails.append(f"the last coordinator ({last_coord}) was sampled fewer than twice: run longer")
            if end["spool_jobs"] != 0:
                fails.append(f"the spool holds {end['spool_jobs']} job directories after every job was deleted")
            if end["spool_bytes"] > warm["spool_bytes"] + SPOOL_SLACK:
                fails.append(f"the spool grew from {warm['spool_bytes']} to {end['spool_bytes']} bytes with every job "
                             f"deleted (bound + {SPOOL_SLACK})")
        outstanding = sum(1 if c % 2 == 0 else DETACH_MAX for c in range(self.a.clients))
        if self.max_spool_jobs > outstanding:
            fails.append(f"the spool held {self.max_spool_jobs} jobs at once; the clients never have more than "
                         f"{outstanding} outstanding")

        done_secs = sorted(s for v in lg["done"].values() for s in v)
        lat = sorted(self.latencies)
        outcomes = self.fault_outcomes()
        parts = [f for f in outcomes if f["kind"] == "partition"]
        halves = [f for f in outcomes if f["kind"] == "half_open"]
        with self.lock:
            jobs_n = len(self.jobs)
        fig = {
            "verdict": "PASS" if not fails else "FAIL",
            "failures": fails,
            "machine": self.machine,
            "minutes": self.a.minutes, "wall_seconds": round(self.wall or self.t(), 1), "seed": self.a.seed,
            "hard_bound_seconds": self.a.minutes * 60 + self.a.hard_margin, "hit_hard_bound": self.hard,
            "clients": self.a.clients, "workers": WORKERS, "distinct_jobs": len(self.combos),
            "embedded_runs": self.embedded_runs,
            "faults_on": list(self.kinds()) if not self.a.no_chaos else [],
            "jobs": {"accepted": h["accepted"], "done_once": h["done_once"], "verified": h["verified"],
                     "lost": len(h["lost"]), "different": len(self.mismatches), "done_twice": len(h["done_twice"]),
                     "failed_with_reason_under_disk_fault": len(h["failed_explained"]),
                     "failed_unexplained": len(h["failed_unexplained"]), "canceled": len(h["canceled"]),
                     "followed_after_a_cut": len(h["followed"]), "not_accepted_under_a_fault": len(self.refusals),
                     "client_errors": len(self.errors), "deleted": len(lg["deleted"]),
                     "between_samples": jobs_n - getattr(self, "warm_jobs", jobs_n)},
            "history": h,
            "refusals": self.refusals[:50],
            "chaos": dict(self.counts, stall_seconds=round(self.counts["stall_seconds"], 1)),
            "partitions": {"n": len(parts), "by_direction": {d: sum(1 for f in parts if f["direction"] == d)
                                                             for d in netns.DIRECTIONS},
                           "longer_than_batch_deadline": sum(1 for f in parts if f["seconds"] > 2.0),
                           "victim_dropped": sum(1 for f in parts if f["victim_dropped"]),
                           "dropped_when_longer": sum(1 for f in parts if f["victim_dropped"] and f["seconds"] > 2.0),
                           "dropped_when_shorter": sum(1 for f in parts if f["victim_dropped"] and f["seconds"] <= 2.0)},
            "half_open": {"n": len(halves), "noticed_before_back": sum(1 for f in halves if f["victim_dropped"]),
                          "reasons": sorted({w for f in halves for w in f["why"]})},
            "faults": outcomes,
            "coordinator_log": {k: lg[k] for k in ("drops", "drop_reasons", "ready", "joins", "rebalances",
                                                   "reslices", "resumed", "lives", "refused", "refusal_reasons")},
            "job_seconds": {"coordinator_median": statistics.median(done_secs) if done_secs else None,
                            "coordinator_p90": done_secs[int(0.9 * (len(done_secs) - 1))] if done_secs else None,
                            "coordinator_max": done_secs[-1] if done_secs else None,
                            "client_median": statistics.median(lat) if lat else None,
                            "client_p90": lat[int(0.9 * (len(lat) - 1))] if lat else None,
                            "client_max": lat[-1] if lat else None},
            "bounds": {"fd_slack": FD_SLACK, "rss_slack": RSS_SLACK, "daemon_env": DAEMON_ENV,
                       "spool_slack": SPOOL_SLACK, "spool_outstanding_max": outstanding},
            "samples": self.measure,
            "checks": checks,
            "coordinator_max": {"fds": self.max_fds[0], "fds_at": round(self.max_fds[1], 1),
                                "rss": self.max_rss[0], "rss_at": round(self.max_rss[1], 1)},
            "max_spool_jobs": self.max_spool_jobs,
            "timeline": self.samples,
            "chaos_events": [(round(t, 1), e) for t, e in self.events],
        }
        return fig


def machine():
    info = Path("/proc/cpuinfo").read_text()

    def field(name):
        m = re.search(rf"^{name}\s*:\s*(.*)$", info, re.M)
        return m.group(1).strip() if m else "?"

    flags = sorted(set(field("flags").split()) & {"avx2", "avx512bw", "avx512_vnni"})
    mem = re.search(r"MemTotal:\s+(\d+) kB", Path("/proc/meminfo").read_text())
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True)
    dirty = subprocess.run(["git", "status", "--porcelain", "-uno"], cwd=REPO, capture_output=True, text=True)
    return {"cpu": field("model name"), "cores": os.cpu_count(),
            "family": field("cpu family"), "model": field("model"), "flags": flags,
            "memory_gib": round(int(mem.group(1)) / 2**20, 1) if mem else None,
            "loadavg_at_start": Path("/proc/loadavg").read_text().split()[:3],
            "date": time.strftime("%Y-%m-%dT%H:%MZ", time.gmtime()),
            "commit": commit.stdout.strip() or "unknown",
            # other work in the tree the binaries may have been built with
            "modified": [l[3:] for l in dirty.stdout.splitlines()]}


def text_report(f):
    m, j, c, lg, js = f["machine"], f["jobs"], f["chaos"], f["coordinator_log"], f["job_seconds"]
    L = [f"texsyn soak: {f['verdict']}", ""]
    L.append(f"machine: {m['cpu']}, {m['cores']} cores (family {m['family']}, model {m['model']}, "
             f"{' '.join(m['flags'])}), {m['memory_gib']} GiB, load average at start {' '.join(m['loadavg_at_start'])}"
             + (f", at end {' '.join(m['loadavg_at_end'])}" if m.get("loadavg_at_end") else ""))
    src = [x for x in m["modified"] if re.match(r"(common|proto|worker|server)/.*\.(c|h|cpp)$", x)]
    L.append(f"date: {m['date']}, commit {m['commit']}"
             + (f" (the tree also had uncommitted source changes: {', '.join(src)})" if src else ""))
    L.append(f"duration: {f['minutes']} min of load ({f['wall_seconds']:.0f} s wall with the drain; hard bound "
             f"{f['hard_bound_seconds']:.0f} s{', HIT' if f['hit_hard_bound'] else ', not reached'}), "
             f"{f['clients']} clients, {f['workers']} workers x 1 thread, {f['distinct_jobs']} distinct jobs "
             f"({f['embedded_runs']} embedded reference runs), seed {f['seed']}")
    L.append(f"faults on: {', '.join(f['faults_on']) or 'none'}")
    L.append("")
    L.append(f"jobs: {j['accepted']} accepted: {j['done_once']} done once, {j['verified']} byte-identical to embedded, "
             f"{j['different']} different, {j['lost']} lost, {j['done_twice']} done twice, "
             f"{j['failed_with_reason_under_disk_fault']} failed with a reason under a disk fault, "
             f"{j['failed_unexplained']} failed with no fault to explain it, {j['canceled']} canceled; "
             f"{j['followed_after_a_cut']} followed by id after a fault cut their client's command; "
             f"{j['not_accepted_under_a_fault']} submissions not accepted under a fault (none queued, a reason "
             f"given); {j['client_errors']} client errors; {j['deleted']} deleted by their clients; "
             f"{j['between_samples']} after the warm-up sample")
    L.append(f"faults: {c['worker_kill']} worker kills, {c['stall']} stalls ({c['stall_seconds']:.0f} s stopped in "
             f"all), replacements: {c['restarts_same_addr']} on the worker's address, {c['joins']} by --join")
    p = f["partitions"]
    if p["n"]:
        L.append(f"  {p['n']} partitions ({', '.join(f'{n} {d}' for d, n in p['by_direction'].items())}), "
                 f"{PARTITION_SECONDS[0]:.0f}-{PARTITION_SECONDS[1]:.0f} s: "
                 f"{p['longer_than_batch_deadline']} longer than the 2 s batch deadline, the victim dropped in "
                 f"{p['dropped_when_longer']} of those; {p['n'] - p['longer_than_batch_deadline']} shorter, the victim "
                 f"dropped in {p['dropped_when_shorter']} of those")
    ho = f["half_open"]
    if ho["n"]:
        L.append(f"  {ho['n']} half-open (cut, killed, namespace deleted): the coordinator dropped the victim before "
                 f"the host came back in {ho['noticed_before_back']} ({'; '.join(ho['reasons']) or '-'})")
    ck = [x for x in f["faults"] if x["kind"] == "coordinator_kill"]
    if ck:
        L.append(f"  {len(ck)} coordinator SIGKILLs, {sum(1 for x in ck if x['running'])} with a job running, "
                 f"down {min(x['down_s'] for x in ck):.1f}-{max(x['down_s'] for x in ck):.1f} s; "
                 f"{lg['resumed']} jobs resumed from a checkpoint")
    dk = [x for x in f["faults"] if x["kind"] in ("disk_full", "disk_ro")]
    if dk:
        L.append(f"  {len(dk)} disk faults, {sum(x['seconds'] for x in dk):.0f} s in all: "
                 f"{sum(1 for x in dk if x['how'] == 'read-only')} read-only, "
                 f"{sum(1 for x in dk if x['how'] != 'read-only')} full"
                 + (f" ({c['ro_busy']} of these meant read-only: the remount was refused while a file was open for "
                    f"writing)" if c["ro_busy"] else "")
                 + f"; the coordinator refused {lg['refused']} submissions")
        for r, n in sorted(lg["refusal_reasons"].items(), key=lambda x: -x[1])[:6]:
            L.append(f"    {n:4d} x refused: {r}")
    L.append(f"coordinator log ({lg['lives']} lives): {lg['drops']} workers dropped, {lg['ready']} workers made ready, "
             f"{lg['joins']} joins, {lg['reslices']} re-slicings, {lg['rebalances']} rebalances")
    for r, n in sorted(lg["drop_reasons"].items(), key=lambda x: -x[1]):
        L.append(f"  {n:4d} x dropped: {r}")
    fx = f["history"]["failed_explained"] + f["history"]["failed_unexplained"]
    if fx:
        L.append("failed jobs (first 8): " + "; ".join(f"{x['job']}: {x['why']}" for x in fx[:8]))

    def s(x):
        return "-" if x is None else f"{x:.2f} s"
    L.append(f"per job: coordinator run time median {s(js['coordinator_median'])}, p90 {s(js['coordinator_p90'])}, "
             f"max {s(js['coordinator_max'])}; client, submit to result written, median "
             f"{s(js['client_median'])}, p90 {s(js['client_p90'])}, max {s(js['client_max'])}")
    L.append("")
    b = f["bounds"]
    L.append(f"bounds, per process from its first quiescent sample to its last: fds <= first + {b['fd_slack']}; "
             f"RSS <= first + {b['rss_slack'] // MiB} MiB (daemons run with "
             f"{' '.join(k + '=' + v for k, v in b['daemon_env'].items())}: RSS is what they hold); slopes by least "
             f"squares over its samples; spool with every job deleted <= warm-up + {b['spool_slack'] // 1024} KiB "
             f"and no job directory; at most {b['spool_outstanding_max']} jobs in the spool at once")
    L.append(f"  {'process':14s} {'samples':>7s} {'from':>8s} {'to':>8s} {'jobs':>5s}  {'fds':>9s} {'bound':>5s} "
             f"{'/100 jobs':>9s}   {'RSS MiB':>13s} {'bound':>6s} {'KiB/100 jobs':>12s}  ok")
    for r in f["checks"]:
        fs = "-" if r["fds_per_100_jobs"] is None else f"{r['fds_per_100_jobs']:+.2f}"
        rs = "-" if r["rss_kib_per_100_jobs"] is None else f"{r['rss_kib_per_100_jobs']:+.0f}"
        L.append(f"  {r['process']:14s} {r['samples']:7d} {r['first']:>8s} {r['last']:>8s} {r['jobs_between']:5d}  "
                 f"{r['fds_first']:3d} -> {r['fds_last']:3d} {r['fds_bound']:5d} {fs:>9s}   "
                 f"{r['rss_first'] / MiB:5.1f} -> {r['rss_last'] / MiB:5.1f} {r['rss_bound'] / MiB:6.1f} {rs:>12s}  "
                 f"{'yes' if r['ok'] else 'NO'}")
    mx = f["coordinator_max"]
    L.append(f"coordinator max over the run (1 s samples, under load): {mx['fds']} fds at {mx['fds_at']:.0f} s, "
             f"{mx['rss'] / MiB:.1f} MiB at {mx['rss_at']:.0f} s")
    w, e = f["samples"].get("warm-up"), f["samples"].get("end")
    if f["samples"]:
        L.append("quiescent samples (every job ended and deleted, 3 workers ready): fds, RSS; for the workers also "
                 "the slice vectors held (must be 0)")
        for when, smp in f["samples"].items():
            cells = ", ".join(f"{n} {p['fds']} {p['rss'] / MiB:.1f} MiB" + (f" {p['vectors']} v" if "vectors" in p
                                                                            else "")
                              for n, p in smp["procs"].items())
            L.append(f"  {when:>8s} at {smp['t']:5.0f} s, {smp['jobs_accepted']:4d} jobs: {cells}")
    if w and e:
        L.append(f"spool: {w['spool_jobs']} jobs / {w['spool_bytes']} bytes after the warm-up, {e['spool_jobs']} jobs / "
                 f"{e['spool_bytes']} bytes at the end; at most {f['max_spool_jobs']} jobs at once")
    L.append("")
    if f["failures"]:
        L.append("failures:")
        L += [f"  - {x}" for x in f["failures"]]
    else:
        L.append("verdict: PASS - no accepted job lost, none different, none done twice, every failure and refusal "
                 "under a fault and with a reason; fds, RSS and the spool within their bounds")
    return "\n".join(L) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="minutes of load (default 10)")
    ap.add_argument("--build", default=str(REPO / "build"))
    ap.add_argument("--out", default=str(REPO / "bench" / "results"), help="where soak.json and soak.txt go")
    ap.add_argument("--clients", type=int, default=4)
    ap.add_argument("--combos", type=int, default=40, help="distinct jobs the clients draw from")
    ap.add_argument("--warmup", type=float, default=None,
                    help="seconds before the first sample (default 15%% of the run, 20..120 s)")
    ap.add_argument("--sample-every", type=float, default=None,
                    help="seconds between the quiescent samples after the warm-up (default a fifth of the run, "
                         "30..120 s; 0: none)")
    ap.add_argument("--no-chaos", action="store_true", help="no faults at all (to tell a leak from chaos)")
    ap.add_argument("--no-partitions", dest="partitions", action="store_false",
                    help="no partitions or half-open links (and no namespaces: all on loopback)")
    ap.add_argument("--no-disk-faults", dest="disk_faults", action="store_false",
                    help="no full or read-only spool (and no tmpfs of its own)")
    ap.add_argument("--no-coordinator-kills", dest="coordinator_kills", action="store_false")
    ap.add_argument("--hard-margin", type=float, default=HARD_MARGIN,
                    help=f"seconds past --minutes at which the soak stops whatever hangs and reports (default "
                         f"{HARD_MARGIN})")
    ap.add_argument("--seed", type=int, default=int(time.time()) % 100000)
    ap.add_argument("--keep", action="store_true", help="keep the temporary directory (kept anyway on failure)")
    a = ap.parse_args()
    if a.no_chaos:
        a.partitions = a.disk_faults = a.coordinator_kills = False
    if (a.partitions or a.disk_faults) and os.geteuid() != 0:
        sys.exit("soak: partitions (network namespaces, nft) and disk faults (a tmpfs spool) need root: run as root, "
                 "or pass --no-partitions --no-disk-faults")
    if a.partitions and netns.missing():
        sys.exit(f"soak: partitions: {netns.missing()}")
    soak = Soak(a)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit("soak: terminated"))
    crashed = []

    def body():
        try:
            soak.run()
        except HardStop:
            pass
        except BaseException as e:  # noqa: B036  reported, and the soak still cleans up
            crashed.append(repr(e))

    fig = None
    try:
        th = threading.Thread(target=body, daemon=True)
        th.start()
        th.join(timeout=max(0.0, soak.hard_left()))
        if th.is_alive():
            log(f"soak: the hard bound ({a.minutes} min + {a.hard_margin:.0f} s) passed: stopping what still runs")
            soak.hard_stop()
            th.join(timeout=10)
        if crashed:
            soak.problems.append(f"the soak itself crashed: {crashed[0]}")
        if getattr(soak, "combos", None) is not None and getattr(soak, "server_log", None) is not None:
            fig = soak.report()
            write_report(fig, Path(a.out))
    except KeyboardInterrupt:
        print(f"soak: interrupted; logs in {soak.tmp}")
        raise
    finally:
        soak.done.set()
        soak.gate.end()
        soak.stop()
    if fig is None:
        sys.exit(f"soak: did not get as far as starting the cluster: {soak.problems or crashed}; logs in {soak.tmp}")
    if fig["verdict"] != "PASS" or a.keep:
        print(f"soak: logs and spool kept in {soak.tmp}")
        sys.exit(1 if fig["verdict"] != "PASS" else 0)
    shutil.rmtree(soak.tmp, ignore_errors=True)


def write_report(fig, out):
    out.mkdir(parents=True, exist_ok=True)
    fig["machine"]["loadavg_at_end"] = Path("/proc/loadavg").read_text().split()[:3]
    (out / "soak.json").write_text(json.dumps(fig, indent=1) + "\n")
    txt = text_report(fig)
    (out / "soak.txt").write_text(txt)
    print(txt, end="")

if __name__ == "__main__":
    main()
