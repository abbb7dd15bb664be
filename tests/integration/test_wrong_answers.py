"""Answers that could make a wrong result: a worker's short, duplicate, extra
or misaddressed answer frame, and a poll() failure in the middle of an
exchange. Each must drop the worker (with a log line naming what was wrong)
and ask the batch again - never merge what arrived - so the output is the
embedded run's bytes.

A tampering proxy between the coordinator and one of two workers forwards
everything and rewrites one query answer ('V' reply) once, mid-job. The
poll() failure comes from a preloaded shim (tests/preload/fail_poll.c).
"""
import re
import struct
import threading

import pytest

from conftest import BUILD, Daemon, LoopbackProxy, run, shutdown_all

HEADER = 12
TAMPER_AT = 30  # the 30th query answer of the job: well inside it


class TamperingProxy(LoopbackProxy):
    """Rewrites the TAMPER_AT-th 'V' frame from the worker, once."""

    def __init__(self, target, mode):
        self.mode = mode
        self.answers = 0
        self.done = threading.Event()
        super().__init__(target)

    def forward(self, client, worker):
        threading.Thread(target=self.plain, args=(client, worker), daemon=True).start()
        threading.Thread(target=self.frames, args=(worker, client), daemon=True).start()

    def plain(self, src, dst):
        while True:
            try:
                data = src.recv(65536)
                if not data:
                    break
                dst.sendall(data)
            except OSError:
                break
        shutdown_all(src, dst)

    def frames(self, src, dst):
        buf = b""
        while True:
            try:
                data = src.recv(65536)
            except OSError:
                data = b""
            if not data:
                break
            buf += data
            while len(buf) >= HEADER:
                length = struct.unpack_from("<I", buf, 4)[0]
                if len(buf) < HEADER + length:
                    break
                frame, buf = buf[:HEADER + length], buf[HEADER + length:]
                try:
                    dst.sendall(self.rewrite(frame))
                except OSError:
                    break
        shutdown_all(src, dst)

    def rewrite(self, frame):
        if chr(frame[3]) != "V" or self.done.is_set():
            return frame
        self.answers += 1
        if self.answers != TAMPER_AT:
            return frame
        self.done.set()
        head, body = frame[:HEADER], frame[HEADER:]
        fid = struct.unpack_from("<I", head, 8)[0]
        nq = struct.unpack_from("<I", body, 8)[0]
        if self.mode == "short":  # the last result missing
            body = body[:8] + struct.pack("<I", nq - 1) + body[12:-12]
        elif self.mode == "extra":  # one result too many
            body = body[:8] + struct.pack("<I", nq + 1) + body[12:] + struct.pack("<IQ", 0, 0)
        elif self.mode == "duplicate":  # the same answer twice
            return frame + frame
        elif self.mode == "misaddressed":  # for a frame never sent
            fid ^= 0x800000
        return b"TS" + head[2:4] + struct.pack("<II", len(body), fid) + body


def job(data, out):
    return ["synth", "--ref", data / "textures" / "brick.png", "-o", out, "--size", "192x144", "--levels", "3",
            "--quiet", "--copy-map-raw", str(out) + ".raw"]


def embedded(texsyn, data, tmp_path):
    out = tmp_path / "embedded.png"
    run(texsyn, *job(data, out), "--embedded")
    return out.read_bytes(), (tmp_path / "embedded.png.raw").read_bytes()


# Each mode's named reason (server/pool/cluster.c req_match, search_batch.c
# answer_reply): a duplicate answers no request outstanding, or not the
# oldest one; a misaddressed answer names a frame id not sent.
WHY = {"short": "which asked", "extra": "which asked",
       "duplicate": "protocol: unsolicited 'V'|does not answer the oldest request",
       "misaddressed": "does not answer the oldest request outstanding"}


@pytest.mark.parametrize("mode", [pytest.param("short", marks=pytest.mark.sanitize), "extra",
                                  "duplicate", "misaddressed"])
def test_bad_answer_drops_the_worker_and_the_batch_is_asked_again(texsyn, data, cluster, tmp_path, mode):
    want = embedded(texsyn, data, tmp_path)
    honest = cluster.worker(1)
    tampered = cluster.worker(1)
    proxy = TamperingProxy(tampered.addr, mode)
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                             "--workers", f"{honest.addr},{proxy.addr}"], tmp_path / "server.log")
    cluster.wait_ready(2)
    out = tmp_path / "cluster.png"
    cluster.texsyn(*job(data, out))
    log = cluster.server.read_log()
    assert proxy.done.is_set(), f"the job ended before answer {TAMPER_AT}: make it longer"
    assert (out.read_bytes(), (tmp_path / "cluster.png.raw").read_bytes()) == want, \
        f"a {mode} answer changed the output"
    assert "dropped" in log and re.search(WHY[mode], log), f"no drop naming the {mode} answer:\n{log}"


def test_poll_failure_in_an_exchange_asks_again(texsyn, data, cluster, tmp_path):
    want = embedded(texsyn, data, tmp_path)
    shim = BUILD / "tests" / "libfail_poll.so"
    assert shim.exists(), f"{shim} is missing: run make"
    workers = [cluster.worker(1), cluster.worker(1)]
    cluster.server = Daemon(["env", f"LD_PRELOAD={shim}", "TEXSYN_FAIL_POLL_AT=40", BUILD / "texsyn-server",
                             "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool", "--workers",
                             ",".join(w.addr for w in workers)], tmp_path / "server.log")
    cluster.wait_ready(2)
    out = tmp_path / "cluster.png"
    cluster.texsyn(*job(data, out))
    log = cluster.server.read_log()
    assert (out.read_bytes(), (tmp_path / "cluster.png.raw").read_bytes()) == want, \
        "a poll failure changed the output"
    assert "poll: Cannot allocate memory (the batch is asked again)" in log, f"the poll failure was not seen:\n{log}"
