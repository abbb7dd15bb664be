"""Shared fixtures: the binaries under test, the shared data, and a runner."""
import json
import os
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
BUILD = Path(os.environ.get("TEXSYN_BUILD", REPO / "build"))
DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))
SANITIZED = os.environ.get("TEXSYN_SANITIZED") == "1"
LONG = os.environ.get("TEXSYN_LONG_TESTS") == "1"
# Frame header start: magic and the protocol version (proto/frame.h).
FRAME_START = b"TS\x02"


def pytest_configure(config):
    config.addinivalue_line("markers", "sanitize: small enough to run under ASan+UBSan too")
    config.addinivalue_line("markers", "long: a measurement of minutes, run by make test-faults only")


def pytest_collection_modifyitems(config, items):
    """Long measurements are left out of `make test` (deselected, so they are
    neither run nor reported as skipped); `make test-faults` sets
    TEXSYN_LONG_TESTS=1 and runs them."""
    if LONG:
        return
    long = [i for i in items if i.get_closest_marker("long")]
    if long:
        config.hook.pytest_deselected(items=long)
        items[:] = [i for i in items if not i.get_closest_marker("long")]


@pytest.fixture(scope="session")
def texsyn():
    exe = BUILD / "texsyn"
    assert exe.exists(), f"{exe} is missing: run make first"
    return exe


@pytest.fixture(scope="session")
def data():
    if not (DATA / "textures" / "brick.png").exists():
        pytest.fail(f"test data not found at {DATA}: tests/test-data.sh gets it (tests/run-integration.sh runs "
                    "it), or set TEXSYN_DATA to a directory holding it", pytrace=False)
    return DATA


def run(exe, *args, env=None, check=True, timeout=600):
    """Runs a texsyn command; returns the CompletedProcess (text mode)."""
    full_env = dict(os.environ)
    full_env.update(env or {})
    p = subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True,
                       env=full_env, timeout=timeout)
    if check and p.returncode != 0:
        raise AssertionError(f"texsyn {' '.join(map(str, args))} failed ({p.returncode}):\n{p.stderr}")
    return p


def synth(exe, ref, out, size, *extra, env=None):
    """An embedded run (a reference result): --embedded, so that a
    TEXSYN_SERVER in the environment cannot send it to a cluster."""
    w, h = size
    report = Path(str(out) + ".json")
    run(exe, "synth", "--embedded", "--ref", ref, "-o", out, "--size", f"{w}x{h}", "--quiet",
        "--report", report, *extra, env=env)
    return json.loads(report.read_text())


def quality(exe, ref, image, samples=1500, wn=7):
    p = run(exe, "quality", "--ref", ref, "--image", image, "--samples", samples, "--wn", wn)
    return json.loads(p.stdout)


# ---- daemons -------------------------------------------------------------

import re
import signal
import socket
import threading
import time


def shutdown_all(*socks):
    """Shuts both directions of every socket, whatever state it is in."""
    for s in socks:
        try:
            s.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass


class LoopbackProxy:
    """Listens on a loopback port chosen by the system and, for every
    connection to it, dials `target` (HOST:PORT) and calls
    self.forward(client_socket, target_socket), which subclasses define."""

    def __init__(self, target):
        self.target = target
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.addr = "127.0.0.1:%d" % self.sock.getsockname()[1]
        threading.Thread(target=self.accept, daemon=True).start()

    def accept(self):
        while True:
            try:
                a, _ = self.sock.accept()
            except OSError:
                return
            host, port = self.target.rsplit(":", 1)
            self.forward(a, socket.create_connection((host, int(port))))

    def close(self):
        self.sock.close()


