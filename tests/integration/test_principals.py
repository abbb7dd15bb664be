"""Principals (issue 29): separate keys for workers, clients (one per user,
its name owning its jobs), an admin and the page, made by
`texsyn-server --gen-secret`. A worker key cannot submit, a client key
cannot join, a page key opens no data-plane link; one client cannot fetch,
cancel or delete another's job, an admin can; quotas count by the key's
name; keys rotate on SIGHUP without losing a job. The page: HTTPS with a
certificate, refused beyond loopback without it when keys guard it, and
slow connections that no longer keep it from a fresh client.

Each test would have failed on the single shared secret of ae57113: there
every key is the same admin, short secrets pass, the owner is what the
client says it is, and 32 slow connections fill the page."""
import hashlib
import hmac
import json
import os
import re
import signal
import socket
import ssl
import stat
import struct
import subprocess
import threading
import time
import urllib.error
import urllib.request

import pytest

from conftest import BUILD, Daemon, jobs_listed, run, synth
from hostile import HEADER, frame_bytes

SIZE = ("--size", "96x64", "--levels", "3")


def ref_of(data):
    return data / "textures" / "brick.png"


def gen(path, kind):
    p = run(BUILD / "texsyn-server", "--gen-secret", kind, path)
    return p.stdout


@pytest.fixture
def keys(tmp_path, monkeypatch):
    """The coordinator's --keys directory: admin, a worker key, two client
    keys and a page key; each holder is given its own file. The fixtures'
    own `texsyn workers` use the admin key."""
    d = tmp_path / "keys"
    d.mkdir()
    for kind, name in (("admin", "ops"), ("worker", "pool"), ("client", "alice"), ("client", "bob"),
                       ("page", "prom")):
        gen(d / f"{name}.key", kind)
    monkeypatch.setenv("TEXSYN_SECRET_FILE", str(d / "ops.key"))
    return d


def start(cluster, keys, *extra, workers=0):
    """A coordinator with the keys and `workers` workers joined with the
    worker key."""
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", cluster.tmp / "spool",
                             "--keys", keys, *extra], cluster.tmp / "server.log")
    for _ in range(workers):
        cluster.worker(1, "--join", cluster.server.addr, "--secret-file", keys / "pool.key")
    return cluster.server


def cli(server, key, *args, check=False, env=None):
    return run(BUILD / "texsyn", *args, "--server", server.addr, "--secret-file", key, check=check, env=env)


def submit(server, key, data, tmp_path, *extra, env=None):
    p = cli(server, key, "synth", "--ref", ref_of(data), "-o", tmp_path / "unused.png", *SIZE, *extra, "--detach",
            check=True, env=env)
    return p.stdout.split()[-1]


# ---- a raw connection start, to show what the coordinator itself refuses ----

def read_frame(s):
    head = b""
    while len(head) < HEADER.size:
        chunk = s.recv(HEADER.size - len(head))
        if not chunk:
            raise ConnectionError("closed")
        head += chunk
    _, _, ftype, length, _ = HEADER.unpack(head)
    body = b""
    while len(body) < length:
        chunk = s.recv(length - len(body))
        if not chunk:
            raise ConnectionError("closed")
        body += chunk
    return ftype.decode(), body


def string(b):
    return struct.pack("<H", len(b)) + b


def key_line(path):
    return path.read_bytes().rstrip(b"\n")


KINDS = {"admin": 1, "worker": 2, "client": 3, "page": 4}


