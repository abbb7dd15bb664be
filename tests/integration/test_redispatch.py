"""Bounded re-dispatch: a slice that keeps crashing the workers it is given
fails its job with a reason, instead of taking the pool down one worker
after another, and the coordinator goes on serving.

Four real workers sit behind frame-aware proxies that forward frames
unchanged, except that the first reference set has a "poisoned" slice:
the worker holding its first vector dies (the proxy resets its
connection) when it is asked a batch. Re-slicing hands that vector to the
next worker, which dies too, and so on."""
import socket
import struct
import threading

import pytest

from conftest import BUILD, Daemon, LoopbackProxy, shutdown_all, synth, slice_ranges

JOB = ["--size", "96x64", "--levels", "3"]


def ref_of(data):
    return data / "textures" / "brick.png"


class Poison:
    """Shared state: the poisoned set (the first one loaded) and the
    workers killed so far."""

    def __init__(self, kills):
        self.lock = threading.Lock()
        self.set = None
        self.kills = kills
        self.killed = []


class FrameProxy(LoopbackProxy):
    """Forwards one loopback port to a worker frame by frame. It remembers
    the slices loaded through it ('N': set id, then per-class vector
    ranges) and resets both connections instead of forwarding a batch ('V') of
    the poisoned set while it holds that set's first vector."""

    def __init__(self, index, target, poison):
        self.index, self.poison = index, poison
        self.first = {}  # set id -> (i0, i1) of class 0 held through this proxy
        super().__init__(target)

    def forward(self, a, b):
        threading.Thread(target=self.to_worker, args=(a, b), daemon=True).start()
        threading.Thread(target=self.plain, args=(b, a), daemon=True).start()

    def dies_on(self, frame):
        kind, body = frame[3:4], frame[12:]
        p = self.poison
        with p.lock:
            if kind == b"N":
                set_id = struct.unpack_from("<I", body, 0)[0]
                if p.set is None:
                    p.set = set_id
                self.first[set_id] = slice_ranges(body)[0]
            if kind != b"V" or struct.unpack_from("<I", body, 0)[0] != p.set or len(p.killed) >= p.kills:
                return False
            i0, i1 = self.first.get(p.set, (1, 1))
            if i0 == 0 and i1 > 0:
                p.killed.append(self.index)
                return True
        return False

    def to_worker(self, src, dst):
        buf = b""
        try:
            while True:
                data = src.recv(65536)
                if not data:
                    break
                buf += data
                while len(buf) >= 12:
                    length = struct.unpack_from("<I", buf, 4)[0]
                    if len(buf) < 12 + length:
                        break
                    frame, buf = buf[:12 + length], buf[12 + length:]
                    if self.dies_on(frame):
                        reset(src, dst)
                        return
                    dst.sendall(frame)
        except OSError:
            pass
        shutdown_all(src, dst)

    def plain(self, src, dst):
        try:
            while True:
                data = src.recv(65536)
                if not data:
                    break
                dst.sendall(data)
        except OSError:
            pass
        shutdown_all(src, dst)



def reset(*socks):
    for s in socks:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        s.close()


@pytest.mark.sanitize
def test_batch_that_keeps_killing_workers_fails_its_job_not_the_pool(texsyn, data, cluster, tmp_path):
    workers = [cluster.worker(1) for _ in range(4)]
    poison = Poison(kills=3)
    proxies = [FrameProxy(i, w.addr, poison) for i, w in enumerate(workers)]
    try:
        args = [BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                "--workers", ",".join(p.addr for p in proxies), "--max-redispatch", "3", "--calibrate-ms", "50"]
        cluster.server = Daemon(args, tmp_path / "server.log")
        cluster.wait_ready(4)
        bad = cluster.texsyn("synth", "--ref", ref_of(data), "-o", tmp_path / "bad.png", *JOB, "--quiet",
                             check=False)
        assert bad.returncode != 0
        assert "lost workers 3 times in a row" in bad.stderr, bad.stderr
        assert len(poison.killed) == 3 and len(set(poison.killed)) == 3, poison.killed
        # The pool recovers (the dropped workers are dialled again) and the
        # next job gives the embedded bytes.
        cluster.wait_ready(4)
        cluster.texsyn("synth", "--ref", ref_of(data), "-o", tmp_path / "good.png", *JOB, "--quiet")
        want = tmp_path / "want.png"
        synth(texsyn, ref_of(data), want, (96, 64), *JOB[2:])
        assert (tmp_path / "good.png").read_bytes() == want.read_bytes()
        assert cluster.server.alive()
    finally:
        for p in proxies:
            p.close()


class DiesLoading(FrameProxy):
    """A worker that dies (its connections reset) whenever it is sent a
    slice ('N'), as one the kernel kills for memory while it builds the
    vectors; the coordinator dials it again, and it rejoins."""

    def dies_on(self, frame):
        if frame[3:4] == b"N":
            with self.poison.lock:
                self.poison.killed.append(self.index)
            return True
        return False


def test_a_worker_dying_at_every_slice_load_fails_the_job_not_forever(texsyn, data, cluster, tmp_path):
    healthy = cluster.worker(1)
    doomed = cluster.worker(1)
    poison = Poison(kills=0)
    proxy = DiesLoading(1, doomed.addr, poison)
    try:
        args = [BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                "--workers", f"{healthy.addr},{proxy.addr}", "--max-redispatch", "3", "--calibrate-ms", "20"]
        cluster.server = Daemon(args, tmp_path / "server.log")
        cluster.wait_ready(2)
        # Long enough at one level for the worker to rejoin, and die, 3 times.
        bad = cluster.texsyn("synth", "--ref", ref_of(data), "-o", tmp_path / "bad.png", "--size", "768x768",
                             "--levels", "2", "--quiet", check=False)
        log = cluster.server.read_log()
        assert bad.returncode != 0, f"the job went on feeding the dying worker:\n{log}"
        assert "lost workers 3 times (does a worker die loading it" in bad.stderr, bad.stderr
        # Each set's loads count (a level has several sets): the set that
        # failed the job lost it 3 times.
        assert len(poison.killed) >= 3, poison.killed
        assert cluster.server.alive()
    finally:
        proxy.close()
