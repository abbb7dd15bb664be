"""Load: 50 small jobs from 5 concurrent clients on a 3-worker pool, one
worker SIGKILLed mid-run. Every job completes exactly once, under the id
its client was given, with the bytes of the embedded run of the same job;
clients with a backlog of detached jobs are served in turn."""
import re
import signal
import socket
import struct
import threading
import time

import pytest

from conftest import BUILD, jobs_listed, run, FRAME_START

CLIENTS = 5
JOBS_PER_CLIENT = 10
SYNC_CLIENTS = (0, 1, 2)      # `texsyn synth --server`: waits for each result
DETACHED_CLIENTS = (3, 4)     # `--detach` all ten, then `watch` and `fetch` each;
                              # 4 submits once 3 has a backlog of ten
KILL_AFTER_STARTED = 8        # jobs started before a worker is killed, mid-job
SERVER_ARGS = ["--calibrate-ms", "50", "--heartbeat", "0.5", "--batch-timeout", "0.5"]

# Ten distinct jobs; every client submits all ten in its own order, so the
# embedded references cost ten runs, not fifty.
COMBOS = [("brick.png" if i % 2 == 0 else "grass.png",
           (64 + 16 * (i % 5), 48 + 12 * (i % 5)), 100 + i) for i in range(10)]

STATES = ["queued", "running", "done", "failed", "canceled"]


def job_args(data, combo):
    ref, (w, h), seed = combo
    return ["--ref", data / "textures" / ref, "--size", f"{w}x{h}", "--levels", "3", "--seed", seed]


# ---- `W status` over one connection ----------------------------------------

def recv_exact(s, n):
    buf = b""
    while len(buf) < n:
        chunk = s.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("coordinator closed the connection")
        buf += chunk
    return buf


class StatusConn:
    """A client connection that asks for every job's status (`W`, id 0) in
    one consistent snapshot; a `texsyn status` process per poll would cost
    a third of a core on this machine."""

    def __init__(self, addr):
        host, port = addr.rsplit(":", 1)
        self.sock = socket.create_connection((host, int(port)), timeout=30)
        name = b"load-poller"
        self.call(b"I", struct.pack("<BIHB", 3, 7, 0, 0) + struct.pack("<H", len(name)) + name)

    def call(self, t, payload):
        self.sock.sendall(FRAME_START + t + struct.pack("<II", len(payload), 1) + payload)
        head = recv_exact(self.sock, 12)
        assert head[:2] == b"TS" and head[3:4] == t, f"unexpected reply {head!r}"
        return recv_exact(self.sock, struct.unpack("<I", head[4:8])[0])

    def snapshot(self):
        """{job id: state name} for every job the coordinator knows."""
        p = self.call(b"W", struct.pack("<QB", 0, 0))
        n, off, jobs = struct.unpack_from("<I", p)[0], 4, {}
        for _ in range(n):
            jid, state = struct.unpack_from("<QB", p, off)
            off += 8 + 1 + 1 + 1 + 2 + 4 + 2
            tlen = struct.unpack_from("<H", p, off)[0]
            off += 2 + tlen
            jobs[jid] = STATES[state]
        return jobs

    def close(self):
        self.sock.close()


# ---- the clients -------------------------------------------------------------

def texsyn(cluster, client, *args, timeout=300):
    """A texsyn command as client `client` (USER names it to the coordinator)."""
    return run(BUILD / "texsyn", *args, "--server", cluster.server.addr, env={"USER": f"load{client}"},
               timeout=timeout)


def order(client):
    return [COMBOS[(3 * client + k) % len(COMBOS)] for k in range(JOBS_PER_CLIENT)]


def sync_client(cluster, data, tmp, client, results):
    for k, combo in enumerate(order(client)):
        out = tmp / f"c{client}-{k}.png"
        p = texsyn(cluster, client, "synth", *job_args(data, combo), "-o", out)
        m = re.search(r"\(job (\d+) on ", p.stderr)
        assert m, f"client {client}: no job id in {p.stderr!r}"
        results.append((client, int(m.group(1)), combo, out))


def detached_client(cluster, data, tmp, client, results, backlog):
    if client != DETACHED_CLIENTS[0]:
        assert backlog.wait(timeout=120), f"client {DETACHED_CLIENTS[0]} never finished submitting"
    ids = []
    try:
        for combo in order(client):
            p = texsyn(cluster, client, "synth", *job_args(data, combo), "-o", tmp / "unused.png", "--detach")
            assert p.stdout.strip().isdigit(), f"client {client}: --detach printed {p.stdout!r}"
            ids.append(int(p.stdout))
    finally:
        backlog.set()
    for k, (jid, combo) in enumerate(zip(ids, order(client))):
        texsyn(cluster, client, "watch", jid, "--quiet")
        out = tmp / f"c{client}-{k}.png"
        texsyn(cluster, client, "fetch", jid, "-o", out)
        results.append((client, jid, combo, out))


