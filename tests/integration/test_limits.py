"""Limits of the coordinator: unfinished jobs per client and the spool's
disk use. A submission past a limit is refused with a message that says
which limit and what to do, other clients' jobs carry on, and deleting
finished jobs gives the space back (their ids are never reused). And no
request names a file outside the spool."""
import socket
import struct

import pytest

from conftest import BUILD, Daemon, run, synth, FRAME_START

SMALL = ["--size", "96x64", "--levels", "3"]
LONG = ["--size", "768x768"]  # seconds on a lone coordinator: stays unfinished


def ref_of(data):
    return data / "textures" / "brick.png"


def as_client(cluster, user, *args, check=True):
    """`texsyn ARGS --server ...` as another user: the coordinator tells
    clients apart by the user@host they identify with."""
    return run(BUILD / "texsyn", *args, "--server", cluster.server.addr, env={"USER": user}, check=check)


def submit(cluster, user, data, out, *job):
    p = as_client(cluster, user, "synth", "--ref", ref_of(data), "-o", out, *job, "--detach", check=False)
    return p.returncode, p.stdout.strip(), p.stderr


def test_per_client_job_limit_refuses_only_that_client(texsyn, data, cluster, tmp_path):
    cluster.start(0, 1, "--jobs", "1", "--max-client-jobs", "2")
    ids = []
    for i in range(2):
        code, job, err = submit(cluster, "alice", data, tmp_path / "a.png", *LONG, "--seed", str(i + 1))
        assert code == 0, err
        ids.append(job)
    code, _, err = submit(cluster, "alice", data, tmp_path / "a.png", *LONG)
    assert code != 0
    assert "already has 2 unfinished jobs" in err and "--max-client-jobs" in err, err
    code, bob, err = submit(cluster, "bob", data, tmp_path / "b.png", *SMALL)
    assert code == 0, err
    # A running job cannot be deleted; canceling it frees alice's slot.
    busy = as_client(cluster, "alice", "delete", ids[0], check=False)
    assert busy.returncode == 1 and "cancel it first" in busy.stderr, busy.stderr
    as_client(cluster, "alice", "cancel", ids[0])
    code, again, err = submit(cluster, "alice", data, tmp_path / "a.png", *SMALL)
    assert code == 0, err
    as_client(cluster, "alice", "cancel", ids[1])  # still queued: never starts
    assert " canceled" in as_client(cluster, "alice", "status", ids[1]).stdout
    for job in (bob, again):
        as_client(cluster, "bob", "watch", job, "--quiet")
    want = tmp_path / "want.png"
    synth(texsyn, ref_of(data), want, (96, 64), "--levels", "3")
    as_client(cluster, "bob", "fetch", bob, "-o", tmp_path / "bob.png")
    assert (tmp_path / "bob.png").read_bytes() == want.read_bytes()
    assert cluster.server.alive()


def test_spool_limit_refuses_until_jobs_are_deleted(texsyn, data, cluster, tmp_path):
    cluster.start(0, 1, "--max-spool", "1M")  # one small job reserves ~0.4 MiB, at most half
    done = []
    for i in range(10):
        code, job, err = submit(cluster, "carol", data, tmp_path / "c.png", *SMALL, "--seed", str(i + 1))
        if code != 0:
            break
        as_client(cluster, "carol", "watch", job, "--quiet")
        done.append(job)
    assert code != 0, "ten jobs fit a 1 MiB spool?"
    assert "spool is full" in err and "--max-spool" in err and "texsyn delete" in err, err
    assert 1 <= len(done) < 10
    as_client(cluster, "carol", "delete", done[0])
    status = as_client(cluster, "carol", "status").stdout
    assert not any(line.split()[0] == done[0] for line in status.splitlines()), status
    gone = as_client(cluster, "carol", "fetch", done[0], "-o", tmp_path / "x.png", check=False)
    assert gone.returncode == 1 and f"no job {done[0]}" in gone.stderr
    code, job, err = submit(cluster, "carol", data, tmp_path / "c.png", *SMALL)
    assert code == 0, err
    as_client(cluster, "carol", "watch", job, "--quiet")
    missing = as_client(cluster, "carol", "delete", "9999", check=False)
    assert missing.returncode == 1 and "no job 9999" in missing.stderr


@pytest.mark.sanitize
def test_deleted_ids_are_not_reused_after_a_restart(data, cluster, tmp_path):
    cluster.start(0, 1)
    code, job, err = submit(cluster, "dave", data, tmp_path / "d.png", *SMALL)
    assert code == 0, err
    as_client(cluster, "dave", "watch", job, "--quiet")
    as_client(cluster, "dave", "delete", job)
    cluster.server.stop()
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", cluster.tmp / "spool"],
                            cluster.tmp / "server2.log")
    code, again, err = submit(cluster, "dave", data, tmp_path / "d.png", *SMALL)
    assert code == 0, err
    assert int(again) > int(job)


