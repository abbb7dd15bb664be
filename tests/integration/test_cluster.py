"""The cluster: a coordinator and workers on loopback give the embedded
run's exact bytes, size slices by calibrated rate, serve several clients at
once and survive peers that speak garbage."""
import errno
import os
import signal
import socket
import struct
import subprocess
import threading
import time

import pytest

from conftest import BUILD, Daemon, FRAME_START, LoopbackProxy, SANITIZED, jobs_listed, run, shutdown_all, synth

# Under ASan+UBSan (several times slower) a smaller job takes the same paths.
SIZE = (192, 144) if SANITIZED else (256, 192)


def ref_of(data):
    return data / "textures" / "brick.png"


def embedded(texsyn, data, tmp_path, *extra, name="embedded", ref=None):
    out = tmp_path / f"{name}.png"
    raw = tmp_path / f"{name}.raw"
    synth(texsyn, ref or ref_of(data), out, SIZE, "--copy-map-raw", raw, *extra)
    return out.read_bytes(), raw.read_bytes()


def remote(cluster, data, tmp_path, *extra, name="remote", ref=None):
    out = tmp_path / f"{name}.png"
    raw = tmp_path / f"{name}.raw"
    report = tmp_path / f"{name}.json"
    w, h = SIZE
    cluster.texsyn("synth", "--ref", ref or ref_of(data), "-o", out, "--size", f"{w}x{h}", "--quiet",
                   "--copy-map-raw", raw, "--report", report, *extra)
    return out.read_bytes(), raw.read_bytes()


# Under ASan+UBSan only the 2-worker case runs: the others add time, not code.
# 1, 3 and 16 workers are covered, on four jobs, by test_golden.py.
@pytest.mark.parametrize("nworkers", [0, pytest.param(2, marks=pytest.mark.sanitize)])
def test_cluster_output_is_byte_identical_to_embedded(texsyn, data, cluster, tmp_path, nworkers):
    want = embedded(texsyn, data, tmp_path)
    cluster.start(nworkers, 1)
    got = remote(cluster, data, tmp_path)
    assert got[0] == want[0], "image differs from the embedded run"
    assert got[1] == want[1], "copy map differs from the embedded run"
    if nworkers:
        assert all(w["batches"] > 0 for w in cluster.pool()), "a worker never answered"


# The colour case searches the aerial photograph's three channels: the
# textures are grey, and on them --rgb-search would search one.
@pytest.mark.parametrize("extra", [["--parity"], ["--usage-weight", "2"], ["--rgb-search", "--levels", "4"]])
def test_unequal_workers_match_embedded_with_parity_usage_colour(texsyn, data, cluster, tmp_path, extra):
    ref = data / "aerial" / "aero1.jpg" if "--rgb-search" in extra else ref_of(data)
    want = embedded(texsyn, data, tmp_path, *extra, ref=ref)
    cluster.worker(1)
    cluster.worker(2)
    cluster.worker(1)
    cluster.start()
    assert remote(cluster, data, tmp_path, *extra, ref=ref) == want


class Throttle:
    """Holds a process to a fraction of its speed, like a cgroup CPU quota:
    SIGSTOP/SIGCONT cycles of 4 ms, `running` of each one running. The
    cycle is shorter than a scan, so scans see the slowdown (a worker's
    rate is its own scan time). A busy loop pinned beside a worker does not
    slow it mid-job: the scheduler favours the worker, which sleeps between
    batches, whenever it wakes."""

    CYCLE = 0.004

    def __init__(self, pid, running=0.5):
        self.pid, self.on, self.running = pid, True, running
        self.thread = threading.Thread(target=self.run)
        self.thread.start()

    def run(self):
        while self.on:
            os.kill(self.pid, signal.SIGSTOP)
            time.sleep(self.CYCLE * (1 - self.running))
            os.kill(self.pid, signal.SIGCONT)
            time.sleep(self.CYCLE * self.running)

    def stop(self):
        self.on = False
        self.thread.join()
        os.kill(self.pid, signal.SIGCONT)


def rebalances(cluster):
    return cluster.server.read_log().count("rebalance ")


