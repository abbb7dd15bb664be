"""The Modbus TCP monitoring and control plane of both daemons, read and
written with real clients: mbpoll (Debian's command-line Modbus master)
and `texsyn modbus` (libmodbus in C). Register numbers are the ones in
proto/mbmap.h and the README."""
import os
import shutil
import signal
import socket
import struct
import subprocess
import time

import pytest

from conftest import BUILD, FRAME_START, modbus_registers, run, synth

JOB = ["--size", "384x288", "--usage-weight", "1"]
SERVER_ARGS = ["--calibrate-ms", "50", "--modbus-poll", "0.2"]


def ref_of(data):
    return data / "textures" / "brick.png"


def mbpoll(addr, *args, write=(), check=True):
    """mbpoll against HOST:PORT, zero-based addresses, one poll; `write`
    holds values to write instead of reading."""
    if shutil.which("mbpoll") is None:
        pytest.fail("mbpoll is not installed: it is Debian's mbpoll, which deploy/install-deps.sh installs",
                    pytrace=False)
    host, port = addr.rsplit(":", 1)
    p = subprocess.run(["mbpoll", "-m", "tcp", "-a", "1", "-0", "-1", "-p", port, *map(str, args), host,
                        *map(str, write)],
                       capture_output=True, text=True, timeout=30)
    if check and p.returncode != 0:
        raise AssertionError(f"mbpoll {args} failed: {p.stdout}{p.stderr}")
    return p


def input_registers(addr, start, count):
    out = mbpoll(addr, "-t", "3", "-r", start, "-c", count).stdout
    regs = {}
    for line in out.splitlines():
        if line.startswith("["):
            k, v = line.split(":")
            regs[int(k.strip("[]"))] = int(v.split()[0]) & 0xFFFF  # "54526 (-11010)"
    assert len(regs) == count, out
    return regs


def u64(regs, at):
    return regs[at] << 48 | regs[at + 1] << 32 | regs[at + 2] << 16 | regs[at + 3]


def start(cluster, nworkers, *server_args, control=True):
    for _ in range(nworkers):
        cluster.worker(1, "--modbus", "0", *(["--modbus-control", "--modbus-allow", "127.0.0.1"] if control else []))
    cluster.start(0, 1, *SERVER_ARGS, "--modbus", "0", *(["--modbus-control", "--modbus-allow", "127.0.0.1"] if control else []), *server_args)
    return cluster


def submit(cluster, data, out):
    args = [BUILD / "texsyn", "synth", "--server", cluster.server.addr, "--ref", ref_of(data), "-o", out, *JOB,
            "--quiet"]
    return subprocess.Popen([str(a) for a in args], stderr=subprocess.PIPE, text=True)


def wait_until(what, pred, timeout=30):
    deadline = time.time() + timeout
    while not pred():
        assert time.time() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


@pytest.fixture(scope="module")
def expected(texsyn, data, tmp_path_factory):
    out = tmp_path_factory.mktemp("expected") / "expected.png"
    synth(texsyn, ref_of(data), out, (384, 288), *JOB[2:])
    return out.read_bytes()


def test_maps_read_with_mbpoll_and_libmodbus(data, cluster, tmp_path, expected):
    start(cluster, 2, control=False)
    w = cluster.workers[0]
    regs = input_registers(w.modbus, 0, 32)
    assert regs[0] == 0x5453 and regs[1] == FRAME_START[2] and regs[3] == 2  # magic, protocol, worker
    assert regs[5] == 1  # threads
    assert u64(regs, 12) > 0  # calibrated rate
    before = u64(regs, 24)
    job = submit(cluster, data, tmp_path / "out.png")
    wait_until("queries served to grow while the job runs",
               lambda: job.poll() is None and u64(input_registers(w.modbus, 0, 32), 24) > before)
    seen = modbus_registers(cluster.server.modbus)
    assert seen["role"] == "coordinator" and seen["workers"] == "2"
    assert job.wait(timeout=300) == 0, job.stderr.read()
    job.stderr.close()
    assert (tmp_path / "out.png").read_bytes() == expected
    server = input_registers(cluster.server.modbus, 32, 16)
    assert server[32] == 2 and server[35] << 16 | server[36] == 1  # workers, jobs done
    assert u64(server, 39) == 1 and server[43] == 1000  # the last job, finished
    worker = modbus_registers(w.modbus)
    assert worker["role"] == "worker" and int(worker["queries"]) > before and worker["state"] in ("idle", "scanning")


