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
FRAME_START = b"TS\x08"


def pytest_configure(config):
    config.addinivalue_line("markers", "sanitize: small enough to run under ASan+UBSan too")
    config.addinivalue_line("markers", "long: a measurement of minutes, run by make test-faults only")
    config.addinivalue_line("markers", "asan_only: needs the sanitizer build; run by its stage only")


def pytest_collection_modifyitems(config, items):
    """Long measurements are left out of `make test` (deselected, so they are
    neither run nor reported as skipped); `make test-faults` sets
    TEXSYN_LONG_TESTS=1 and runs them. Tests of what only the sanitizer
    build has run in the sanitized stage only (TEXSYN_SANITIZED=1)."""
    def left_out(item):
        return (not LONG and item.get_closest_marker("long")) or \
            (not SANITIZED and item.get_closest_marker("asan_only"))
    out = [i for i in items if left_out(i)]
    if out:
        config.hook.pytest_deselected(items=out)
        items[:] = [i for i in items if not left_out(i)]


def pytest_terminal_summary(terminalreporter):
    """Every skipped test on a line of its own, "SKIP NODE_ID: REASON"
    (pytest's -rs folds skips by file and line): tests/run-all.sh holds
    each against tests/skips.allow, test by test."""
    for rep in terminalreporter.stats.get("skipped", []):
        why = rep.longrepr[2] if isinstance(rep.longrepr, tuple) else str(rep.longrepr)
        terminalreporter.write_line(f"SKIP {rep.nodeid}: {why.removeprefix('Skipped: ')}")


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


STATUS_HEADER = ["ID", "STATE", "ENGINE", "OWNER", "SUBMITTED", "STARTED", "ENDED", "PROGRESS", "OUTPUT"]


def jobs_listed(text):
    """`texsyn status` (every job) as a list of dicts keyed by its header's
    names in lower case, and "note": what follows the output, two spaces
    after it. An empty listing says so under the header."""
    lines = text.splitlines()
    assert lines and lines[0].split() == STATUS_HEADER, text
    if lines[1:] == ["(no jobs)"]:
        return []
    rows = []
    for line in lines[1:]:
        f = line.split(None, len(STATUS_HEADER) - 1)
        output, _, note = f[-1].partition("  ")
        rows.append(dict(zip([h.lower() for h in STATUS_HEADER], f[:-1] + [output]), note=note.strip()))
    return rows


def workers_listed(text):
    """`texsyn workers` as a list of dicts: name, addr, threads, simd,
    calibrated, rate, share, state, batches, and "dropped" (when a dead
    worker was, as printed)."""
    lines = text.splitlines()
    assert lines and lines[0].split() == ["NAME", "ADDRESS", "THREADS", "SIMD", "CALIBRATED", "RATE", "SHARE",
                                          "STATE", "BATCHES"], text
    rows = []
    for line in lines[1:]:
        f = line.split(None, 9)
        if len(f) >= 9 and f[2].isdigit():
            rows.append({"name": f[0], "addr": f[1], "threads": int(f[2]), "simd": f[3], "calibrated": float(f[4]),
                         "rate": float(f[5]), "share": float(f[6].rstrip("%")), "state": f[7],
                         "batches": int(f[8]), "dropped": f[9].removeprefix("dropped ") if len(f) > 9 else ""})
    return rows


def modbus_registers(addr):
    """A daemon's Modbus registers by name (`texsyn modbus HOST:PORT`)."""
    out = run(BUILD / "texsyn", "modbus", addr).stdout
    return dict(line.split(" ", 1) for line in out.splitlines())


def dropped_during_the_job(log, addr):
    """The worker at addr was dropped while the coordinator's only job ran:
    its "dropped" line lies between the job's "queued" and "done" lines
    (a worker dropped after the job took no work from it). Returns the
    reason the drop names."""
    import re
    lines = log.splitlines()
    queued = next((i for i, line in enumerate(lines) if re.search(r"job \d+ queued ", line)), None)
    assert queued is not None, f"no job was queued:\n{log}"
    job = re.search(r"job (\d+) queued ", lines[queued]).group(1)
    done = next((i for i, line in enumerate(lines) if f"job {job} done in " in line), None)
    drop = next((i for i, line in enumerate(lines) if re.search(rf"worker \d+ \({re.escape(addr)}\) dropped: ", line)),
                None)
    assert done is not None, f"job {job} is not logged done:\n{log}"
    assert drop is not None, f"the worker at {addr} was never dropped:\n{log}"
    assert queued < drop < done, f"the worker at {addr} was dropped outside job {job}'s run:\n{log}"
    return lines[drop].split(") dropped: ", 1)[1]


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


class SignalledPopen(subprocess.Popen):
    """A Popen that remembers the signals sent through it (kill() and
    terminate() go through send_signal too): a daemon that ends by any
    other signal crashed."""

    def __init__(self, *args, **kwargs):
        self.signals_sent = set()
        super().__init__(*args, **kwargs)

    def send_signal(self, sig):
        self.signals_sent.add(sig)
        super().send_signal(sig)