def vectors_held(worker):
    """The reference vectors a worker holds in slices: its Modbus register."""
    out = run(BUILD / "texsyn", "modbus", worker.modbus).stdout
    return int(dict(line.split(" ", 1) for line in out.splitlines())["vectors"])


def test_slow_worker_gets_a_proportionally_smaller_slice(data, cluster, tmp_path):
    """What the workers really hold, read from their Modbus `vectors`
    registers while the finest level's set is loaded, divides the
    reference in proportion to their calibrated rates."""
    for _ in range(2):
        cluster.worker(1, "--modbus", "0")
    slow = Throttle(cluster.workers[1].proc.pid)
    try:
        cluster.start(0, 1, "--rebalance-after", "3600")  # keep the calibrated slicing
        p = subprocess.Popen([str(BUILD / "texsyn"), "synth", "--server", cluster.server.addr, "--ref",
                              ref_of(data), "-o", tmp_path / "out.png", "--size", "512x384", "--quiet"],
                             stderr=subprocess.PIPE, text=True)
        most = [0, 0]  # the largest loading seen: the finest level's
        while p.poll() is None:
            held = [vectors_held(w) for w in cluster.workers]
            if sum(held) > sum(most):
                most = held
    finally:
        slow.stop()
    assert p.wait() == 0, p.stderr.read()
    p.stderr.close()
    pool = cluster.pool()
    fast, slow = pool[0], pool[1]
    # Held to half speed, the second worker calibrates at about half the
    # rate; the noisy shared machine gets a wide margin.
    assert slow["calibrated"] < 0.75 * fast["calibrated"], pool
    assert [w["rate"] for w in pool] == [w["calibrated"] for w in pool]
    assert min(most) > 0, f"never saw both workers holding vectors: {most}"
    # Slices are whole rows of the finest reference (512 of them): the
    # fraction held is the rate's to within a few rows.
    total = fast["rate"] + slow["rate"]
    for w, held in zip(pool, most):
        assert abs(held / sum(most) - w["rate"] / total) < 0.02, (most, pool)
    assert most[1] < most[0], most


class Slowed:
    """What run_slowed saw: seconds from the throttle's start to the job's
    end; whether the job was still running when the throttle was lifted;
    the batches the throttled worker answered while throttled (its scans
    measured the slowdown: a throttle on an idle worker proves nothing)."""

    def __init__(self, elapsed, running, batches):
        self.elapsed, self.running, self.batches = elapsed, running, batches


def run_slowed(cluster, data, tmp_path, slow_seconds, running, size=(2048, 1536)):
    """A long job; once both workers have answered its batches, worker 2
    runs at `running` of its speed for slow_seconds (or until the job ends)."""
    w, h = size
    p = subprocess.Popen([str(BUILD / "texsyn"), "synth", "--server", cluster.server.addr, "--ref",
                          ref_of(data), "-o", tmp_path / "long.png", "--size", f"{w}x{h}", "--quiet",
                          "--parity"], stderr=subprocess.PIPE, text=True)
    while p.poll() is None and not all(x["batches"] > 0 for x in cluster.pool()):
        time.sleep(0.05)
    before = cluster.pool()[1]["batches"]
    assert p.poll() is None, "the job ended before the worker was throttled"
    slow = Throttle(cluster.workers[1].proc.pid, running)
    t0 = time.time()
    while p.poll() is None and time.time() - t0 < slow_seconds:
        time.sleep(0.05)
    still = p.poll() is None
    answered = cluster.pool()[1]["batches"] - before
    slow.stop()
    p.wait(timeout=600)
    assert p.returncode == 0, p.stderr.read()
    p.stderr.close()
    return Slowed(time.time() - t0, still, answered)


@pytest.mark.long  # 25 s of measured slowdown: make test-faults
def test_sustained_slowdown_rebalances(data, cluster, tmp_path):
    cluster.start(2, 1, "--rebalance-after", "2")
    # At a quarter of its speed the worker's scans measure well below the
    # other's (2 workers: a deviation of about 0.45 from their mean)
    s = run_slowed(cluster, data, tmp_path, 600, 0.25)
    assert s.elapsed > 3, "job too short to show a sustained slowdown"
    assert s.batches > 0, "the throttled worker answered no batch while throttled"
    assert rebalances(cluster) >= 1, cluster.server.read_log()
    pool = cluster.pool()
    assert pool[1]["share"] < 0.8 * pool[0]["share"], pool