def test_writes_need_modbus_control(data, cluster, tmp_path):
    start(cluster, 1, control=False)
    for addr in (cluster.workers[0].modbus, cluster.server.modbus):
        p = mbpoll(addr, "-t", "0", "-r", "0", write=[1], check=False)
        assert p.returncode != 0 and "Illegal function" in p.stdout + p.stderr, p.stdout + p.stderr
    p = run(BUILD / "texsyn", "modbus", cluster.workers[0].modbus, "--set", "drain=1", check=False)
    assert p.returncode == 1 and "--modbus-control" in p.stderr
    assert "coil write refused" in cluster.workers[0].read_log()
    assert modbus_registers(cluster.workers[0].modbus)["state"] != "draining"


def test_drain_mid_job_keeps_the_bytes(data, cluster, tmp_path, expected):
    start(cluster, 3)
    victim = cluster.workers[1]
    job = submit(cluster, data, tmp_path / "out.png")
    wait_until("the job to load slices", lambda: int(modbus_registers(victim.modbus)["vectors"]) > 0)
    run(BUILD / "texsyn", "modbus", victim.modbus, "--set", "drain=1")
    assert job.wait(timeout=300) == 0, job.stderr.read()
    job.stderr.close()
    assert (tmp_path / "out.png").read_bytes() == expected
    wait_until("the drained worker to hold nothing", lambda: modbus_registers(victim.modbus)["vectors"] == "0")
    assert modbus_registers(victim.modbus)["state"] == "draining"
    states = [w["state"] for w in cluster.pool()]
    assert states.count("draining") == 1 and states.count("active") == 2, states
    assert "draining: its slices are handed back" in cluster.server.read_log()
    # Cleared, it gets slices again: the next job runs on all three.
    run(BUILD / "texsyn", "modbus", victim.modbus, "--set", "drain=0")
    wait_until("the worker to be back", lambda: [w["state"] for w in cluster.pool()].count("active") == 3)
    job = submit(cluster, data, tmp_path / "again.png")
    assert job.wait(timeout=300) == 0
    job.stderr.close()
    assert (tmp_path / "again.png").read_bytes() == expected
    assert int(modbus_registers(victim.modbus)["batches"]) > 0


def test_pause_holds_the_queue(data, cluster, tmp_path, expected):
    start(cluster, 1)
    run(BUILD / "texsyn", "modbus", cluster.server.modbus, "--set", "pause=1")
    assert modbus_registers(cluster.server.modbus)["paused"] == "1"
    p = cluster.texsyn("synth", "--ref", ref_of(data), "-o", tmp_path / "x.png", *JOB, "--detach")
    job = p.stdout.strip()
    time.sleep(1.0)
    assert cluster.texsyn("status", job).stdout.splitlines()[0].split()[:2] == [job, "held"]
    assert modbus_registers(cluster.server.modbus)["queued"] == "1"
    run(BUILD / "texsyn", "modbus", cluster.server.modbus, "--set", "pause=0")
    cluster.texsyn("watch", job, "--quiet")
    cluster.texsyn("fetch", job, "-o", tmp_path / "y.png")
    assert (tmp_path / "y.png").read_bytes() == expected


def raw_modbus(addr, frame):
    host, port = addr.rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=5) as s:
        s.sendall(frame)
        try:
            return s.recv(256)
        except (ConnectionResetError, socket.timeout):
            return b""