def embedded_references(texsyn_exe, data, tmp):
    refs = {}
    for i, combo in enumerate(COMBOS):
        out = tmp / f"embedded{i}.png"
        run(texsyn_exe, "synth", *job_args(data, combo), "-o", out, "--quiet", "--embedded")
        refs[combo] = out.read_bytes()
    return refs


@pytest.mark.long  # 30 s of load: make test-faults
def test_fifty_jobs_five_clients_one_worker_killed(texsyn, data, cluster, tmp_path):
    want = embedded_references(texsyn, data, tmp_path)
    cluster.start(3, 1, *SERVER_ARGS)
    results, errors, snapshots = [], [], []
    backlog = threading.Event()

    def guard(fn, *args):
        try:
            fn(*args)
        except BaseException as e:  # reported after the join
            errors.append(e)

    threads = [threading.Thread(target=guard, args=(sync_client, cluster, data, tmp_path, c, results))
               for c in SYNC_CLIENTS]
    threads += [threading.Thread(target=guard, args=(detached_client, cluster, data, tmp_path, c, results, backlog))
                for c in DETACHED_CLIENTS]
    t0 = time.time()
    for t in threads:
        t.start()
    poller = StatusConn(cluster.server.addr)
    victim, killed_at = cluster.workers[1], None
    try:
        while any(t.is_alive() for t in threads):
            snap = poller.snapshot()
            snapshots.append(snap)
            started = sum(1 for s in snap.values() if s != "queued")
            running = "running" in snap.values()
            if killed_at is None and started >= KILL_AFTER_STARTED and running:
                victim.proc.send_signal(signal.SIGKILL)
                killed_at = started
            time.sleep(0.05)
        final = poller.snapshot()
    finally:
        poller.close()
        for t in threads:
            t.join()
    elapsed = time.time() - t0
    log = cluster.server.read_log()
    assert not errors, f"{errors}\n{log}"
    assert killed_at is not None, "the run ended before a worker was killed"
    assert victim.proc.wait(timeout=10) == -signal.SIGKILL
    assert "dropped" in log, "the coordinator never noticed the killed worker"
    # It dials the dead address every 0.5 s for the rest of the run, and says so once.
    assert log.count(f"worker {victim.addr}: cannot connect") == 1, log
    assert cluster.server.alive()

    # None lost, none duplicated: the coordinator knows exactly the 50 ids
    # the clients were given, each once, each done.
    assert len(results) == CLIENTS * JOBS_PER_CLIENT
    ids = [jid for _, jid, _, _ in results]
    assert len(set(ids)) == len(ids), f"an id was given twice: {sorted(ids)}"
    assert sorted(final) == sorted(ids), f"coordinator jobs {sorted(final)} != client jobs {sorted(ids)}"
    assert set(final.values()) == {"done"}, final
    listing = cluster.texsyn("status").stdout
    rows = jobs_listed(listing)
    assert sorted(int(r["id"]) for r in rows) == sorted(ids), listing
    assert all(r["state"] == "done" for r in rows), listing
    owner = {int(j): int(c) for j, c in re.findall(r"job (\d+) queued from \S+ \(load(\d+)@", log)}
    assert {jid: c for c, jid, _, _ in results} == owner, "a job is filed under another client"

    # Every output is the embedded run's.
    for client, jid, combo, out in results:
        assert out.read_bytes() == want[combo], f"client {client} job {jid} {combo}: output differs"

    # Fairness: client a queued ten jobs before b queued any. The next job
    # comes from the client with the fewest started, so b's jobs go first
    # until b has caught up with a - long before a's backlog is gone (first
    # come, first served would run all of a's first) - and from then on
    # neither runs ahead while both have jobs waiting.
    a, b = DETACHED_CLIENTS
    worst, caught_up = 0, False
    for snap in snapshots:
        queued = {c: 0 for c in (a, b)}
        started = {c: 0 for c in (a, b)}
        for jid, state in snap.items():
            c = owner.get(jid)
            if c in queued:
                (queued if state == "queued" else started)[c] += 1
        if queued[a] and queued[b]:
            caught_up = caught_up or started[b] >= started[a]
            if caught_up:
                worst = max(worst, abs(started[a] - started[b]))
    assert caught_up, f"client {b} never caught up with client {a}'s backlog"
    assert worst <= 2, f"one backlogged client ran {worst} jobs ahead of the other"
    print(f"load: {len(ids)} jobs in {elapsed:.1f} s, worker killed after {killed_at} started, "
          f"{len(snapshots)} snapshots, backlog skew {worst}")