def test_one_second_spike_does_not_rebalance(data, cluster, tmp_path):
    """The spike hits the job, not an idle worker: the job runs through it
    with the throttled worker answering batches (a rebalance on a spike
    would come during it)."""
    cluster.start(2, 1, "--rebalance-after", "3")
    s = run_slowed(cluster, data, tmp_path, 1.0, 0.25, size=(1536, 1152))  # twice --rebalance-after beyond the spike
    assert s.running, "the job ended during the spike: it proves nothing"
    assert s.batches > 0, "the throttled worker answered no batch during the spike"
    assert rebalances(cluster) == 0, cluster.server.read_log()


class DelayProxy(LoopbackProxy):
    """A slower link: every piece of data waits 5 ms, both ways."""

    def forward(self, a, b):
        for src, dst in ((a, b), (b, a)):
            threading.Thread(target=self.pump, args=(src, dst), daemon=True).start()

    @staticmethod
    def pump(src, dst):
        while True:
            try:
                data = src.recv(65536)
                if not data:
                    break
                time.sleep(0.005)
                dst.sendall(data)
            except OSError:
                break
        shutdown_all(src, dst)


@pytest.mark.long  # 25 s behind a throttled link: make test-faults
def test_worker_behind_a_slow_link_keeps_its_share(texsyn, data, cluster, tmp_path):
    """Rates come from the workers' own scan times: 5 ms more per round trip
    does not make a worker slower at scanning, so no rebalance may shrink
    its share (end to end, it lost share at every rebalance)."""
    near = cluster.worker(1)
    far = DelayProxy(cluster.worker(1).addr)
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                             "--rebalance-after", "1", "--rebalance-from", "batches",
                             "--workers", f"{near.addr},{far.addr}"], tmp_path / "server.log")
    cluster.wait_ready(2)
    # Some 15 s of batches on the delayed link: many chances to rebalance.
    cluster.texsyn("synth", "--ref", ref_of(data), "-o", tmp_path / "out.png", "--size", "384x288", "--quiet")
    after = {w["addr"]: w for w in cluster.pool()}
    far_now = after[far.addr]
    assert far_now["rate"] > 0.7 * far_now["calibrated"], (after, cluster.server.read_log())
    assert far_now["share"] > 0.35 * 100, (after, cluster.server.read_log())


def test_several_clients_at_once(texsyn, data, cluster, tmp_path):
    seeds = [1, 2, 3, 4]
    want = {s: embedded(texsyn, data, tmp_path, "--seed", s, name=f"e{s}") for s in seeds}
    cluster.start(2, 1)
    got, errors = {}, []

    def client(seed):
        try:
            got[seed] = remote(cluster, data, tmp_path, "--seed", seed, name=f"r{seed}")
        except Exception as e:  # reported below
            errors.append(e)

    threads = [threading.Thread(target=client, args=(s,)) for s in seeds]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    for s in seeds:
        assert got[s] == want[s], f"seed {s} differs"


def test_detach_status_watch_fetch(texsyn, data, cluster, tmp_path):
    want = embedded(texsyn, data, tmp_path)
    cluster.start(1, 1)
    w, h = SIZE
    p = cluster.texsyn("synth", "--ref", ref_of(data), "-o", tmp_path / "x.png", "--size", f"{w}x{h}",
                       "--detach", "--copy-map-raw", tmp_path / "x.raw")
    job = p.stdout.strip()
    assert job.isdigit(), p.stdout
    cluster.texsyn("watch", job, "--quiet")
    assert " done" in cluster.texsyn("status", job).stdout
    cluster.texsyn("fetch", job, "-o", tmp_path / "f.png", "--copy-map-raw", tmp_path / "f.raw")
    assert (tmp_path / "f.png").read_bytes() == want[0]
    assert (tmp_path / "f.raw").read_bytes() == want[1]
    listing = cluster.texsyn("status").stdout
    assert job in listing
    bad = cluster.texsyn("fetch", "999", "-o", tmp_path / "n.png", check=False)
    assert bad.returncode == 1 and "no job 999" in bad.stderr