# ---- nothing outside the spool ---------------------------------------------

def raw_call(addr, kind, payload):
    """One request on a fresh connection after the identify exchange;
    returns (reply type, reply payload)."""
    name = b"raw-client"
    ident = struct.pack("<BIHB", 3, 7, 0, 0) + struct.pack("<H", len(name)) + name

    def frame(t, body, fid):
        return FRAME_START + t + struct.pack("<II", len(body), fid) + body

    def read_frame(s):
        head = recv_exact(s, 12)
        body = recv_exact(s, struct.unpack_from("<I", head, 4)[0])
        return head[3:4], body

    host, port = addr.rsplit(":", 1)
    with socket.create_connection((host, int(port)), timeout=30) as s:
        s.sendall(frame(b"I", ident, 0))
        read_frame(s)
        s.sendall(frame(kind, payload, 7))
        return read_frame(s)


def recv_exact(s, n):
    buf = b""
    while len(buf) < n:
        chunk = s.recv(n - len(buf))
        assert chunk, "connection closed"
        buf += chunk
    return buf


def submit_payload(spec, ref_name, ref):
    spec, name = spec.encode(), ref_name.encode()
    return struct.pack("<I", len(spec)) + spec + struct.pack("<H", len(name)) + name + struct.pack("<I", len(ref)) + ref


@pytest.mark.sanitize
def test_requests_cannot_reach_outside_the_spool(data, cluster, tmp_path):
    """Hostile names in a raw submit: a reference name full of '../' only
    lends its extension, and outputs with a path in their extension are
    refused; job ids are numbers, so fetch and delete name nothing else."""
    cluster.start(0, 1)
    ref = ref_of(data).read_bytes()
    spool = cluster.tmp / "spool"
    before = set(p for p in cluster.tmp.rglob("*") if spool not in p.parents)
    kind, body = raw_call(cluster.server.addr, b"S",
                          submit_payload("size=64x48\nlevels=3\n", "../../../../escape/../x/evil.png", ref))
    assert kind == b"S", body
    job = str(struct.unpack("<Q", body)[0])
    files = sorted(p.name for p in (spool / "jobs" / job).iterdir())
    assert "ref.png" in files, files
    for spec, name in [("size=64x48\noutput=../../x\n", "a.png"), ("size=64x48\ncopy_map=/etc/passwd\n", "a.png"),
                       ("size=64x48\n", "evil.png/../../x"), ("size=64x48\n", "noext")]:
        kind, body = raw_call(cluster.server.addr, b"S", submit_payload(spec, name, ref))
        assert kind == b"E", (spec, name)
        assert b"extension" in body or b"output" in body or b"copy_map" in body, body
    for kind_, payload in [(b"F", struct.pack("<Q", 2**64 - 1)), (b"D", struct.pack("<Q", 0))]:
        kind, body = raw_call(cluster.server.addr, kind_, payload)
        assert kind == b"E" and b"no job" in body, body
    after = set(p for p in cluster.tmp.rglob("*") if spool not in p.parents)
    assert after == before, after - before
    run(BUILD / "texsyn", "watch", job, "--quiet", "--server", cluster.server.addr)


def test_full_pool_refuses_workers_before_calibrating_them(texsyn, data, cluster, tmp_path):
    """--max-workers 2 with three addresses: two serve, the third is not even
    dialled (a refusal after its calibration would cost it a scan every
    0.5 s), and a job runs on the two."""
    for _ in range(3):
        cluster.worker(1)
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                             "--max-workers", "2", "--workers", ",".join(w.addr for w in cluster.workers)],
                            tmp_path / "server.log")
    cluster.wait_ready(2)
    out = tmp_path / "out.png"
    cluster.texsyn("synth", "--ref", data / "textures" / "brick.png", "-o", out, "--size", "96x96", "--levels", "2",
                   "--quiet")
    log = cluster.server.read_log()
    assert "the pool is full (2 workers, texsyn-server --max-workers); not dialled while it is" in log, log
    calibrated = [w for w in cluster.workers if "calibrated for" in w.read_log()]
    assert len(calibrated) == 2, [w.read_log() for w in cluster.workers]


# ---- what one message may make a worker allocate -------------------------------

def vm_rss_kib(pid):
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