def handshake(addr, key, role):
    """Identifies as `role` (1 coordinator, 2 worker, 3 client) and proves
    `key` (a typed key file) as PROTOCOL.md describes; returns what the
    acceptor answered the response with: ('A', proof) or ('E', text)."""
    secret = key_line(key)
    _, kind, name, _ = secret.decode().split(":")
    host, port = addr.rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=10) as s:
        ident = struct.pack("<BIHB", role, 0x7 | 0x8, 0, 0) + string(b"raw")
        s.sendall(frame_bytes("I", 0, ident))
        assert read_frame(s)[0] == "I"
        ftype, ch = read_frame(s)
        assert ftype == "A" and ch[0] == 1, (ftype, ch)
        na, nc = ch[1:33], os.urandom(32)
        acceptor = 1 if role != 1 else 2
        t = b"texsyn-auth-v2" + bytes([1, role, acceptor, KINDS[kind], len(name)]) + name.encode() + na + nc
        mac = hmac.new(secret, t, hashlib.sha256).digest()
        s.sendall(frame_bytes("A", 0, bytes([2]) + nc + bytes([KINDS[kind]]) + string(name.encode()) + mac))
        ftype, body = read_frame(s)
        return ftype, body[6:].decode(errors="replace") if ftype == "E" else body


# ---- keys ------------------------------------------------------------------

@pytest.mark.sanitize
def test_gen_secret_writes_an_owner_only_key_once(tmp_path):
    path = tmp_path / "alice.key"
    assert gen(path, "client") == f"wrote client key 'alice' to {path}\n"
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    line = path.read_text()
    assert re.fullmatch(r"texsyn:client:alice:[0-9a-f]{64}\n", line), line
    p = run(BUILD / "texsyn-server", "--gen-secret", "client", path, check=False)
    assert p.returncode == 1 and "exists: --gen-secret never overwrites a key" in p.stderr, p.stderr
    assert path.read_text() == line
    assert gen(tmp_path / "w", "worker:rack-7") == f"wrote worker key 'rack-7' to {tmp_path / 'w'}\n"
    assert (tmp_path / "w").read_text()[:-65] != line[:-65]
    for kind, why in (("boss", "admin, worker, client or page"), ("client:a b", "the key's name")):
        p = run(BUILD / "texsyn-server", "--gen-secret", kind, tmp_path / "x", check=False)
        assert p.returncode == 1 and why in p.stderr, p.stderr
    p = run(BUILD / "texsyn-server", "--gen-secret", "client", check=False)
    assert p.returncode == 2 and "give the key file's PATH" in p.stderr, p.stderr


@pytest.mark.sanitize
def test_a_secret_shorter_than_32_bytes_is_refused_everywhere(data, tmp_path):
    short = tmp_path / "short"
    short.write_text("x" * 31 + "\n")
    short.chmod(0o600)
    why = f"secret file {short} holds 31 bytes, fewer than 32"
    for exe, args in (("texsyn-server", ["--listen", "127.0.0.1:0", "--spool", tmp_path / "spool"]),
                      ("texsyn-worker", ["--listen", "127.0.0.1:0"])):
        p = subprocess.run([str(BUILD / exe), *map(str, args), "--secret-file", str(short)], capture_output=True,
                           text=True, timeout=30)
        assert p.returncode == 2 and why in p.stderr and "--gen-secret" in p.stderr, (exe, p.stderr)
    p = run(BUILD / "texsyn", "status", "--server", "127.0.0.1:9", "--secret-file", short, check=False)
    assert p.returncode == 1 and why in p.stderr, p.stderr


# ---- who may do what on the data plane -------------------------------------

