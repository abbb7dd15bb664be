#!/usr/bin/python3
"""Soak: hundreds of small jobs for --minutes (10) against a coordinator with
3 workers, while a chaos thread kills, stalls and replaces workers. Not part
of `make test`; `make soak SOAK_MINUTES=N` runs it.

What runs (all on loopback, in a temporary directory):
  * texsyn-server --workers w0,w1,w2 with its default options (heartbeat 2 s,
    batch timeout 2 s, 2 jobs at once): the soak tests the daemon as deployed.
  * 3 texsyn-worker --listen --threads 1 --modbus (their register map says
    how many reference vectors they hold; the coordinator supervises them
    over it too). w0 is the sentinel: it may be stalled but is never killed,
    so at least one worker lives from the warm-up sample to the end and its
    fds and RSS can be compared. The daemons run with a fixed glibc mmap
    threshold (DAEMON_ENV, see the bounds below) so that RSS measures what
    they hold, not what the allocator keeps for reuse.
  * --clients (4) clients, each a thread running the real CLI as its own
    user (USER=soakN): even clients run `texsyn synth --server` and wait for
    the result; odd ones submit 1 to 4 jobs with --detach, then `watch`,
    `fetch` each. Every client then `texsyn delete`s the job it fetched, as a
    real client would, so the spool must stay small.
  * Jobs are drawn from a pool of --combos (40) distinct small jobs: brick,
    grass or aero1 (tests/test-data.sh), 64x48 to 128x96, 2 or 3 levels,
    W_N 5 or 7, random seeds, --rgb-search, --parity, a usage penalty and a
    raw copy map on some. A verifier thread runs each distinct job once with
    `texsyn synth --embedded` (cached by its parameters) and compares every
    fetched output, image and raw copy map, byte for byte.
  * A chaos thread, every 4 to 16 s: SIGKILL a random worker (not w0), or
    SIGSTOP one for 1 to 6 s then SIGCONT (shorter than the 2 s batch
    deadline floor: the batch just waits; longer: the worker is dropped, its
    batch is asked again of the others, and the worker comes back). A killed
    worker is replaced 0.5 to 4 s later, either on its own address (a --listen
    worker: the coordinator dials its --workers addresses again every 0.5 s)
    or by a new `texsyn-worker --join` (the way a worker joins a running
    coordinator). The first event is a kill, the second a stall.

Measured at quiescent points, after the warm-up, every --sample-every (120)
seconds and at the end: the clients and the chaos thread are paused, every
job has ended and has been deleted, and the pool has its 3 workers ready
again. Then the coordinator's and every surviving worker's open fds
(/proc/PID/fd) and RSS (/proc/PID/status VmRSS), the vectors each worker
holds (must be 0) and the spool's size are taken. The bounds compare the
end with the warm-up; the samples between show the trend. A monitor thread
also samples the coordinator every second (the max is reported) and prints a
progress line every 30 s.

The run fails (exit status 1, the reasons listed) if a job is lost, failed or
refused, an output differs from the embedded run, a client command fails or
hangs, the coordinator or a worker we did not kill exits, the pool does not
come back to 3 ready workers, or a bound below is exceeded.

Writes OUT/soak.json and OUT/soak.txt (default bench/results).
Usage: bench/soak.py [--minutes 10] [--build build] [--out bench/results]
"""
import argparse
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
MiB = 1 << 20

# ---- the bounds -------------------------------------------------------------
#
# Both samples are taken at a quiescent point with the same pool (3 workers
# connected, no job queued or running, no client connected but the
# sampler's), so a daemon that frees what it is done with has the same set
# of fds at both. The only legitimate differences are transient: a dial of a
# dead --workers address in flight (at most one per address the coordinator
# was started with, 3), a connection whose peer has closed and that the
# daemon has not reaped yet, a checkpoint or result file being written.
# FD_SLACK = 8 covers those with room to spare, while a leak of one fd per
# job (hundreds between the samples) or per worker failure (dozens in 10
# minutes) overshoots it by far.
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
# of jobs between the samples overshoots it. The bound is warm-up + 16 MiB.
RSS_SLACK = 16 * MiB
DAEMON_ENV = {"MALLOC_MMAP_THRESHOLD_": "131072"}
# The spool: at both samples every job has been deleted, so the spool holds
# its bookkeeping only (last-id, an empty jobs/). Its bytes may differ by the
# width of the last id; SPOOL_SLACK = 64 KiB. During the run, at most every
# client's outstanding jobs (1 for a waiting client, up to DETACH_MAX for a
# detached one) can be in the spool at once; the max seen is checked too.
SPOOL_SLACK = 64 * 1024
DETACH_MAX = 4