@pytest.mark.sanitize
def test_a_tiny_image_message_cannot_grow_a_worker_past_its_budget(cluster, tmp_path):
    """A 1x1 query image with a copy map, then a 47-byte 'R' asking for its
    next level at 8192x8192 (about 640 MiB): refused before anything is
    allocated, with the budget in the message; the connection stays."""
    w = cluster.worker(1, "--max-replica-memory", "64M")
    host, port = w.addr.rsplit(":", 1)

    def frame(t, body, fid):
        return FRAME_START + t + struct.pack("<II", len(body), fid) + body

    def read_frame(s):
        head = recv_exact(s, 12)
        return head[3:4], recv_exact(s, struct.unpack_from("<I", head, 4)[0])

    name = b"fake-coordinator"
    load = (struct.pack("<IBQ", 1, 1, 0) + struct.pack("<IIBIIBH", 1, 1, 1, 0, 0, 0, 1) + b"\x80"
            + struct.pack("<II", 1, 1) + b"\x40" + struct.pack("<II", 0, 0))
    nxt = struct.pack("<IBQ", 1, 2, 0) + struct.pack("<IIIIIB", 0, 8192, 8192, 1, 1, 1) + b"\x40"
    assert len(frame(b"R", nxt, 3)) == 47
    with socket.create_connection((host, int(port)), timeout=30) as s:
        s.sendall(frame(b"I", struct.pack("<BIHB", 1, 7, 0, 0) + struct.pack("<H", len(name)) + name, 0))
        assert read_frame(s)[0] == b"I"
        s.sendall(frame(b"R", load, 2))
        assert read_frame(s) == (b"R", struct.pack("<I", 1))
        before = vm_rss_kib(w.proc.pid)
        s.sendall(frame(b"R", nxt, 3))
        kind, body = read_frame(s)
        grew = vm_rss_kib(w.proc.pid) - before
        assert kind == b"E", (kind, body)
        text = body[6:].decode()
        assert "8192x8192 query image needs" in text and "--max-replica-memory is 64.0 MiB" in text, text
        assert grew < 16 * 1024, f"the worker grew by {grew} KiB"
        s.sendall(frame(b"H", b"", 4))  # still served
        assert read_frame(s) == (b"H", b"\x00")  # not draining
    assert w.alive()


def tiff_header(w, h, channels, bits, sample_format):
    """A little-endian TIFF that declares w x h pixels of `channels`
    samples and leaves the pixels out: what a probe of its header sees."""
    tags = [(256, 4, 1, w), (257, 4, 1, h), (258, 3, channels, bits), (259, 3, 1, 1), (262, 3, 1, 2),
            (273, 4, 1, 8), (277, 3, 1, channels), (278, 4, 1, h), (279, 4, 1, 0xFFFFFFFF), (284, 3, 1, 1),
            (338, 3, channels - 3, 2), (339, 3, channels, sample_format)]
    out_of_line = 8 + 2 + 12 * len(tags) + 4
    entries, extra = b"", b""
    for tag, typ, count, value in tags:
        if typ == 3 and count > 2:  # the values do not fit the entry
            entries += struct.pack("<HHII", tag, typ, count, out_of_line + len(extra))
            extra += struct.pack(f"<{count}H", *[value] * count)
        elif typ == 3:
            entries += struct.pack("<HHIHH", tag, typ, count, value, value if count == 2 else 0)
        else:
            entries += struct.pack("<HHII", tag, typ, count, value)
    return b"II*\x00" + struct.pack("<IH", 8, len(tags)) + entries + b"\x00" * 4 + extra


@pytest.mark.sanitize
def test_an_input_that_decodes_to_16_gib_is_refused_before_decoding(data, cluster, tmp_path):
    """16384x16384 with 16 float channels: within --max-pixels, 16 GiB
    decoded. Refused from its header, with its size and the option; the
    coordinator's memory does not move."""
    cluster.start(0, 1)
    big = tiff_header(16384, 16384, 16, 32, 3)
    rss = vm_rss_kib(cluster.server.proc.pid)
    kind, body = raw_call(cluster.server.addr, b"S", submit_payload("size=64x48\nlevels=3\n", "big.tif", big))
    assert kind == b"E", body
    text = body[6:].decode()
    assert ("decode to 16384.0 MiB, over texsyn-server --max-input-memory (4096.0 MiB)" in text
            and "big.tif, is 16384x16384 with 16 channels of float" in text), text
    assert vm_rss_kib(cluster.server.proc.pid) - rss < 64 * 1024
    assert not any((cluster.tmp / "spool" / "jobs").iterdir())
    kind, body = raw_call(cluster.server.addr, b"S", submit_payload("size=64x48\nlevels=3\n", "r.png",
                                                                   ref_of(data).read_bytes()))
    assert kind == b"S", body


def test_one_job_cannot_reserve_most_of_the_spool(data, cluster, tmp_path):
    """A job whose reserve (33 MiB) fits --max-spool but is more than half
    of it is refused, naming the size that would take it; a smaller one is
    queued."""
    cluster.start(0, 1, "--max-spool", "48M")
    code, _, err = submit(cluster, "dave", data, tmp_path / "d.png", "--size", "1024x1024", "--levels", "3")
    assert code != 0
    assert "this job alone needs about" in err and "more than half of --max-spool (48.0 MiB)" in err, err
    code, job, err = submit(cluster, "dave", data, tmp_path / "d.png", *SMALL)
    assert code == 0, err
    as_client(cluster, "dave", "watch", job, "--quiet")