@pytest.mark.sanitize
def test_each_key_only_in_its_own_role(data, cluster, keys, tmp_path):
    server = start(cluster, keys, workers=1)
    cluster.wait_ready(1)
    # The coordinator itself refuses, whatever a client program would check.
    assert handshake(server.addr, keys / "pool.key", 3) == (
        "E", "refused: worker key 'pool' cannot be used by a client; a client needs a client key "
             "(texsyn-server --gen-secret client PATH) or an admin key")
    assert handshake(server.addr, keys / "alice.key", 2) == (
        "E", "refused: client key 'alice' cannot be used by a worker; a worker needs a worker key "
             "(texsyn-server --gen-secret worker PATH) or an admin key")
    assert handshake(server.addr, keys / "prom.key", 3) == (
        "E", "refused: page key 'prom' opens the operations page only, never the data plane")
    ftype, _ = handshake(server.addr, keys / "alice.key", 3)
    assert ftype == "A"  # the proof: alice is let in as a client
    # An unknown name reads like a wrong secret.
    stranger = tmp_path / "zed.key"
    gen(stranger, "client")
    assert handshake(server.addr, stranger, 3) == (
        "E", "authentication failed: wrong secret, or no client key 'zed' here (the coordinator's --keys "
             "directory must hold that key's file)")
    log = server.read_log()
    assert "refused 127.0.0.1:" in log and "worker key 'pool' cannot be used by a client" in log
    # The programs say so before connecting.
    p = cli(server, keys / "pool.key", "status")
    assert p.returncode == 1 and "is a worker key; a client needs a client key" in p.stderr, p.stderr
    p = subprocess.run([str(BUILD / "texsyn-worker"), "--join", server.addr, "--secret-file", str(keys / "bob.key")],
                       capture_output=True, text=True, timeout=30)
    assert p.returncode == 2 and "is a client key; a worker needs a worker key" in p.stderr, p.stderr
    # And the worker key did its job: the embedded run's bytes.
    out, want = tmp_path / "a.png", tmp_path / "embedded.png"
    cli(server, keys / "alice.key", "synth", "--ref", ref_of(data), "-o", out, *SIZE, "--quiet", check=True)
    synth(BUILD / "texsyn", ref_of(data), want, (96, 64), "--levels", "3")
    assert out.read_bytes() == want.read_bytes()
    assert re.search(r"worker joining from \S+ \(texsyn-worker [^)]*\), worker key pool", log), log


@pytest.mark.sanitize
def test_only_the_owner_or_an_admin_acts_on_a_job(data, cluster, keys, tmp_path):
    server = start(cluster, keys, workers=1)
    job = submit(server, keys / "alice.key", data, tmp_path, env={"USER": "mallory"})
    cli(server, keys / "alice.key", "watch", job, check=True)
    for verb in ("fetch", "cancel", "delete"):
        args = [verb, job] + (["-o", tmp_path / "stolen.png"] if verb == "fetch" else [])
        p = cli(server, keys / "bob.key", *args)
        assert p.returncode == 1, p.stdout
        assert f"job {job} belongs to alice: only its owner or an admin key may {verb} it" in p.stderr, p.stderr
    assert not (tmp_path / "stolen.png").exists()
    # Bob sees that the job exists, not what it made.
    row = [r for r in jobs_listed(cli(server, keys / "bob.key", "status", check=True).stdout) if r["id"] == job]
    assert row and row[0]["owner"] == "alice" and row[0]["output"] == "-", row
    # The owner is the key's name, not the $USER the client reports.
    row = [r for r in jobs_listed(cli(server, keys / "alice.key", "status", check=True).stdout) if r["id"] == job]
    assert row[0]["owner"] == "alice" and row[0]["output"] != "-", row
    cli(server, keys / "alice.key", "fetch", job, "-o", tmp_path / "mine.png", check=True)
    assert (tmp_path / "mine.png").stat().st_size > 0
    cli(server, keys / "ops.key", "delete", job, check=True)  # the admin may
    assert f"job {job} deleted by 127.0.0.1:" in server.read_log()


def test_quotas_count_by_the_keys_name(data, cluster, keys, tmp_path):
    """--max-client-jobs 1: alice cannot get a second unfinished job by
    reporting another $USER; bob still can."""
    server = start(cluster, keys, "--max-client-jobs", "1", "--jobs", "1", "--threads", "1")
    big = ("--size", "1024x1024", "--levels", "5")
    submit(server, keys / "alice.key", data, tmp_path, *big, env={"USER": "one"})
    p = cli(server, keys / "alice.key", "synth", "--ref", ref_of(data), "-o", tmp_path / "u.png", *SIZE,
            "--detach", env={"USER": "two"})
    assert p.returncode == 1, p.stdout
    assert "client alice already has 1 unfinished jobs, the limit (--max-client-jobs)" in p.stderr, p.stderr
    submit(server, keys / "bob.key", data, tmp_path, env={"USER": "one"})