@pytest.mark.sanitize
def test_submission_cut_short_by_a_crash_does_not_block_the_next(texsyn, data, cluster, tmp_path):
    """A coordinator killed mid-upload leaves a job directory without its
    spec: never acknowledged, removed on restart - and its id must not be
    handed to the next job."""
    partial = tmp_path / "spool" / "jobs" / "1"
    partial.mkdir(parents=True)
    (partial / "ref.png").write_bytes(ref_of(data).read_bytes())
    cluster.start()
    args = ["--ref", ref_of(data), "--size", "64x48", "--levels", "3"]
    p = cluster.texsyn("synth", *args, "-o", tmp_path / "x.png", "--detach")
    job = p.stdout.strip()
    assert job == "2", p.stdout
    assert not partial.exists(), "the cut-short submission's files stayed in the spool"
    cluster.texsyn("watch", job, "--quiet")
    assert [(r["id"], r["state"]) for r in jobs_listed(cluster.texsyn("status").stdout)] == [("2", "done")]
    cluster.texsyn("fetch", job, "-o", tmp_path / "f.png")
    run(texsyn, "synth", *args, "-o", tmp_path / "e.png", "--quiet", "--embedded")
    assert (tmp_path / "f.png").read_bytes() == (tmp_path / "e.png").read_bytes()


@pytest.mark.sanitize
def test_status_lists_every_job_of_a_long_spool(data, cluster, tmp_path):
    """A spool with 1500 finished jobs, and one more submitted: `texsyn
    status` lists them all, the newest included."""
    cluster.start()
    args = ["--ref", ref_of(data), "--size", "64x48", "--levels", "3", "-o", tmp_path / "x.png"]
    cluster.texsyn("synth", *args, "--quiet")
    cluster.server.stop()
    jobs = tmp_path / "spool" / "jobs"
    for i in range(2, 1501):  # copies of job 1, the reference hard-linked
        d = jobs / str(i)
        d.mkdir()
        for f in (jobs / "1").iterdir():
            os.link(f, d / f.name)
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool"],
                            tmp_path / "server2.log")
    newest = cluster.texsyn("synth", *args, "--detach").stdout.strip()
    assert newest == "1501", newest
    rows = jobs_listed(cluster.texsyn("status").stdout)
    assert [int(r["id"]) for r in rows] == list(range(1, 1502)), rows[-3:]
    assert all(r["state"] == "done" for r in rows[:1500])


def test_cancel_a_running_job(data, cluster, tmp_path):
    cluster.start(1, 1)
    p = cluster.texsyn("synth", "--ref", ref_of(data), "-o", tmp_path / "big.png", "--size", "2048x2048",
                       "--detach")
    job = p.stdout.strip()
    deadline = time.time() + 30
    while "running" not in cluster.texsyn("status", job).stdout and time.time() < deadline:
        time.sleep(0.05)
    cluster.texsyn("cancel", job)
    w = cluster.texsyn("watch", job, "--quiet", check=False)
    assert w.returncode == 1 and "canceled" in w.stdout + w.stderr
    again = cluster.texsyn("cancel", job, check=False)
    assert again.returncode == 1 and "already canceled" in again.stderr


def test_bad_job_gets_a_clear_error_and_the_server_goes_on(data, cluster, tmp_path):
    cluster.start(1, 1)
    p = cluster.texsyn("synth", "--ref", ref_of(data), "-o", tmp_path / "x.png", "--size", "64x64",
                       "--wb", "4", check=False)
    assert p.returncode == 2 and "--wb 4: need an odd number in 1..15" in p.stderr, p.stderr
    notimg = tmp_path / "fake.png"
    notimg.write_bytes(b"not an image at all" * 10)
    p = cluster.texsyn("synth", "--ref", notimg, "-o", tmp_path / "y.png", "--size", "64x64", check=False)
    assert p.returncode == 1, p.stderr
    # What it is not, and its first bytes ("not an i"): the user sees which file is wrong and why.
    assert f"{notimg}: not a PNG, JPEG, TIFF or OpenEXR image (starts with bytes 6e 6f 74 20 61 6e 20 69)" \
        in p.stderr, p.stderr
    assert " queued " not in cluster.server.read_log(), "a bad job reached the queue"
    remote(cluster, data, tmp_path)  # still serving