# What a sanitizer prints when it finds an error: ASan and LSan name
# themselves, UBSan reports "FILE:LINE:COL: runtime error: ...", TSan
# (make test-tsan) "WARNING: ThreadSanitizer: data race" and the like.
SANITIZER_REPORT = re.compile(r"ERROR: (AddressSanitizer|LeakSanitizer)|WARNING: ThreadSanitizer|"
                              r"^\S+:\d+:\d+: runtime error:", re.M)
STOP_SECONDS = 20

# Every daemon the running test started, for check_daemons (below).
DAEMONS = []


class Daemon:
    """A texsyn-server or texsyn-worker started on a kernel-chosen loopback
    port; stopped (SIGTERM, then SIGKILL) by the fixture that made it, and
    checked after the test by check_daemons. Signals go through
    self.proc.send_signal (or kill/terminate), which records them."""

    def __init__(self, args, log_path):
        self.name = Path(log_path).stem
        self.log_path = log_path
        self.log = open(log_path, "w")
        self.stop_timed_out = False
        self.proc = SignalledPopen([str(a) for a in args], stdout=subprocess.PIPE, stderr=self.log, text=True)
        DAEMONS.append(self)
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

    def expect_signal(self, sig):
        """The daemon will die of sig by the test's doing, not sent through
        proc.send_signal (a preloaded shim raises it)."""
        self.proc.signals_sent.add(sig)

    def wait_log(self, pattern, timeout=300):
        """The first match of pattern in the log, polled every 10 ms: tests
        wait for the event itself, not for a time it usually takes."""
        deadline = time.time() + timeout
        while time.time() < deadline:
            m = re.search(pattern, self.read_log())
            if m:
                return m
            assert self.alive(), f"{self.name} died waiting for {pattern!r}:\n{self.read_log()}"
            time.sleep(0.01)
        raise AssertionError(f"{self.name} never logged {pattern!r}:\n{self.read_log()}")

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=STOP_SECONDS)
            except subprocess.TimeoutExpired:
                self.stop_timed_out = True
                self.proc.kill()
                self.proc.wait()
        if self.proc.stdout:
            self.proc.stdout.close()
        self.log.close()
        return self.proc.returncode

    def faults(self):
        """What went wrong with this daemon, as sentences (none: all well):
        an exit by a signal nobody sent (a crash, or a sanitizer's abort),
        a sanitizer report in its log, or no exit within STOP_SECONDS of
        SIGTERM."""
        found = []
        rc = self.proc.returncode
        if rc is not None and rc < 0 and -rc not in self.proc.signals_sent:
            found.append(f"{self.name} (pid {self.proc.pid}) died of {signal.Signals(-rc).name}, "
                         "a signal the test did not send")
        if self.stop_timed_out:
            found.append(f"{self.name} (pid {self.proc.pid}) did not exit within {STOP_SECONDS} s of SIGTERM")
        log = self.read_log()
        m = SANITIZER_REPORT.search(log)
        if m:
            start = log.rfind("\n", 0, m.start()) + 1
            found.append(f"{self.name}'s log ({self.log_path}) holds a sanitizer report:\n"
                         + "\n".join(log[start:].splitlines()[:30]))
        return found


@pytest.fixture(autouse=True)
def check_daemons():
    """After every test: stops the daemons it left running, then fails it
    (an error at teardown) if any daemon crashed, hung on SIGTERM or left a
    sanitizer report. Autouse fixtures are set up first, so this runs after
    the fixtures that stop their own daemons."""
    DAEMONS.clear()
    yield
    found = []
    for d in DAEMONS:
        d.stop()
        found += d.faults()
    DAEMONS.clear()
    if found:
        pytest.fail("\n".join(found), pytrace=False)


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

    def submit(self, ref, *args):
        """`texsyn synth --detach` of ref with args (size, options, side
        outputs); returns the job id."""
        p = self.texsyn("synth", "--ref", ref, "-o", self.tmp / "unused.png", *args, "--detach")
        return p.stdout.split()[-1]

    def restart_server(self, *server_args, log="server2.log"):
        """A new coordinator on the same spool and workers (the old one
        stopped or killed)."""
        args = [BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", self.tmp / "spool",
                "--workers", ",".join(w.addr for w in self.workers), *server_args]
        self.server = Daemon(args, self.tmp / log)

    def pool(self, dead=False):
        """`texsyn workers` as a list of dicts (workers_listed); the dead
        ones, which are no longer in the pool, only with dead."""
        return [w for w in workers_listed(self.texsyn("workers").stdout) if dead or w["state"] != "dead"]

    def wait_ready(self, n, timeout=30):
        deadline = time.time() + timeout
        while time.time() < deadline:
            if sum(1 for w in self.pool() if w["state"] == "active") >= n:
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
    nclass, labelled = struct.unpack_from("<HB", body, off)
    off += 4
    if labelled == 2:  # the labels as a tile: its sides, then its bytes
        off += 2 + body[off] * body[off + 1]
    return [struct.unpack_from("<III", body, off + 12 * c)[1:] for c in range(nclass)]