def test_the_coordinator_proves_itself_to_listening_workers_with_their_key(data, cluster, keys, tmp_path):
    good = cluster.worker(1, "--secret-file", keys / "pool.key")
    other = tmp_path / "other.key"
    gen(other, "worker")
    stray = cluster.worker(1, "--secret-file", other)
    server = start(cluster, keys, "--workers", f"{good.addr},{stray.addr}")
    cluster.wait_ready(1)
    assert [w["addr"] for w in cluster.pool() if w["state"] == "active"] == [good.addr]
    server.wait_log(re.escape(f"{stray.addr}: authentication failed: {stray.addr} uses worker key 'other', which is "
                              "not in this coordinator's --keys or --secret-file"))
    # A client key cannot pose as the coordinator to a worker.
    assert handshake(good.addr, keys / "alice.key", 1) == (
        "E", "authentication failed: wrong secret, or not the worker key 'pool' this worker holds")


def test_keys_rotate_on_sighup_without_losing_a_job(data, cluster, keys, tmp_path):
    server = start(cluster, keys, workers=1)
    job = submit(server, keys / "alice.key", data, tmp_path)
    fresh = tmp_path / "alice-new.key"
    gen(fresh, "client:alice")
    assert cli(server, fresh, "status").returncode == 1  # not yet known
    os.link(fresh, keys / "alice-2.key")
    server.proc.send_signal(signal.SIGHUP)
    server.wait_log(r"SIGHUP: keys reloaded: 1 admin, 1 worker, 3 client, 1 page")
    cli(server, keys / "alice.key", "status", job, check=True)  # both work meanwhile
    cli(server, fresh, "watch", job, check=True)
    (keys / "alice.key").rename(tmp_path / "alice-old.key")
    server.proc.send_signal(signal.SIGHUP)
    server.wait_log(r"SIGHUP: keys reloaded: 1 admin, 1 worker, 2 client, 1 page")
    p = cli(server, tmp_path / "alice-old.key", "status")
    assert p.returncode == 1 and "wrong secret, or no client key 'alice' here" in p.stderr, p.stderr
    cli(server, fresh, "fetch", job, "-o", tmp_path / "kept.png", check=True)  # the job is still alice's
    assert (tmp_path / "kept.png").stat().st_size > 0
    # A broken key file: the reload fails and the keys in use stay.
    bad = keys / "broken.key"
    bad.write_text("not a key at all, but long enough to be one\n")
    bad.chmod(0o600)
    server.proc.send_signal(signal.SIGHUP)
    server.wait_log(r"SIGHUP: keys not reloaded, the ones in use stay: .*broken.key is not a typed key")
    cli(server, fresh, "status", job, check=True)


# ---- the page ----------------------------------------------------------------

def get(url, auth=None, context=None, source=None, timeout=10):
    req = urllib.request.Request(url, headers={"Authorization": auth} if auth else {})
    try:
        with urllib.request.urlopen(req, timeout=timeout, context=context) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def http_addr(server):
    return server.wait_log(r"http page on (\S+?)[, ]").group(1)


@pytest.mark.sanitize
def test_the_page_takes_a_page_or_admin_key_never_a_data_plane_key(data, cluster, keys, tmp_path):
    server = start(cluster, keys, "--http", ":0")
    base = "http://" + http_addr(server)
    for name, code in (("prom", 200), ("ops", 200), ("alice", 401), ("pool", 401)):
        token = key_line(keys / f"{name}.key").decode()
        assert get(base + "/metrics", "Bearer " + token)[0] == code, name
    code, body = get(base + "/status.json")
    assert code == 401 and b"needs a page key or an admin key" in body


