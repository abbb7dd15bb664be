"""Fault injection: workers killed, stalled past the batch deadline or
restarted at random moments of a job, all workers killed, the coordinator
killed and restarted, and a loopback proxy that delays, slices, stalls or
resets the worker connections. Every job must finish with the bytes of
the fault-free run.

Trials: TEXSYN_FAULT_TRIALS (default 6; `make test-faults` runs 20),
seeded by TEXSYN_FAULT_SEED (default 2004) so a failing trial can be
replayed: its seed, fault, victim and moment are in the assertion text."""
import os
import random
import signal
import socket
import threading
import time

import pytest

from conftest import (BUILD, Daemon, FRAME_START, LoopbackProxy, SANITIZED, dropped_during_the_job, modbus_registers,
                      shutdown_all, synth)

TRIALS = int(os.environ.get("TEXSYN_FAULT_TRIALS", "6"))
SEED = int(os.environ.get("TEXSYN_FAULT_SEED", "2004"))
# Under ASan+UBSan (about 10x slower) a smaller job still spans every fault.
SIZE = (192, 144) if SANITIZED else (384, 288)
JOB = ["--size", "%dx%d" % SIZE, "--usage-weight", "1"]
# Short deadlines so a stall is detected quickly; calibration kept short.
SERVER_ARGS = ["--batch-timeout", "0.5", "--calibrate-ms", "50", "--heartbeat", "0.5"]
STALL = 1.5  # seconds a stopped worker stays stopped: past the 0.5 s deadline


def ref_of(data):
    return data / "textures" / "brick.png"


@pytest.fixture(scope="module")
def expected(texsyn, data, tmp_path_factory):
    """The fault-free result and how long a 3-worker cluster takes for it."""
    out = tmp_path_factory.mktemp("expected") / "expected.png"
    synth(texsyn, ref_of(data), out, SIZE, *JOB[2:])
    return out.read_bytes()


def submit(cluster, data, out):
    """Starts `texsyn synth --server` in the background; returns the Popen."""
    import subprocess
    args = [BUILD / "texsyn", "synth", "--server", cluster.server.addr, "--ref", ref_of(data), "-o", out,
            *JOB, "--quiet"]
    return subprocess.Popen([str(a) for a in args], stderr=subprocess.PIPE, text=True)


def finish(proc, timeout=300):
    _, err = proc.communicate(timeout=timeout)
    return proc.returncode, err


def restart_worker(cluster, w, name):
    """A new worker process on the dead one's address."""
    fresh = Daemon([BUILD / "texsyn-worker", "--listen", w.addr, "--threads", 1, "--name", name],
                   cluster.tmp / f"{name}.log")
    cluster.workers.append(fresh)
    return fresh


def inject(cluster, fault, victim, rng):
    w = cluster.workers[victim]
    if fault == "kill":
        w.proc.send_signal(signal.SIGKILL)
    elif fault == "stall":
        w.proc.send_signal(signal.SIGSTOP)
        time.sleep(STALL)
        w.proc.send_signal(signal.SIGCONT)
    elif fault == "restart":
        w.proc.send_signal(signal.SIGKILL)
        w.proc.wait()
        time.sleep(rng.uniform(0, 0.3))
        restart_worker(cluster, w, f"restarted{victim}")


# Batches each worker answers in the fault-free job (3 workers; the count
# is the job's, not the machine's): faults land in the first half of it.
JOB_BATCHES = 488 if SANITIZED else 778


def wait_until_answered(w, batches, what, timeout=120):
    """Waits, by the worker's own counters, until it has answered `batches`
    batches and holds a slice; returns the vectors it holds."""
    deadline = time.time() + timeout
    while time.time() < deadline:
        regs = modbus_registers(w.modbus)
        if int(regs["batches"]) >= batches and int(regs["vectors"]) > 0:
            return int(regs["vectors"])
        time.sleep(0.01)
    raise AssertionError(f"{what}: the victim never answered {batches} batches holding a slice")


@pytest.mark.parametrize("trial", [pytest.param(t, marks=pytest.mark.sanitize) if t < 1 else t
                                   for t in range(TRIALS)])
def test_random_worker_fault_keeps_the_bytes(data, cluster, tmp_path, expected, trial):
    """The fault comes at a moment the victim itself reports: after a
    random number of its batches, while it holds a slice (Modbus), so
    every trial takes work away from the job; the coordinator must say it
    noticed, stalls included."""
    rng = random.Random(SEED * 1000 + trial)
    fault = rng.choice(["kill", "stall", "restart"])
    victim = rng.randrange(3)
    after = int(rng.uniform(0.03, 0.45) * JOB_BATCHES)
    what = f"seed {SEED} trial {trial}: {fault} worker {victim} after {after} batches"
    for _ in range(3):
        cluster.worker(1, "--modbus", "0")
    cluster.start(0, 1, *SERVER_ARGS)
    out = tmp_path / "out.png"
    job = submit(cluster, data, out)
    held = wait_until_answered(cluster.workers[victim], after, what)
    assert job.poll() is None, f"{what}: the job ended before the fault"
    inject(cluster, fault, victim, rng)
    code, err = finish(job)
    log = cluster.server.read_log()
    assert code == 0, f"{what}: job failed: {err}\n{log}"
    assert out.read_bytes() == expected, f"{what}: output differs from the fault-free run"
    assert cluster.server.alive(), what
    assert held > 0, what
    addr = cluster.workers[victim].addr
    assert any("dropped" in line and addr in line for line in log.splitlines()), \
        f"{what}: the coordinator never noticed\n{log}"