WORKERS = 3
CHAOS_EVERY = (4.0, 16.0)      # seconds between chaos events
STALL_SECONDS = (1.0, 6.0)     # SIGSTOP .. SIGCONT
REPLACE_AFTER = (0.5, 4.0)     # a killed worker's replacement starts this much later
KILL_SHARE = 0.6               # of the events after the first two; the rest are stalls
POOL_TIMEOUT = 90              # seconds for the pool to have its workers ready again
CMD_TIMEOUT = 600              # seconds for one client command: past it, the job counts as hung
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
    p = subprocess.Popen([str(a) for a in args], stdout=subprocess.PIPE, stderr=open(log_path, "a"), text=True, env=env)
    line = p.stdout.readline()
    m = re.search(want, line)
    if not m:
        p.kill()
        p.wait()
        p.stdout.close()
        return None, f"{args[0]} did not start: {line!r}, see {log_path}", None
    mb = re.search(r"modbus (?:on )?([0-9.]+:\d+)", line)
    return p, m.group(1), mb.group(1) if mb else None


class Worker:
    def __init__(self, name, proc, mode, addr, modbus, log_path, sentinel=False):
        self.name, self.proc, self.mode, self.addr, self.log_path = name, proc, mode, addr, log_path
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
    thread still running waits at it."""

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

    def drain(self):
        with self.cv:
            self.open = False
            while self.waiting < self.active:
                self.cv.wait()

    def reopen(self):
        with self.cv:
            self.open = True
            self.cv.notify_all()

    def end(self):
        with self.cv:
            self.finish = True
            self.cv.notify_all()


# ---- the soak -----------------------------------------------------------------

class Soak:
    def __init__(self, a):
        self.a = a
        self.build = Path(a.build).resolve()
        self.texsyn = self.build / "texsyn"
        self.rng = random.Random(a.seed)
        self.tmp = Path(tempfile.mkdtemp(prefix="texsyn-soak-"))
        self.spool = self.tmp / "spool"
        self.lock = threading.Lock()
        self.gate = Gate()
        self.chaos_lock = threading.Lock()
        self.done = threading.Event()      # the soak's time is up
        self.workers = []                  # every Worker ever started
        self.next_worker = 0
        self.jobs = {}                     # id -> record
        self.errors = []                   # client-side failures (strings)
        self.problems = []                 # unexpected daemon exits etc.
        self.mismatches = []
        self.refs = {}                     # combo key -> (png sha, raw sha or None)
        self.ref_lock = threading.Lock()
        self.verify_q = queue.Queue()
        self.verified = 0
        self.embedded_runs = 0
        self.counts = {"kills": 0, "stalls": 0, "restarts_same_addr": 0, "joins": 0, "stall_seconds": 0.0}
        self.events = []                   # (t, what)
        self.samples = []                  # coordinator timeline
        self.max_fds = (0, 0.0)
        self.max_rss = (0, 0.0)
        self.max_spool_jobs = 0
        self.latencies = []                # client-side seconds, submit to result
        self.measure = {}

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

    def worker_args(self, name, mode, addr):
        where = ["--listen", addr] if mode == "listen" else ["--join", self.server_addr]
        return [self.build / "texsyn-worker", *where, "--threads", 1, "--name", name, "--modbus", "127.0.0.1:0"]

    def start_worker(self, mode, addr="127.0.0.1:0", sentinel=False):
        """A listen worker (on addr) or a join worker; None if it did not start."""
        name = f"w{self.next_worker}"
        self.next_worker += 1
        log_path = self.tmp / f"{name}.log"
        want = r"listening on (\S+)" if mode == "listen" else r"modbus on (\S+)"
        p, got, modbus = start_daemon(self.worker_args(name, mode, addr), log_path, want)
        if p is None:
            self.events.append((self.t(), f"{name}: {got}"))
            return None
        w = Worker(name, p, mode, got if mode == "listen" else None, modbus, log_path, sentinel)
        with self.lock:
            self.workers.append(w)
        return w

    def start_cluster(self):
        self.t0 = time.time()
        first = [self.start_worker("listen", sentinel=(i == 0)) for i in range(WORKERS)]
        if None in first:
            sys.exit(f"soak: a worker did not start: {self.events}")
        self.server_log = self.tmp / "server.log"
        args = [self.build / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", self.spool,
                "--workers", ",".join(w.addr for w in first)]
        self.server, addr, _ = start_daemon(args, self.server_log)
        if self.server is None:
            sys.exit(f"soak: {addr}")
        self.server_addr = addr
        self.wait_pool(WORKERS, "at start")

    def t(self):
        return time.time() - self.t0

    # ---- client commands

    def cli(self, client, *args, timeout=CMD_TIMEOUT):
        env = dict(os.environ)
        env.pop("TEXSYN_SERVER", None)
        env["USER"] = f"soak{client}"
        argv = [str(self.texsyn), *map(str, args), "--server", self.server_addr]
        try:
            return subprocess.run(argv, capture_output=True, text=True, env=env, timeout=timeout)
        except subprocess.TimeoutExpired:  # the child is killed; the caller reports a hang
            return subprocess.CompletedProcess(argv, -1, "", f"no answer within {timeout} s (hung)")

    def pool(self):
        """[(addr, state)] from `texsyn workers`; None if the call failed."""
        p = self.cli("-", "workers", timeout=30)
        if p.returncode != 0:
            return None
        rows = []
        for line in p.stdout.splitlines()[1:]:
            f = line.split()
            if len(f) == 8 and f[1].isdigit():
                rows.append((f[0], f[6]))
        return rows

    def status(self):
        """{id: state} of every job the coordinator lists; None on failure."""
        p = self.cli("-", "status", timeout=30)
        if p.returncode != 0:
            return None
        return {int(f[0]): f[1] for f in (l.split() for l in p.stdout.splitlines()) if f and f[0].isdigit()}

    def wait_pool(self, n, when):
        deadline = time.time() + POOL_TIMEOUT
        rows = None
        while time.time() < deadline:
            rows = self.pool()
            if rows is not None and sum(1 for _, s in rows if s == "ready") >= n:
                return True
            time.sleep(0.2)
        self.problems.append(f"{when}: the pool did not get {n} ready workers back within {POOL_TIMEOUT} s: {rows}")
        return False

    def client_error(self, client, what, p=None):
        msg = f"client {client}: {what}"
        if p is not None:
            msg += f" (exit {p.returncode}): {p.stderr.strip()[-500:]}"
        with self.lock:
            self.errors.append(msg)
        log(f"soak: ERROR {msg}")

    def record(self, jid, client, combo, t_submit):
        with self.lock:
            if jid in self.jobs:
                self.errors.append(f"client {client}: job id {jid} given twice")
            self.jobs[jid] = {"client": client, "combo": combo["key"], "submitted": t_submit, "state": "accepted"}

    def finished(self, jid, combo, out, raw, t_submit):
        with self.lock:
            self.jobs[jid]["state"] = "fetched"
            self.latencies.append(time.time() - t_submit)
        self.verify_q.put((jid, combo, out, raw))

    def outputs(self, client, combo, tag):
        out = self.tmp / "out" / f"c{client}-{tag}.png"
        raw = self.tmp / "out" / f"c{client}-{tag}.raw" if combo["raw"] else None
        return out, raw, ["-o", out] + (["--copy-map-raw", raw] if raw else [])

    def delete(self, client, jid):
        p = self.cli(client, "delete", jid, timeout=60)
        if p.returncode != 0:
            return self.client_error(client, f"delete {jid} failed", p)
        with self.lock:
            self.jobs[jid]["state"] = "deleted"

    def sync_job(self, client, rng, k):
        combo = rng.choice(self.combos)
        out, raw, outargs = self.outputs(client, combo, k)
        t = time.time()
        p = self.cli(client, "synth", *combo["args"], *outargs)
        m = re.search(r"\(job (\d+) on ", p.stderr)
        if m:
            self.record(int(m.group(1)), client, combo, t)
        if p.returncode != 0 or not m:
            return self.client_error(client, f"synth {combo['key']} failed", p)
        jid = int(m.group(1))
        self.finished(jid, combo, out, raw, t)
        self.delete(client, jid)

    def detached_batch(self, client, rng, k):
        batch = []
        for i in range(rng.randint(1, DETACH_MAX)):
            combo = rng.choice(self.combos)
            t = time.time()
            # The outputs are named at submission (the paths are the client's,
            # unused with --detach): a raw copy map is made only if asked for.
            raw = ["--copy-map-raw", self.tmp / "unused.raw"] if combo["raw"] else []
            p = self.cli(client, "synth", *combo["args"], "-o", self.tmp / "unused.png", *raw, "--detach", timeout=120)
            if p.returncode != 0 or not p.stdout.strip().isdigit():
                self.client_error(client, f"synth --detach {combo['key']} failed, printed {p.stdout!r}", p)
                continue
            jid = int(p.stdout)
            self.record(jid, client, combo, t)
            batch.append((jid, combo, t))
        for i, (jid, combo, t) in enumerate(batch):
            p = self.cli(client, "watch", jid, "--quiet")
            if p.returncode != 0:
                self.client_error(client, f"watch {jid} ({combo['key']}) did not end done", p)
                continue
            out, raw, outargs = self.outputs(client, combo, f"{k}-{i}")
            p = self.cli(client, "fetch", jid, *outargs, timeout=120)
            if p.returncode != 0:
                self.client_error(client, f"fetch {jid} failed", p)
                continue
            self.finished(jid, combo, out, raw, t)
            self.delete(client, jid)

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

    def chaos(self):
        rng = random.Random(self.a.seed * 7919)
        n = 0
        while not self.done.wait(rng.uniform(*CHAOS_EVERY)):
            with self.chaos_lock:
                if not self.gate.open or self.done.is_set():
                    continue
                kill = n == 0 or (n > 1 and rng.random() < KILL_SHARE)
                live = self.live_workers()
                victims = [w for w in live if not (kill and w.sentinel)]
                if not victims:
                    continue
                w = rng.choice(victims)
                n += 1
                if kill:
                    self.kill(w, rng)
                else:
                    secs = rng.uniform(*STALL_SECONDS)
                    self.events.append((self.t(), f"stall {w.name} for {secs:.1f} s"))
                    w.proc.send_signal(signal.SIGSTOP)
                    self.done.wait(secs)
                    w.proc.send_signal(signal.SIGCONT)
                    self.counts["stalls"] += 1
                    self.counts["stall_seconds"] += secs

    def kill(self, w, rng):
        w.killed = True
        w.proc.send_signal(signal.SIGKILL)
        w.proc.wait()
        self.counts["kills"] += 1
        delay = rng.uniform(*REPLACE_AFTER)
        time.sleep(delay)
        new = None
        if w.mode == "listen" and rng.random() < 0.5:
            new = self.start_worker("listen", w.addr)
            if new is not None:
                self.counts["restarts_same_addr"] += 1
        if new is None:
            new = self.start_worker("join")
            if new is None:
                self.problems.append(f"a replacement for {w.name} did not start: {self.events[-1][1]}")
                return
            self.counts["joins"] += 1
        self.events.append((self.t(), f"kill {w.name}; {new.name} {'on ' + new.addr if new.mode == 'listen' else 'joins'}"
                                      f" {delay:.1f} s later"))
        if w.proc.stdout:
            w.proc.stdout.close()

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
            fds, rss, sj = proc_fds(self.server.pid), proc_mem(self.server.pid), self.spool_jobs()
            if fds is None or rss is None or self.server.poll() is not None:
                self.problems.append(f"the coordinator exited ({self.server.poll()}) at {t:.0f} s")
                log(f"soak: ERROR the coordinator exited at {t:.0f} s")
                self.done.set()
                return
            with self.lock:
                self.max_fds = max(self.max_fds, (fds, t))
                self.max_rss = max(self.max_rss, (rss, t))
                self.max_spool_jobs = max(self.max_spool_jobs, sj)
                if t - last_sample >= 10:
                    last_sample = t
                    self.samples.append({"t": round(t, 1), "fds": fds, "rss": rss, "spool_jobs": sj})
                for w in self.workers:
                    if not w.killed and not w.alive() and w.name not in reported_dead:
                        reported_dead.add(w.name)
                        self.problems.append(f"worker {w.name} exited on its own ({w.proc.returncode}) at {t:.0f} s,"
                                             f" see its log")
                        log(f"soak: ERROR worker {w.name} exited on its own ({w.proc.returncode})")
            if time.time() - last >= PROGRESS_EVERY:
                last = time.time()
                self.progress(fds, rss, sj)

    def progress(self, fds, rss, sj):
        with self.lock:
            states = [j["state"] for j in self.jobs.values()]
            live = sum(1 for w in self.workers if not w.killed and w.alive())
        log(f"[{self.t():5.0f} s] jobs {len(states)} accepted, {states.count('deleted') + states.count('fetched')} "
            f"finished, {self.verified} verified, {len(self.mismatches)} mismatched, {len(self.errors)} errors | "
            f"kills {self.counts['kills']} stalls {self.counts['stalls']} replacements "
            f"{self.counts['restarts_same_addr'] + self.counts['joins']} | workers {live} | coordinator "
            f"{fds} fds {rss / MiB:.1f} MiB | spool {sj} jobs")

    # ---- quiescent samples

    def pause_and_sample(self, when):
        self.quiesce(when)
        self.snapshot(when)
        self.chaos_lock.release()
        self.gate.reopen()

    def quiesce(self, when):
        """Pauses clients and chaos, waits until every job has ended and the
        pool has its workers ready; returns the chaos lock's holder state."""
        self.gate.drain()
        self.chaos_lock.acquire()
        return self.settle(when)

    def settle(self, when):
        """Waits until every job has ended and the pool has its workers
        ready, then for heartbeats, reaps and closes; returns the jobs'
        states."""
        deadline = time.time() + POOL_TIMEOUT
        st = None
        while time.time() < deadline:
            st = self.status()
            if st is not None and not any(s in ("queued", "running") for s in st.values()):
                break
            time.sleep(0.2)
        else:
            self.problems.append(f"{when}: jobs still queued or running after {POOL_TIMEOUT} s: {st}")
        self.wait_pool(WORKERS, when)
        time.sleep(2.0)
        return st

    def registers(self, w):
        """A worker's Modbus register map by name (`texsyn modbus`), {} on failure."""
        try:
            p = subprocess.run([str(self.texsyn), "modbus", w.modbus], capture_output=True, text=True, timeout=30)
        except subprocess.TimeoutExpired:
            return {}
        return dict(l.split(None, 1) for l in p.stdout.splitlines() if len(l.split(None, 1)) == 2)

    def snapshot(self, when):
        st = self.status()
        procs = {"coordinator": proc_info(self.server.pid)}
        for w in self.live_workers():
            reg = self.registers(w)
            procs[w.name] = dict(proc_info(w.proc.pid), mode=w.mode, sentinel=w.sentinel, vectors=reg.get("vectors"),
                                 state=reg.get("state"), batches=reg.get("batches"), errors=reg.get("errors"))
            if reg.get("vectors") != "0":
                self.problems.append(f"{when}: worker {w.name} holds {reg.get('vectors')} reference vectors with no "
                                     f"job queued or running (its slices were not freed), state {reg.get('state')}")
        snap = {"t": round(self.t(), 1), "procs": procs, "spool_jobs": self.spool_jobs(),
                "spool_bytes": self.spool_bytes(), "jobs_listed": len(st) if st is not None else None,
                "jobs_accepted": len(self.jobs)}
        self.measure[when] = snap
        c = procs["coordinator"]
        log(f"soak: {when} sample at {snap['t']:.0f} s: coordinator {c['fds']} fds, {c['rss'] / MiB:.1f} MiB; "
            f"spool {snap['spool_jobs']} jobs, {snap['spool_bytes']} bytes; workers "
            + ", ".join(f"{n} {p['fds']} fds {p['rss'] / MiB:.1f} MiB {p['vectors']} vectors"
                        for n, p in procs.items() if n != "coordinator"))
        return snap

    # ---- the run

    def run(self):
        a = self.a
        data = self.data_dir()
        self.combos = self.make_combos(data)
        (self.tmp / "out").mkdir()
        self.machine = machine()
        log(f"soak: {a.minutes} min, {WORKERS} workers, {a.clients} clients, {len(self.combos)} distinct jobs, "
            f"seed {a.seed}, in {self.tmp}")
        self.start_cluster()
        duration = a.minutes * 60
        warmup = a.warmup if a.warmup is not None else min(120.0, max(20.0, 0.15 * duration))
        threads = [threading.Thread(target=self.verifier, daemon=True)]
        threads.append(threading.Thread(target=self.monitor, daemon=True))
        if not a.no_chaos:
            threads.append(threading.Thread(target=self.chaos, daemon=True))
        clients = [threading.Thread(target=self.client, args=(c,), daemon=True) for c in range(a.clients)]
        self.gate.active = len(clients)
        for t in threads + clients:
            t.start()
        # Warm-up, the first sample, then one every --sample-every seconds
        # (the trend; the bounds compare the warm-up sample with the end).
        if not self.done.wait(warmup):
            self.pause_and_sample("warm-up")
            self.warm_jobs = len(self.jobs)
        every = a.sample_every
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
        self.gate.drain()
        self.done.set()
        self.chaos_lock.acquire()
        self.gate.end()
        for t in clients:
            t.join(timeout=CMD_TIMEOUT + 60)
        self.settle("end")
        self.snapshot("end")
        self.verify_q.join()
        self.verify_q.put(None)
        self.final_status = self.status()
        self.wall = self.t()
        return self.report()

    def stop(self):
        if getattr(self, "server", None) is not None and self.server.poll() is None:
            self.server.send_signal(signal.SIGTERM)
            try:
                self.server.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.server.kill()
                self.server.wait()
        if getattr(self, "server", None) is not None and self.server.stdout:
            self.server.stdout.close()
        for w in self.workers:
            w.stop()

    # ---- the verdict

    def server_log_figures(self):
        text = self.server_log.read_text(errors="replace")
        queued = [int(x) for x in re.findall(r"job (\d+) queued from", text)]
        done = re.findall(r"job (\d+) done in ([0-9.]+)s", text)
        failed = re.findall(r"job (\d+) failed(?:: (.*))?", text)
        canceled = re.findall(r"job (\d+) canceled", text)
        deleted = [int(x) for x in re.findall(r"job (\d+) deleted by", text)]
        refused = re.findall(r"refused a job from .*", text)
        drops = re.findall(r"worker \d+ \(\S+\) dropped: (.*)", text)
        reasons = {}
        for d in drops:
            key = re.sub(r"[0-9.]+", "N", d)[:80]
            reasons[key] = reasons.get(key, 0) + 1
        return {
            "queued": queued, "done": {int(j): float(s) for j, s in done}, "failed": failed, "canceled": canceled,
            "deleted": deleted, "refused": refused, "drops": len(drops), "drop_reasons": reasons,
            "ready": len(re.findall(r"\) ready: scans", text)),
            "joins": len(re.findall(r"worker joining from", text)),
            "rebalances": len(re.findall(r"rebalance \d+:", text)),
            "reslices": len(re.findall(r"set \d+ generation \d+ over", text)),
            "resumed": len(re.findall(r"resuming .* from its checkpoint", text)),
        }

    def report(self):
        lg = self.server_log_figures()
        fails = list(self.problems)
        fails += [f"client error: {e}" for e in self.errors]
        fails += [f"output differs: {m}" for m in self.mismatches]
        ids = set(self.jobs)
        if sorted(lg["queued"]) != sorted(ids):
            fails.append(f"the coordinator queued {len(lg['queued'])} jobs, the clients were given {len(ids)} ids: "
                         f"only queued {sorted(set(lg['queued']) - ids)[:20]}, only given {sorted(ids - set(lg['queued']))[:20]}")
        not_done = sorted(set(lg["queued"]) - set(lg["done"]))
        if not_done:
            fails.append(f"{len(not_done)} accepted jobs never finished: {not_done[:20]}")
        if lg["failed"]:
            fails.append(f"{len(lg['failed'])} jobs failed: {lg['failed'][:10]}")
        if lg["canceled"]:
            fails.append(f"{len(lg['canceled'])} jobs canceled: {lg['canceled'][:10]}")
        if lg["refused"]:
            fails.append(f"{len(lg['refused'])} submissions refused: {lg['refused'][:5]}")
        unverified = sorted(j for j, r in self.jobs.items() if not r.get("verified"))
        if unverified:
            fails.append(f"{len(unverified)} accepted jobs have no verified output: {unverified[:20]}")
        if self.final_status is None:
            fails.append("`texsyn status` failed at the end")
        elif self.final_status:
            fails.append(f"jobs left in the coordinator after every client deleted its jobs: "
                         f"{dict(list(self.final_status.items())[:20])}")
        if not self.a.no_chaos and (self.counts["kills"] == 0 or self.counts["stalls"] == 0):
            fails.append(f"the chaos thread did too little ({self.counts['kills']} kills, {self.counts['stalls']} "
                         f"stalls): run longer")

        bounds = []
        warm, end = self.measure.get("warm-up"), self.measure.get("end")
        if warm is None or end is None:
            fails.append("no warm-up sample: the run was too short or ended early")
        else:
            for name, w in warm["procs"].items():
                e = end["procs"].get(name)
                if e is None:
                    continue  # killed between the samples
                fd_bound = w["fds"] + FD_SLACK
                rss_bound = w["rss"] + RSS_SLACK
                ok_fd, ok_rss = e["fds"] <= fd_bound, e["rss"] <= rss_bound
                bounds.append({"process": name, "fds_warm": w["fds"], "fds_end": e["fds"], "fds_bound": fd_bound,
                               "rss_warm": w["rss"], "rss_end": e["rss"], "rss_bound": rss_bound,
                               "ok": ok_fd and ok_rss})
                if not ok_fd:
                    fails.append(f"{name}: {e['fds']} open fds at the end, {w['fds']} after the warm-up "
                                 f"(bound {fd_bound} = warm-up + {FD_SLACK})")
                if not ok_rss:
                    fails.append(f"{name}: RSS {e['rss'] / MiB:.1f} MiB at the end, {w['rss'] / MiB:.1f} MiB after the "
                                 f"warm-up (bound {rss_bound / MiB:.1f} MiB)")
            if "coordinator" not in end["procs"] or not any(b["process"] != "coordinator" for b in bounds):
                fails.append("no worker lived from the warm-up sample to the end")
            if end["spool_jobs"] != 0:
                fails.append(f"the spool holds {end['spool_jobs']} job directories after every job was deleted")
            if end["spool_bytes"] > warm["spool_bytes"] + SPOOL_SLACK:
                fails.append(f"the spool grew from {warm['spool_bytes']} to {end['spool_bytes']} bytes with every job "
                             f"deleted (bound + {SPOOL_SLACK})")
        outstanding = sum(1 if c % 2 == 0 else DETACH_MAX for c in range(self.a.clients))
        if self.max_spool_jobs > outstanding:
            fails.append(f"the spool held {self.max_spool_jobs} jobs at once; the clients never have more than "
                         f"{outstanding} outstanding")

        done_secs = sorted(lg["done"].values())
        lat = sorted(self.latencies)
        fig = {
            "verdict": "PASS" if not fails else "FAIL",
            "failures": fails,
            "machine": self.machine,
            "minutes": self.a.minutes, "wall_seconds": round(self.wall, 1), "seed": self.a.seed,
            "clients": self.a.clients, "workers": WORKERS, "distinct_jobs": len(self.combos),
            "embedded_runs": self.embedded_runs,
            "jobs": {"accepted": len(ids), "finished": len(lg["done"]), "verified": self.verified,
                     "failed": len(lg["failed"]), "canceled": len(lg["canceled"]), "refused": len(lg["refused"]),
                     "mismatched": len(self.mismatches), "client_errors": len(self.errors),
                     "deleted": len(lg["deleted"]),
                     "between_samples": len(ids) - getattr(self, "warm_jobs", len(ids))},
            "chaos": dict(self.counts, stall_seconds=round(self.counts["stall_seconds"], 1)),
            "coordinator_log": {k: lg[k] for k in ("drops", "drop_reasons", "ready", "joins", "rebalances",
                                                   "reslices", "resumed")},
            "job_seconds": {"coordinator_median": statistics.median(done_secs) if done_secs else None,
                            "coordinator_p90": done_secs[int(0.9 * (len(done_secs) - 1))] if done_secs else None,
                            "coordinator_max": done_secs[-1] if done_secs else None,
                            "client_median": statistics.median(lat) if lat else None,
                            "client_p90": lat[int(0.9 * (len(lat) - 1))] if lat else None,
                            "client_max": lat[-1] if lat else None},
            "bounds": {"fd_slack": FD_SLACK, "rss_slack": RSS_SLACK, "daemon_env": DAEMON_ENV,
                       "spool_slack": SPOOL_SLACK, "spool_outstanding_max": outstanding},
            "samples": self.measure,
            "checks": bounds,
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
             f"{' '.join(m['flags'])}), {m['memory_gib']} GiB, load average at start {' '.join(m['loadavg_at_start'])}")
    src = [x for x in m["modified"] if re.match(r"(common|proto|worker|server)/.*\.(c|h|cpp)$", x)]
    L.append(f"date: {m['date']}, commit {m['commit']}"
             + (f" (the tree also had uncommitted source changes: {', '.join(src)})" if src else ""))
    L.append(f"duration: {f['minutes']} min of load ({f['wall_seconds']:.0f} s wall with the drain), "
             f"{f['clients']} clients, {f['workers']} workers x 1 thread, {f['distinct_jobs']} distinct jobs "
             f"({f['embedded_runs']} embedded reference runs), seed {f['seed']}")
    L.append("")
    L.append(f"jobs: {j['accepted']} accepted, {j['finished']} finished, {j['verified']} byte-identical to embedded, "
             f"{j['failed']} failed, {j['canceled']} canceled, {j['refused']} refused, {j['mismatched']} mismatched, "
             f"{j['client_errors']} client errors; {j['deleted']} deleted by their clients; "
             f"{j['between_samples']} between the warm-up and the end samples")
    L.append(f"chaos: {c['kills']} kills, {c['stalls']} stalls ({c['stall_seconds']:.0f} s stopped in all), "
             f"replacements: {c['restarts_same_addr']} on the killed worker's address, {c['joins']} by --join")
    L.append(f"coordinator log: {lg['drops']} workers dropped (a drop mid-batch re-asks the batch of the others), "
             f"{lg['ready']} workers made ready, {lg['joins']} joins, {lg['reslices']} re-slicings, "
             f"{lg['rebalances']} rebalances")
    for r, n in sorted(lg["drop_reasons"].items(), key=lambda x: -x[1]):
        L.append(f"  {n:4d} x dropped: {r}")

    def s(x):
        return "-" if x is None else f"{x:.2f} s"
    L.append(f"per job: coordinator run time median {s(js['coordinator_median'])}, p90 {s(js['coordinator_p90'])}, "
             f"max {s(js['coordinator_max'])}; client, submit to result written, median "
             f"{s(js['client_median'])}, p90 {s(js['client_p90'])}, max {s(js['client_max'])}")
    L.append("")
    b = f["bounds"]
    L.append(f"bounds: fds <= warm-up + {b['fd_slack']}; RSS <= warm-up + {b['rss_slack'] // MiB} MiB (daemons run with "
             f"{' '.join(k + '=' + v for k, v in b['daemon_env'].items())}: RSS is what they hold); spool with every job deleted <= warm-up + {b['spool_slack'] // 1024} KiB "
             f"and no job directory; at most {b['spool_outstanding_max']} jobs in the spool at once")
    L.append(f"  {'process':12s} {'fds warm':>8s} {'end':>5s} {'bound':>6s}   {'RSS warm':>9s} {'end':>9s} "
             f"{'bound':>9s}  ok")
    for r in f["checks"]:
        L.append(f"  {r['process']:12s} {r['fds_warm']:8d} {r['fds_end']:5d} {r['fds_bound']:6d}   "
                 f"{r['rss_warm'] / MiB:7.1f}Mi {r['rss_end'] / MiB:7.1f}Mi {r['rss_bound'] / MiB:7.1f}Mi  "
                 f"{'yes' if r['ok'] else 'NO'}")
    mx = f["coordinator_max"]
    L.append(f"coordinator max over the run (1 s samples, under load): {mx['fds']} fds at {mx['fds_at']:.0f} s, "
             f"{mx['rss'] / MiB:.1f} MiB at {mx['rss_at']:.0f} s")
    w, e = f["samples"].get("warm-up"), f["samples"].get("end")
    if f["samples"]:
        L.append("quiescent samples (every job ended and deleted, 3 workers ready): fds, RSS; for the workers also "
                 "the slice vectors held (must be 0)")
        L.append(f"  {'sample':>8s} {'at s':>5s} {'jobs':>5s}  {'coordinator':>17s}  {'w0 (sentinel)':>21s}  "
                 f"other workers")
        for when, smp in f["samples"].items():
            c, w0 = smp["procs"]["coordinator"], smp["procs"].get("w0")
            others = [(n, p) for n, p in smp["procs"].items() if n not in ("coordinator", "w0")]
            cell0 = "-" if w0 is None else f"{w0['fds']:3d} {w0['rss'] / MiB:6.1f} MiB {w0['vectors']:>3s} v"
            rest = ", ".join(f"{n} {p['fds']} {p['rss'] / MiB:.1f} MiB {p['vectors']} v" for n, p in others)
            L.append(f"  {when:>8s} {smp['t']:5.0f} {smp['jobs_accepted']:5d}  {c['fds']:3d} {c['rss'] / MiB:7.1f} MiB  "
                     f"{cell0:>21s}  {rest}")
    if w and e:
        L.append(f"spool: {w['spool_jobs']} jobs / {w['spool_bytes']} bytes after the warm-up, {e['spool_jobs']} jobs / "
                 f"{e['spool_bytes']} bytes at the end; at most {f['max_spool_jobs']} jobs at once")
    L.append("")
    if f["failures"]:
        L.append("failures:")
        L += [f"  - {x}" for x in f["failures"]]
    else:
        L.append("verdict: PASS - no job lost or failed, every output byte-identical to embedded, fds, RSS and the "
                 "spool within their bounds")
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
    ap.add_argument("--sample-every", type=float, default=120.0,
                    help="seconds between the quiescent samples after the warm-up (default 120; 0: none)")
    ap.add_argument("--no-chaos", action="store_true", help="no kills or stalls (to tell a leak from chaos)")
    ap.add_argument("--seed", type=int, default=int(time.time()) % 100000)
    ap.add_argument("--keep", action="store_true", help="keep the temporary directory (kept anyway on failure)")
    a = ap.parse_args()
    soak = Soak(a)
    fig = None
    try:
        fig = soak.run()
    except KeyboardInterrupt:
        print(f"soak: interrupted; logs in {soak.tmp}")
        raise
    finally:
        soak.done.set()
        soak.gate.end()
        soak.stop()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    fig["machine"]["loadavg_at_end"] = Path("/proc/loadavg").read_text().split()[:3]
    (out / "soak.json").write_text(json.dumps(fig, indent=1) + "\n")
    txt = text_report(fig)
    (out / "soak.txt").write_text(txt)
    print(txt, end="")
    if fig["verdict"] != "PASS" or a.keep:
        print(f"soak: logs and spool kept in {soak.tmp}")
        sys.exit(1 if fig["verdict"] != "PASS" else 0)
    shutil.rmtree(soak.tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