def self_signed(tmp_path):
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    run("/usr/bin/openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
        "-keyout", key, "-out", cert, "-days", "1", "-subj", "/CN=localhost",
        "-addext", "subjectAltName=IP:127.0.0.1")
    key.chmod(0o600)
    return cert, key


@pytest.mark.sanitize
def test_the_page_over_https(data, cluster, keys, tmp_path):
    cert, key = self_signed(tmp_path)
    for args in (["--http-cert", cert, "--http-key", key], ["--http", ":0", "--http-cert", cert]):
        p = run(BUILD / "texsyn-server", "--spool", tmp_path / "spool", *args, check=False, timeout=30)
        assert p.returncode == 2 and "--http-cert and --http-key go together, with --http" in p.stderr, p.stderr
    server = start(cluster, keys, "--http", "127.0.0.1:0", "--http-cert", cert, "--http-key", key)
    addr = http_addr(server)
    assert f"http page on {addr} over HTTPS, pages need a page or admin key" in server.read_log()
    ctx = ssl.create_default_context(cafile=str(cert))
    token = "Bearer " + key_line(keys / "prom.key").decode()
    code, body = get(f"https://{addr}/status.json", token, context=ctx)
    assert code == 200 and json.loads(body)["jobs"] == []
    with pytest.raises((urllib.error.URLError, ConnectionError, OSError)):
        get(f"http://{addr}/status.json", token, timeout=3)  # no plain HTTP there


def test_the_page_beyond_loopback_needs_https_when_keys_guard_it(data, cluster, keys, tmp_path):
    p = run(BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool", "--keys", keys,
            "--http", "0.0.0.0:0", check=False, timeout=30)
    assert p.returncode == 1, p.stdout
    assert ("--http 0.0.0.0:0: the page would send its keys in the clear beyond loopback: give --http-cert and "
            "--http-key (HTTPS), or keep --http on loopback behind a TLS reverse proxy (deploy/README.md, \"Who may look\")"
            in p.stderr), p.stderr
    cert, key = self_signed(tmp_path)
    server = start(cluster, keys, "--http", "0.0.0.0:0", "--http-cert", cert, "--http-key", key)
    port = http_addr(server).rsplit(":", 1)[1]
    ctx = ssl.create_default_context(cafile=str(cert))
    assert get(f"https://127.0.0.1:{port}/metrics", "Bearer " + key_line(keys / "ops.key").decode(),
               context=ctx)[0] == 200


def slow_connections(port, n, sources):
    """n connections that send half a request line and then nothing, from
    the given loopback addresses in turn."""
    socks = []
    for i in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.bind((sources[i % len(sources)], 0))
        s.connect(("127.0.0.1", port))
        s.sendall(b"GET /status.js")
        socks.append(s)
    return socks


def test_slow_connections_do_not_keep_the_page_from_a_fresh_client(cluster, tmp_path):
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                             "--http", ":0"], tmp_path / "server.log")
    port = int(http_addr(cluster.server).rsplit(":", 1)[1])
    sources = [f"127.0.0.{i}" for i in range(2, 22)]
    socks = slow_connections(port, 32, sources[:1]) + slow_connections(port, 300, sources)
    try:
        t0 = time.monotonic()
        code, body = get(f"http://127.0.0.1:{port}/status.json", timeout=5)
        took = time.monotonic() - t0
        assert code == 200 and "jobs" in json.loads(body)
        assert took < 1.0, took
        # One address holds at most 16: the 17th from it is closed at once.
        extra = slow_connections(port, 1, sources[:1])[0]
        extra.settimeout(5)
        try:
            assert extra.recv(100) == b""
        except ConnectionResetError:
            pass  # closed unread: a reset
        extra.close()
    finally:
        for s in socks:
            s.close()


# ---- what a worker may claim --------------------------------------------------