@pytest.mark.sanitize
def test_all_workers_killed_coordinator_finishes_alone(data, cluster, tmp_path, expected):
    cluster.start(3, 1, *SERVER_ARGS)
    out = tmp_path / "out.png"
    job = submit(cluster, data, out)
    cluster.server.wait_log(r"job \d+: checkpoint after level 3 ")  # the workers have done a level's work
    assert job.poll() is None, "the job ended before the workers were killed"
    for w in cluster.workers:
        w.proc.send_signal(signal.SIGKILL)
    code, err = finish(job)
    assert code == 0, err
    assert out.read_bytes() == expected
    assert cluster.pool() == []


def wait_for(path, timeout=60):
    deadline = time.time() + timeout
    while not path.exists():
        assert time.time() < deadline, f"{path} never appeared"
        time.sleep(0.01)


@pytest.mark.sanitize
def test_coordinator_killed_mid_job_resumes_after_restart(data, cluster, tmp_path, expected):
    """kill -9 of the coordinator once a job has checkpointed a level: a new
    coordinator on the same spool resumes it from that level, still serves
    the job finished before the crash, and clients watch and fetch both by
    id - same bytes."""
    cluster.start(2, 1, *SERVER_ARGS)
    finished = cluster.texsyn("synth", "--ref", ref_of(data), "-o", tmp_path / "first.png", *JOB, "--detach")
    first_id = finished.stdout.split()[-1]
    cluster.texsyn("watch", first_id, "--quiet", timeout=300)
    p = cluster.texsyn("synth", "--ref", ref_of(data), "-o", tmp_path / "unused.png", *JOB, "--detach")
    job_id = p.stdout.split()[-1]
    wait_for(cluster.tmp / "spool" / "jobs" / job_id / "checkpoint")
    cluster.server.proc.send_signal(signal.SIGKILL)
    cluster.server.proc.wait()
    cluster.server.stop()
    args = [BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", cluster.tmp / "spool",
            "--workers", ",".join(w.addr for w in cluster.workers), *SERVER_ARGS]
    cluster.server = Daemon(args, cluster.tmp / "server2.log")
    w = cluster.texsyn("watch", job_id, "--quiet", check=False, timeout=300)
    log = cluster.server.read_log()
    assert w.returncode == 0, w.stderr + log
    assert f"job {job_id}: resuming after level" in log, log
    for jid in (first_id, job_id):
        out = tmp_path / f"out{jid}.png"
        cluster.texsyn("fetch", jid, "-o", out)
        assert out.read_bytes() == expected, f"job {jid}"
    assert not (cluster.tmp / "spool" / "jobs" / job_id / "checkpoint").exists()


# ---- a fault-injecting proxy ----------------------------------------------

class Proxy(LoopbackProxy):
    """Forwards one loopback port to a worker, damaging the coordinator's
    connection on the way: `delay` (2 ms per piece), `pieces` (every
    read forwarded in writes of 1, 2, ..., 7 bytes in turn, so frames and
    their headers arrive cut at every offset), `stall` (forwarding stops for STALL s once, mid-job),
    `reset` (the connection is reset once after some traffic: 30 kB to the
    worker, mid-job now that queries travel as positions)."""

    def __init__(self, target, mode):
        self.mode = mode
        self.damaged = threading.Event()
        super().__init__(target)

    def forward(self, a, b):
        for s in (a, b):
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        threading.Thread(target=self.pump, args=(a, b, True), daemon=True).start()
        threading.Thread(target=self.pump, args=(b, a, False), daemon=True).start()

    def pump(self, src, dst, to_worker):
        sent = 0
        try:
            while True:
                data = src.recv(65536)
                if not data:
                    break
                sent += len(data)
                # Past the calibration, at a batch of queries ('V'): a
                # stall there meets the batch deadline, not a slice load's.
                armed = to_worker and not self.damaged.is_set() and sent > 30_000 and FRAME_START + b"V" in data
                if self.mode == "reset" and armed:
                    self.damaged.set()
                    for s in (src, dst):
                        s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
                        s.close()
                    return
                if self.mode == "stall" and armed:
                    self.damaged.set()
                    time.sleep(STALL)
                if self.mode == "delay":
                    time.sleep(0.002)
                if self.mode == "pieces":
                    i = k = 0
                    while i < len(data):
                        n, k = k % 7 + 1, k + 1
                        dst.sendall(data[i:i + n])
                        i += n
                else:
                    dst.sendall(data)
        except OSError:
            pass
        shutdown_all(src, dst)


@pytest.mark.parametrize("mode", ["delay", "pieces", "stall", pytest.param("reset", marks=pytest.mark.sanitize)])
def test_damaging_proxy_keeps_the_bytes(data, cluster, tmp_path, expected, mode):
    workers = [cluster.worker(1) for _ in range(2)]
    proxy = Proxy(workers[0].addr, mode)
    try:
        args = [BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                "--workers", f"{proxy.addr},{workers[1].addr}", *SERVER_ARGS]
        cluster.server = Daemon(args, tmp_path / "server.log")
        cluster.wait_ready(2)
        out = tmp_path / "out.png"
        code, err = finish(submit(cluster, data, out))
        assert code == 0, err
        assert out.read_bytes() == expected
        if mode in ("stall", "reset"):
            assert proxy.damaged.is_set(), "the proxy never got to damage the connection"
            # The coordinator knows the damaged worker by the proxy's address;
            # a reset reads as a reset, a broken pipe or a close, by timing.
            why = dropped_during_the_job(cluster.server.read_log(), proxy.addr)
            assert mode == "reset" or why == "no answer before the batch deadline", why
    finally:
        proxy.close()
