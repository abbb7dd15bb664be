"""Sealed links (issue 29): with --secret-file every frame after the
handshake travels sealed (proto/PROTOCOL.md, "Sealed frames").

A relay between the coordinator and a worker passes the handshake through,
then alters, drops, replays or reorders one sealed frame of a connection,
either way, or alters an 'I' frame of the handshake (outside every MAC):
each time the side that receives it ends the connection and logs the
reason, the coordinator dials the worker again, and the jobs that run
meanwhile end with the embedded run's bytes. A capture of a whole job's
traffic, client link and worker link, holds none of the input image's
bytes - and the same capture without a secret does (the check can fail)."""
import os
import queue
import random
import re
import socket
import struct
import threading
import time

from conftest import BUILD, Daemon, LoopbackProxy, run, synth
from pnm import pixels_of

HEADER = struct.Struct("<2sBcII")  # magic, version, type, payload length, id
SIZE = ("96x64", "--levels", "3")
# What the receiving side logs for each action (the coordinator for frames
# the worker sent, the worker for frames the coordinator sent).
REASONS = {
    "alter": r"sealed link: (sealed frame \d+ failed authentication \(altered|a plain|sealed frame \d+ arrived)",
    "replay": r"sealed link: sealed frame \d+ arrived again where \d+ was due \(replayed or reordered\)",
    "reorder": r"sealed link: sealed frame \d+ arrived where \d+ was due \(1 dropped, or reordered\)",
    # A dropped frame shows when the next one comes; a dropped request
    # with nothing after it (a heartbeat between jobs) leaves its answer
    # missing, and the coordinator says so at the deadline.
    "drop": r"sealed link: sealed frame \d+ arrived where \d+ was due \(1 dropped, or reordered\)|"
            r"no answer|heartbeat",
    "ident": r"sealed link: sealed frame 0 failed authentication",
}


def secret(tmp_path):
    path = tmp_path / "secret"
    path.write_text(os.urandom(24).hex() + "\n")
    path.chmod(0o600)
    return path


def ref_of(data):
    return data / "textures" / "brick.png"


class Trial:
    """One alteration: `action` on the nth sealed frame (n from 0) that
    `way` carries ("c2w" coordinator to worker, "w2c" back), or for
    "ident", one byte of the name in that way's 'I' frame."""

    def __init__(self, action, way, n, rng):
        self.action, self.way, self.n, self.rng = action, way, n, rng
        self.fired = threading.Event()
        self.closed = threading.Event()

    def __repr__(self):
        return f"{self.action} {self.way} #{self.n}"