def mbap(pdu, unit=1, tid=7, proto=0):
    return struct.pack(">HHHB", tid, proto, len(pdu) + 1, unit) + pdu


@pytest.mark.sanitize
def test_malformed_modbus_requests_leave_both_planes_serving(data, cluster, tmp_path):
    start(cluster, 1)
    for addr in (cluster.workers[0].modbus, cluster.server.modbus):
        # Unknown function: exception 01. Out-of-range registers: exception 02.
        assert raw_modbus(addr, mbap(b"\x41"))[7:9] == b"\xc1\x01"
        assert raw_modbus(addr, mbap(struct.pack(">BHH", 4, 200, 10)))[7:9] == b"\x84\x02"
        assert raw_modbus(addr, mbap(struct.pack(">BHH", 3, 0, 1)))[7:9] == b"\x83\x02"  # no holding registers
        # Garbage, a wrong protocol id, a lying length: the connection is dropped.
        assert raw_modbus(addr, b"GET / HTTP/1.1\r\nHost: x\r\n\r\n") == b""
        assert raw_modbus(addr, mbap(struct.pack(">BHH", 4, 0, 1), proto=5)) == b""
        assert raw_modbus(addr, struct.pack(">HHHB", 1, 0, 50, 1) + b"\x04\x00\x00\x00\x01") == b""
        assert modbus_registers(addr)["magic"] == "0x5453"
    w, h = 96, 64
    cluster.texsyn("synth", "--ref", ref_of(data), "-o", tmp_path / "x.png", "--size", f"{w}x{h}", "--levels", "3",
                   "--quiet")
    assert cluster.server.alive() and cluster.workers[0].alive()


class Hog:
    """Two busy loops pinned with a worker to one CPU: another tenant's
    load. The worker then gets about a third of that CPU."""

    def __init__(self, cpu):
        self.procs = [subprocess.Popen(["/usr/bin/python3", "-c", "while True: pass"],
                                       preexec_fn=lambda: os.sched_setaffinity(0, {cpu})) for _ in range(2)]

    def stop(self):
        for p in self.procs:
            p.kill()
            p.wait()


@pytest.mark.long  # 25 s of measured load: make test-faults
@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="needs two CPUs")
def test_load_read_over_modbus_rebalances(data, cluster, tmp_path):
    """Each worker pinned to its own CPU; mid-job the second one's CPU gets
    another tenant. Its CPU share, read over Modbus, drops against the
    first one's for longer than --rebalance-after, and its slice shrinks
    (batch timings are told to stay out of it); the output keeps its
    bytes."""
    start(cluster, 2, "--rebalance-after", "1", "--rebalance-tolerance", "0.2", "--rebalance-from", "modbus")
    cpus = sorted(os.sched_getaffinity(0))
    for worker, cpu in zip(cluster.workers, cpus[:2]):
        for tid in os.listdir(f"/proc/{worker.proc.pid}/task"):
            os.sched_setaffinity(int(tid), {cpu})
    w, h = 1024, 768
    out = tmp_path / "long.png"
    p = subprocess.Popen([str(BUILD / "texsyn"), "synth", "--server", cluster.server.addr, "--ref",
                          str(ref_of(data)), "-o", str(out), "--size", f"{w}x{h}", "--quiet"],
                         stderr=subprocess.PIPE, text=True)
    wait_until("a CPU-share baseline", lambda: all(modbus_registers(x.modbus)["cpu_share"] != "unknown" for x in cluster.workers))
    wait_until("both workers answering the job", lambda: all(x["batches"] > 0 for x in cluster.pool()))

    def ratio():
        pool = cluster.pool()
        return pool[1]["share"] / pool[0]["share"]

    before = ratio()
    hog = Hog(cpus[1])
    line = "CPU shares (Modbus) changed unevenly"
    try:
        wait_until("a rebalance", lambda: line in cluster.server.read_log() or p.poll() is not None, 300)
        assert line in cluster.server.read_log(), cluster.server.read_log()
        # the new rates cut the job's sets again at its next batch
        wait_until("a smaller slice", lambda: ratio() < 0.8 * before or p.poll() is not None, 300)
        assert ratio() < 0.8 * before, (before, cluster.pool())
    finally:
        hog.stop()
    assert p.wait(timeout=600) == 0, p.stderr.read()
    p.stderr.close()
    assert ": rates deviated" not in cluster.server.read_log()  # batch timings were told to stay out
    want = tmp_path / "want.png"
    synth(BUILD / "texsyn", ref_of(data), want, (w, h))
    assert out.read_bytes() == want.read_bytes()