class Daemon:
    """A texsyn-server or texsyn-worker started on a kernel-chosen loopback
    port; stopped (SIGTERM, then SIGKILL) by the fixture that made it."""

    def __init__(self, args, log_path):
        self.log_path = log_path
        self.log = open(log_path, "w")
        self.proc = subprocess.Popen([str(a) for a in args], stdout=subprocess.PIPE,
                                     stderr=self.log, text=True)
        line = self.proc.stdout.readline()
        m = re.search(r"listening on (\S+)", line)
        if not m:
            self.stop()
            raise AssertionError(f"{args[0]} did not start: {line!r}\n{Path(log_path).read_text()}")
        self.addr = m.group(1)
        self.port = int(self.addr.rsplit(":", 1)[1])
        mb = re.search(r"\(modbus (\S+)\)", line)
        self.modbus = mb.group(1) if mb else None  # HOST:PORT of its Modbus plane

    def read_log(self):
        if not self.log.closed:
            self.log.flush()
        return Path(self.log_path).read_text()

    def alive(self):
        return self.proc.poll() is None

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stdout:
            self.proc.stdout.close()
        self.log.close()
        return self.proc.returncode


class Cluster:
    """Workers and a coordinator on loopback, like deploy/local-cluster.sh."""

    def __init__(self, tmp_path):
        self.tmp = tmp_path
        self.workers = []
        self.server = None

    def worker(self, threads=1, *extra, prefix=()):
        i = len(self.workers)
        w = Daemon([*prefix, BUILD / "texsyn-worker", "--listen", "127.0.0.1:0", "--threads", threads,
                    "--name", f"w{i}", *extra], self.tmp / f"worker{i}.log")
        self.workers.append(w)
        return w

    def start(self, nworkers=0, threads=1, *server_args):
        for _ in range(nworkers):
            self.worker(threads)
        args = [BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", self.tmp / "spool",
                *server_args]
        if self.workers:
            args += ["--workers", ",".join(w.addr for w in self.workers)]
        self.server = Daemon(args, self.tmp / "server.log")
        self.wait_ready(len(self.workers))
        return self

    def texsyn(self, *args, check=True, timeout=600):
        return run(BUILD / "texsyn", *args, "--server", self.server.addr, check=check, timeout=timeout)

    def pool(self):
        """`texsyn workers` as a list of dicts."""
        out = self.texsyn("workers").stdout.splitlines()
        rows = []
        for line in out[1:]:
            f = line.split()
            if len(f) == 8 and f[1].isdigit():
                rows.append({"addr": f[0], "threads": int(f[1]), "simd": f[2], "calibrated": float(f[3]),
                             "rate": float(f[4]), "share": float(f[5].rstrip("%")), "state": f[6],
                             "batches": int(f[7])})
        return rows

    def wait_ready(self, n, timeout=30):
        deadline = time.time() + timeout
        while time.time() < deadline:
            if sum(1 for w in self.pool() if w["state"] == "ready") >= n:
                return
            time.sleep(0.05)
        raise AssertionError(f"{n} workers not ready:\n{self.server.read_log()}")

    def stop(self):
        codes = []
        if self.server:
            codes.append(self.server.stop())
        for w in self.workers:
            codes.append(w.stop())
        return codes


@pytest.fixture
def cluster(tmp_path):
    for exe in ("texsyn-server", "texsyn-worker"):
        assert (BUILD / exe).exists(), f"{BUILD / exe} is missing: run make first"
    c = Cluster(tmp_path)
    yield c
    c.stop()


def slice_ranges(body):
    """The per-class vector ranges [(i0, i1), ...] of an 'N' (load slice)
    payload (proto/PROTOCOL.md): past set, gen, image and the window, to the
    classes."""
    import struct
    nfine, ncoarse = body[12], body[13]
    off = 18
    first_noff = None
    for n in (nfine, ncoarse):
        if n:
            noff = struct.unpack_from("<H", body, off + 8)[0]
            first_noff = noff if first_noff is None else first_noff
            off += 10 + 4 * noff
    nparts = body[off]
    off += 1 + 7 * nparts
    off += 1 + (first_noff if body[off] else 0)  # the known flags
    off += 16
    nclass = struct.unpack_from("<H", body, off)[0]
    off += 4
    return [struct.unpack_from("<III", body, off + 12 * c)[1:] for c in range(nclass)]