class ClaimsFourfold:
    """Between the coordinator and one worker: passes everything, but
    multiplies the comparisons every 'V' answer reports by four, as a
    worker that wants most of the reference would."""

    def __init__(self, target):
        from hostile import FrameReader
        self.FrameReader, self.target = FrameReader, target
        self.lsock = socket.create_server(("127.0.0.1", 0))
        self.addr = f"127.0.0.1:{self.lsock.getsockname()[1]}"
        self.socks = []
        threading.Thread(target=self.accept, daemon=True).start()

    def accept(self):
        while True:
            try:
                coord, _ = self.lsock.accept()
            except OSError:
                return
            host, port = self.target.rsplit(":", 1)
            worker = socket.create_connection((host, int(port)))
            self.socks += [coord, worker]
            threading.Thread(target=self.copy, args=(coord, worker), daemon=True).start()
            threading.Thread(target=self.answers, args=(worker, coord), daemon=True).start()

    @staticmethod
    def copy(src, dst):
        try:
            while data := src.recv(1 << 16):
                dst.sendall(data)
        except OSError:
            pass
        for s in (src, dst):
            s.close()

    def answers(self, src, dst):
        reader = self.FrameReader()
        try:
            while data := src.recv(1 << 16):
                reader.feed(data)
                for f in reader.frames():
                    if f.type != "V":
                        dst.sendall(f.raw)
                        continue
                    p = bytearray(f.payload)
                    pairs = struct.unpack_from("<Q", p, 20)[0]  # after set, gen, count, scan time
                    struct.pack_into("<Q", p, 20, pairs * 4)
                    dst.sendall(frame_bytes("V", f.id, bytes(p)))
        except OSError:
            pass
        for s in (src, dst):
            s.close()

    def close(self):
        self.lsock.close()
        for s in self.socks:
            s.close()


def test_a_worker_cannot_claim_more_than_calibration_measured(data, cluster, tmp_path):
    honest, liar = cluster.worker(1), cluster.worker(1)
    relay = ClaimsFourfold(liar.addr)
    try:
        cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                                 "--workers", f"{honest.addr},{relay.addr}", "--rebalance-after", "0.5",
                                 "--rebalance-tolerance", "0.05",
                                 "--rebalance-from", "batches"], tmp_path / "server.log")
        cluster.wait_ready(2)
        run(BUILD / "texsyn", "synth", "--server", cluster.server.addr, "--ref", ref_of(data), "-o",
            tmp_path / "out.png", "--size", "400x300", "--quiet")
        log = cluster.server.read_log()
        assert "rebalance 1: rates deviated" in log, log  # the claim was acted on
        w = {x["addr"]: x for x in cluster.pool()}[relay.addr]
        assert w["rate"] <= 1.25 * w["calibrated"] * 1.001, w
    finally:
        relay.close()


def test_a_request_trickled_in_is_cut_at_its_deadline(cluster, tmp_path):
    """A byte every 2 s never lets the idle timeout fire; the request's own
    deadline (10 s from the connection) does."""
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                             "--http", ":0"], tmp_path / "server.log")
    port = int(http_addr(cluster.server).rsplit(":", 1)[1])
    s = socket.create_connection(("127.0.0.1", port), timeout=30)
    t0 = time.monotonic()
    trickle = b"GET /status.json HTTP/1.1\r\nX-Slow: " + b"a" * 100
    closed = None
    for i in range(len(trickle)):
        try:
            s.sendall(trickle[i:i + 1])
            s.settimeout(2)
            if s.recv(100) == b"":
                closed = time.monotonic() - t0
                break
        except socket.timeout:
            continue
        except OSError:
            closed = time.monotonic() - t0
            break
        if time.monotonic() - t0 > 25:
            break
    s.close()
    assert closed is not None and 9.5 < closed < 13, closed
    cluster.server.wait_log(r"http: closed 1 connection that sent no whole request within 10 s")
    assert get(f"http://127.0.0.1:{port}/metrics")[0] == 200