# ---- protocol robustness ----------------------------------------------------

def frame(t, payload=b"", ident=1, magic=b"TS", version=FRAME_START[2], length=None):
    n = len(payload) if length is None else length
    return magic + bytes([version]) + t.encode() + struct.pack("<II", n, ident) + payload


def ident_payload(role):
    name = b"fake-peer"
    return struct.pack("<BIHB", role, 7, 0, 0) + struct.pack("<H", len(name)) + name


BAD_STREAMS = {
    "garbage": b"GET / HTTP/1.1\r\nHost: x\r\n\r\n" * 4,
    "bad_version": frame("I", ident_payload(3), version=9),
    "version_1_peer": frame("I", ident_payload(3), version=1),
    "oversized_length": frame("I", b"", length=0xFFFFFFF0),
    "truncated_then_close": frame("I", ident_payload(3))[:15],
    "bad_first_message": frame("V", b"\x00" * 40),
    "malformed_ident": frame("I", b"\x03\x00"),
    "nul_in_name": frame("I", struct.pack("<BIHB", 3, 0, 0, 0) + b"\x03\x00a\x00b"),
}


def send_bad(addr, data, one_byte=False):
    """Sends a stream (whole, or a byte per write), then reads until the
    peer closes; the peer may close early, right at the first bad byte, and
    then even shutdown() finds the connection gone (ENOTCONN)."""
    host, port = addr.rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=10) as s:
        try:
            if one_byte:
                for b in data:
                    s.sendall(bytes([b]))
            else:
                s.sendall(data)
            s.shutdown(socket.SHUT_WR)
            while s.recv(4096):
                pass
        except (ConnectionResetError, BrokenPipeError, socket.timeout):
            pass
        except OSError as e:
            if e.errno != errno.ENOTCONN:
                raise


# Not under ASan+UBSan: reassembly from 1-byte writes runs there in
# test_frame (unit) and fuzz_frame, and the worker's test below takes the
# daemon's paths for bad peers.
@pytest.mark.parametrize("one_byte", [False, True])
def test_server_survives_bad_peers(data, cluster, tmp_path, one_byte):
    cluster.start(1, 1)
    for name, stream in BAD_STREAMS.items():
        send_bad(cluster.server.addr, stream, one_byte=one_byte and len(stream) < 200)
        assert cluster.server.alive(), f"server died on {name}"
        assert cluster.pool(), f"server stopped answering after {name}"
    log = cluster.server.read_log()
    assert "protocol error" in log and "bad magic" in log and "exceeds the limit" in log
    # A peer of the first protocol is told what is wrong and what to do.
    assert (f"speaks texsyn protocol version 1, this build {FRAME_START[2]}: run the same release on both sides"
            in log)
    remote(cluster, data, tmp_path)


@pytest.mark.sanitize
def test_worker_survives_bad_peers_and_keeps_serving(texsyn, data, cluster, tmp_path):
    want = embedded(texsyn, data, tmp_path)
    w = cluster.worker(1)
    # A fake coordinator: identifies, then sends broken requests.
    broken = [
        frame("I", ident_payload(1)) + frame("V", b"\x01\x02\x03"),
        frame("I", ident_payload(1)) + frame("N", b"\x00" * 30),
        frame("I", ident_payload(1)) + frame("Z", b""),
        frame("I", ident_payload(1)) + frame("V", b"", length=0x7FFFFFFF),
        frame("I", ident_payload(1))[:-3],
    ]
    for stream in [*BAD_STREAMS.values(), *broken]:
        send_bad(w.addr, stream)
        assert w.alive()
    for stream in broken[:2]:
        send_bad(w.addr, stream, one_byte=True)
    cluster.start()
    assert remote(cluster, data, tmp_path) == want
    assert "protocol error" in w.read_log()