def test_worker_silent_on_both_planes_is_dropped(data, cluster, tmp_path, expected):
    """Heartbeats off, so only the Modbus reads can notice: a stopped idle
    worker (neither plane answers) leaves the pool; continued, it is dialled
    again and serves the next job."""
    start(cluster, 2, "--heartbeat", "0")
    victim = cluster.workers[0]
    victim.proc.send_signal(signal.SIGSTOP)
    try:
        wait_until("the silent worker to be dropped",
                   lambda: "its Modbus and data planes are both silent" in cluster.server.read_log())
    finally:
        victim.proc.send_signal(signal.SIGCONT)
    wait_until("the worker to be back", lambda: [w["state"] for w in cluster.pool()].count("active") == 2)
    job = submit(cluster, data, tmp_path / "out.png")
    assert job.wait(timeout=300) == 0
    job.stderr.close()
    assert (tmp_path / "out.png").read_bytes() == expected


# ---- who reaches the plane ------------------------------------------------------

def non_loopback_ipv4():
    out = subprocess.run(["hostname", "-I"], capture_output=True, text=True, timeout=10).stdout
    return next((a for a in out.split() if "." in a and not a.startswith("127.")), None)


def read_regs(host, port, count=4):
    """Input registers 0..count-1 with a raw Modbus TCP request (function
    04); None if the daemon closed the connection instead of answering."""
    with socket.create_connection((host, int(port)), timeout=5) as s:
        s.sendall(struct.pack(">HHHBBHH", 9, 0, 6, 1, 4, 0, count))
        reply = b""
        while len(reply) < 9 + 2 * count:
            try:
                chunk = s.recv(256)
            except ConnectionResetError:
                return None
            if not chunk:
                return None
            reply += chunk
    return struct.unpack(f">{count}H", reply[9:9 + 2 * count])


def test_modbus_listens_on_loopback_unless_told_and_admits_only_the_allow_list(cluster, tmp_path):
    """`:PORT` is loopback, like a bare PORT (it used to bind every
    interface); `*:PORT` binds them all, and a peer off loopback is still
    closed at accept unless --modbus-allow names it; --modbus-control needs
    an allow-list."""
    w = cluster.worker(1, "--modbus", ":0")
    assert w.modbus.startswith("127.0.0.1:"), w.modbus
    ip = non_loopback_ipv4()
    assert ip is not None, "this test needs a non-loopback IPv4 address (hostname -I)"
    open_ = cluster.worker(1, "--modbus", "*:0")
    port = open_.modbus.rsplit(":", 1)[1]
    assert read_regs("127.0.0.1", port)[0] == 0x5453
    assert read_regs(ip, port) is None
    allowed = cluster.worker(1, "--modbus", "0.0.0.0:0", "--modbus-allow", f"10.255.255.0/24,{ip}/32")
    assert read_regs(ip, allowed.modbus.rsplit(":", 1)[1])[0] == 0x5453
    for daemon, extra in ((BUILD / "texsyn-worker", ["--listen", "127.0.0.1:0"]),
                          (BUILD / "texsyn-server", ["--listen", "127.0.0.1:0", "--spool", tmp_path / "s"])):
        p = run(daemon, *extra, "--modbus", "0", "--modbus-control", check=False)
        assert p.returncode == 2 and "--modbus-control needs --modbus-allow" in p.stderr, p.stderr
    p = run(BUILD / "texsyn-worker", "--listen", "127.0.0.1:0", "--modbus-allow", "10.1.2.3/33", check=False)
    assert p.returncode == 2 and "'10.1.2.3/33': the prefix must be 0..32" in p.stderr, p.stderr