class SealRelay(LoopbackProxy):
    """Forwards whole frames both ways; each new connection takes the next
    trial armed (none: it only forwards). Every byte is also recorded in
    `capture` (way -> bytearray)."""

    def __init__(self, target):
        self.trials = queue.Queue()
        self.capture = {"c2w": bytearray(), "w2c": bytearray()}
        super().__init__(target)

    def forward(self, a, b):
        try:
            trial = self.trials.get_nowait()
        except queue.Empty:
            trial = None
        socks = (a, b)
        done = threading.Barrier(2, action=lambda: trial and trial.closed.set())
        threading.Thread(target=self.pump, args=(a, b, "c2w", trial, socks, done), daemon=True).start()
        threading.Thread(target=self.pump, args=(b, a, "w2c", trial, socks, done), daemon=True).start()

    def pump(self, src, dst, way, trial, socks, done):
        mine = trial if trial is not None and trial.way == way else None
        buf, sealed, held = bytearray(), 0, None
        try:
            while True:
                src.settimeout(0.5 if held is not None else None)
                try:
                    data = src.recv(65536)
                except socket.timeout:
                    dst.sendall(held)  # nothing came after it: not reordered; the next one is
                    held, mine.n = None, sealed
                    continue
                if not data:
                    break
                buf += data
                while len(buf) >= HEADER.size:
                    length = HEADER.unpack_from(buf)[3]
                    if len(buf) < HEADER.size + length:
                        break
                    frame = bytes(buf[:HEADER.size + length])
                    del buf[:HEADER.size + length]
                    self.capture[way] += frame
                    out = [frame]
                    kind = frame[3:4]
                    if mine is not None and not mine.fired.is_set():
                        if mine.action == "ident" and kind == b"I":
                            name_at = HEADER.size + 10  # role, caps, threads, simd, u16 length
                            f = bytearray(frame)
                            f[name_at + mine.rng.randrange(6)] ^= 0x20  # "texsyn" -> "teXsyn"
                            out = [bytes(f)]
                            mine.fired.set()
                        elif kind == b"Z" and held is not None:
                            out = [frame, held]  # the next one first
                            held = None
                            mine.fired.set()
                        elif kind == b"Z" and sealed == mine.n:
                            out = self.act(mine, frame)
                            if mine.action == "reorder":
                                held, out = frame, []
                    if kind == b"Z":
                        sealed += 1
                    for f in out:
                        dst.sendall(f)
        except OSError:
            pass
        for s in socks:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        try:
            done.wait(timeout=30)
        except threading.BrokenBarrierError:
            pass

    @staticmethod
    def act(trial, frame):
        if trial.action == "reorder":
            return []
        trial.fired.set()
        if trial.action == "drop":
            return []
        if trial.action == "replay":
            return [frame, frame]
        # alter: one bit of the type, the id (the counter), the ciphertext
        # or the tag; never magic, version or length, which the frame
        # reader refuses before anything is opened.
        f = bytearray(frame)
        pos = trial.rng.choice([3, *range(8, 12), *range(HEADER.size, len(f))])
        f[pos] ^= 1 << trial.rng.randrange(8)
        return [bytes(f)]


class JobLoop:
    """Jobs one after another on the coordinator, each checked against the
    embedded bytes, until stopped."""

    def __init__(self, addr, data, tmp_path, want, env):
        self.addr, self.data, self.tmp, self.want, self.env = addr, data, tmp_path, want, env
        self.done, self.problems, self.stopping = 0, [], threading.Event()
        self.thread = threading.Thread(target=self.loop, daemon=True)
        self.thread.start()

    def loop(self):
        while not self.stopping.is_set():
            out = self.tmp / f"job{self.done}.png"
            p = run(BUILD / "texsyn", "synth", "--server", self.addr, "--ref", ref_of(self.data), "-o", out,
                    "--size", *SIZE, "--quiet", env=self.env, check=False)
            if p.returncode != 0:
                self.problems.append(f"job {self.done} failed: {p.stderr}")
            elif out.read_bytes() != self.want:
                self.problems.append(f"job {self.done}: other bytes than embedded")
            self.done += 1

    def stop(self):
        self.stopping.set()
        self.thread.join(timeout=120)


def reasons(log, pattern):
    return len(re.findall(pattern, log))


def test_every_altered_dropped_replayed_or_reordered_frame_is_detected(texsyn, data, cluster, tmp_path):
    want_path = tmp_path / "embedded.png"
    synth(texsyn, ref_of(data), want_path, (96, 64), "--levels", "3")
    want = want_path.read_bytes()
    key = secret(tmp_path)
    env = {"TEXSYN_SECRET_FILE": str(key)}
    worker = cluster.worker(1, "--secret-file", key)
    relay = SealRelay(worker.addr)
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                             "--secret-file", key, "--workers", relay.addr, "--calibrate-ms", 20,
                             "--heartbeat", 0.3, "--threads", 1], tmp_path / "server.log")
    rng = random.Random(29)
    trials = [Trial(action, way, rng.randrange(1, 6), random.Random(rng.random()))
              for seed in range(2) for action in ("alter", "drop", "replay", "reorder") for way in ("c2w", "w2c")]
    trials += [Trial("ident", way, 0, random.Random(way)) for way in ("c2w", "w2c")]
    jobs = JobLoop(cluster.server.addr, data, tmp_path, want, env)
    try:
        for t in trials:
            logs = cluster.server.read_log() + worker.read_log()
            before = reasons(logs, REASONS[t.action])
            relay.trials.put(t)
            assert t.fired.wait(60), f"{t}: never fired\n{cluster.server.read_log()}"
            assert t.closed.wait(60), f"{t}: the connection did not end\n{cluster.server.read_log()}"
            deadline = time.time() + 10
            while reasons(cluster.server.read_log() + worker.read_log(), REASONS[t.action]) == before:
                assert time.time() < deadline, \
                    f"{t}: no reason logged\n{cluster.server.read_log()}\n{worker.read_log()}"
                time.sleep(0.05)
        while jobs.done < 3:  # and after all that, jobs still run on the worker
            time.sleep(0.1)
    finally:
        jobs.stop()
        relay.close()
    assert jobs.problems == [], jobs.problems
    assert jobs.done >= 3
    # Both directions were judged: the worker refused the coordinator's
    # frames, the coordinator the worker's.
    assert "sealed link" in worker.read_log() and "sealed link" in cluster.server.read_log()