def test_joining_workers_match_embedded(texsyn, data, cluster, tmp_path):
    """Workers started with --join announce themselves to the coordinator."""
    want = embedded(texsyn, data, tmp_path)
    cluster.start()
    for i in range(2):
        cluster.worker(1, "--join", cluster.server.addr)
    cluster.wait_ready(2)
    assert remote(cluster, data, tmp_path) == want
    assert [w["batches"] > 0 for w in cluster.pool()] == [True, True]


def test_worker_joining_mid_job_moves_only_the_rows_that_changed(texsyn, data, cluster, tmp_path):
    """A worker that joins while a job runs makes the others' slices
    shrink: they keep the rows (and usage counters) they hold and receive
    none again; the bytes stay the embedded run's."""
    extra = ("--usage-weight", "1")
    size = ("--size", "512x384")
    out, raw = tmp_path / "embedded.png", tmp_path / "embedded.raw"
    run(texsyn, "synth", "--embedded", "--ref", ref_of(data), "-o", out, *size, "--quiet", "--copy-map-raw", raw,
        *extra)
    cluster.start(2, 1)
    job = subprocess.Popen([str(BUILD / "texsyn"), "synth", "--server", cluster.server.addr, "--ref",
                            str(ref_of(data)), "-o", str(tmp_path / "remote.png"), *size, "--quiet",
                            "--copy-map-raw", str(tmp_path / "remote.raw"), *extra],
                           stderr=subprocess.PIPE, text=True)
    # Inside level 0 (3/4 of the work): its set is in use, so the join
    # re-slices it. A join between levels only cuts the next set in 3.
    cluster.server.wait_log(r"job 1: checkpoint after level 1 ", timeout=120)
    cluster.worker(1, "--join", cluster.server.addr)
    _, err = job.communicate(timeout=600)
    assert job.returncode == 0, err
    assert (tmp_path / "remote.png").read_bytes() == out.read_bytes()
    assert (tmp_path / "remote.raw").read_bytes() == raw.read_bytes()
    pool = cluster.pool()
    assert len(pool) == 3 and pool[2]["batches"] > 0, "the job ended before the third worker joined"
    resliced = [line for line in cluster.server.read_log().splitlines() if "kept from their slices" in line]
    assert resliced, cluster.server.read_log()
    for w in cluster.workers[:2]:
        assert "kept from generation" in w.read_log(), w.read_log()


def test_idle_worker_that_dies_leaves_the_pool_and_comes_back(texsyn, data, cluster, tmp_path):
    """Heartbeats find a worker killed between jobs; the coordinator dials
    its address again and uses it once it is back."""
    want = embedded(texsyn, data, tmp_path)
    cluster.start(2, 1, "--heartbeat", "0.5")
    dead = cluster.workers[1]
    dead.proc.kill()
    dead.proc.wait()
    deadline = time.time() + 10
    while time.time() < deadline and len(cluster.pool()) != 1:
        time.sleep(0.1)
    assert len(cluster.pool()) == 1, "the dead worker is still in the pool"
    assert "dropped" in cluster.server.read_log()
    reborn = Daemon([BUILD / "texsyn-worker", "--listen", dead.addr, "--threads", 1],
                    tmp_path / "reborn.log")
    cluster.workers.append(reborn)
    cluster.wait_ready(2)
    assert remote(cluster, data, tmp_path) == want
    assert all(w["batches"] > 0 for w in cluster.pool())


@pytest.mark.parametrize("addr", ["127.0.0.1:", ":7070", "127.0.0.1:0", "nohost"])
def test_worker_refuses_a_join_address_it_could_never_reach(addr):
    p = subprocess.run([str(BUILD / "texsyn-worker"), "--join", addr], capture_output=True, text=True, timeout=30)
    assert p.returncode == 2
    assert f"--join {addr}" in p.stderr and ("port" in p.stderr or "HOST:PORT" in p.stderr)