class ForgedModbus:
    """A Modbus TCP server that answers every read of input registers with
    zeros but for `state` = draining (proto/mbmap.h): someone on the path,
    or on the worker's host, answering the coordinator's polls."""

    def __init__(self, host, port):
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind((host, port))
        self.sock.listen(16)
        self.polls = 0
        import threading
        threading.Thread(target=self.serve, daemon=True).start()

    def serve(self):
        while True:
            try:
                c, _ = self.sock.accept()
            except OSError:
                return
            with c:
                try:
                    req = c.recv(260)
                    if len(req) < 12:
                        continue
                    tid, count = struct.unpack(">H", req[:2])[0], struct.unpack(">H", req[10:12])[0]
                    regs = [0] * count
                    regs[0], regs[4] = 0x5453, 3  # magic; state = draining
                    body = struct.pack(">BBB", 1, 4, 2 * count) + struct.pack(f">{count}H", *regs)
                    c.sendall(struct.pack(">HHH", tid, 0, len(body)) + body)
                    self.polls += 1
                except OSError:
                    pass

    def close(self):
        self.sock.close()


def test_forged_modbus_registers_cannot_drain_a_worker(data, cluster, tmp_path, expected):
    """The coordinator polls a worker's Modbus port at the address its data
    connection comes from. Here the worker's plane is on 127.0.0.2 and a
    forger answers on 127.0.0.1 with `draining`: the coordinator asks the
    worker on the sealed data plane, which says no, so it stays in the
    pool and the job's bytes are the embedded run's."""
    w = cluster.worker(1, "--modbus", "127.0.0.2:0")
    forger = ForgedModbus("127.0.0.1", int(w.modbus.rsplit(":", 1)[1]))
    try:
        cluster.worker(1)
        cluster.start(0, 1, *SERVER_ARGS)
        cluster.server.wait_log(r"its Modbus plane says draining but its data plane does not; ignored")
        assert forger.polls >= 1
        job = cluster.submit(ref_of(data), *JOB)
        cluster.texsyn("watch", job, "--quiet")
        out = tmp_path / "out.png"
        cluster.texsyn("fetch", job, "-o", out)
        assert out.read_bytes() == expected
        assert [x["state"] for x in cluster.pool()] == ["active", "active"]
        assert "draining: its slices are handed back" not in cluster.server.read_log()
    finally:
        forger.close()


def test_idle_modbus_clients_do_not_lock_readers_out(cluster, tmp_path):
    """The issue's finding: 16 idle sockets took every slot of a plane, for
    ever. Now 64 idle ones (8 from 127.0.0.1, the rest evicting each other)
    leave a fresh reader served at once."""
    w = cluster.worker(1, "--modbus", "0")
    host, port = w.modbus.rsplit(":", 1)
    idle = [socket.create_connection((host, int(port)), timeout=5) for _ in range(64)]
    t0 = time.monotonic()
    assert read_regs(host, port)[0] == 0x5453
    assert time.monotonic() - t0 < 1.0
    for s in idle:
        s.close()
    assert "closed to make room (at most 8 from one address" in w.read_log()


@pytest.mark.long  # 30 s of an idle client: make test-faults
def test_an_idle_modbus_client_is_closed_after_30_s(cluster, tmp_path):
    w = cluster.worker(1, "--modbus", "0")
    host, port = w.modbus.rsplit(":", 1)
    idle = socket.create_connection((host, int(port)), timeout=5)
    idle.settimeout(40)
    t0 = time.monotonic()
    assert idle.recv(1) == b""
    waited = time.monotonic() - t0
    assert 25 < waited < 35, waited
    idle.close()