def planes_of(pixels, channels):
    return [pixels[c::channels] for c in range(channels)]


def holds_image(capture, file_bytes, planes, width):
    """Whether any 24-byte run of the input file, or of a row of one of its
    planes, shows in the bytes captured."""
    runs = [file_bytes[i:i + 24] for i in range(64, len(file_bytes) - 24, 997)]
    for p in planes:
        runs += [p[y * width + 8:y * width + 32] for y in range(0, len(p) // width, 7)]
    return any(r in capture for r in runs)


def frame_types(capture):
    """The type letters of the frames in a capture of one way, in order."""
    types, at = [], 0
    while at + HEADER.size <= len(capture):
        types.append(capture[at + 3:at + 4].decode("latin-1"))
        at += HEADER.size + HEADER.unpack_from(capture, at)[3]
    return "".join(types)


def captured_job(data, cluster, tmp_path, key):
    """The traffic of one job (client link, worker link), each way apart,
    through relays that only forward."""
    sec = ("--secret-file", key) if key else ()
    worker = cluster.worker(1, *sec)
    to_worker = SealRelay(worker.addr)
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                             *sec, "--workers", to_worker.addr, "--threads", 1], tmp_path / "server.log")
    cluster.server.wait_log(r"worker 1 \(.*\) ready", timeout=30)
    to_server = SealRelay(cluster.server.addr)
    out = tmp_path / "out.png"
    run(BUILD / "texsyn", "synth", "--server", to_server.addr, "--ref", ref_of(data), "-o", out, "--size", *SIZE,
        "--quiet", env={"TEXSYN_SECRET_FILE": str(key) if key else ""})
    assert re.search(r"worker 1 .* dropped", cluster.server.read_log()) is None, cluster.server.read_log()
    to_worker.close()
    to_server.close()
    return to_server.capture, to_worker.capture


def test_a_whole_jobs_traffic_holds_no_image_bytes(data, cluster, tmp_path):
    w, _, ch, pixels = pixels_of(ref_of(data), tmp_path)
    file_bytes = ref_of(data).read_bytes()
    planes = planes_of(pixels, ch)
    key = secret(tmp_path)
    client_link, worker_link = captured_job(data, cluster, tmp_path, key)
    for link in (client_link, worker_link):
        # The handshake in the clear ('I' both ways, then 'A'), every frame
        # after it sealed.
        assert re.fullmatch("IA+Z+", frame_types(link["c2w"])), frame_types(link["c2w"])[:40]
        assert re.fullmatch("IA+Z+", frame_types(link["w2c"])), frame_types(link["w2c"])[:40]
        both = bytes(link["c2w"] + link["w2c"])
        assert not holds_image(both, file_bytes, planes, w)
    assert len(client_link["c2w"]) > len(file_bytes)  # the image went, sealed
    assert len(worker_link["c2w"]) > 10000
    cluster.stop()
    # The control: without a secret the same capture shows the image, on
    # both links.
    plain = tmp_path / "plain"
    plain.mkdir()
    cluster.workers, cluster.server, cluster.tmp = [], None, plain
    client_link, worker_link = captured_job(data, cluster, plain, None)
    assert "Z" not in frame_types(worker_link["c2w"])
    assert holds_image(bytes(client_link["c2w"]), file_bytes, [], w)
    assert holds_image(bytes(worker_link["c2w"]), b"", planes, w)
