"""Bad reference images sent to a running coordinator: each gets one clear
error naming the file and what is wrong, sent to its sender, while the
other jobs carry on and come out right. Two senders: the real client
(`texsyn synth --server`, which checks the reference itself before
uploading it) and a raw client that skips those checks and submits the
bytes as they are, as a buggy or hostile client would."""
import socket
import struct
import time
import zlib

import pytest

from conftest import FRAME_START, SANITIZED, synth

# Under ASan+UBSan (several times slower) a smaller job takes the same paths.
SIZE = (192, 144) if SANITIZED else (256, 192)
SERVER_LIMIT = "over the limit of 268435456 pixels; raise it with texsyn-server --max-pixels"


def png_chunk(kind, body):
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def huge_png():
    """A valid PNG header claiming 100000 x 100000 grey pixels, nothing else."""
    ihdr = struct.pack(">IIBBBBB", 100000, 100000, 8, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", ihdr) + png_chunk(b"IDAT", b"")
            + png_chunk(b"IEND", b""))


def huge_tiff():
    """A classic little-endian TIFF header claiming 100000 x 100000 grey
    pixels in one 16-byte strip."""
    tags = [(256, 4, 100000), (257, 4, 100000), (258, 3, 8), (259, 3, 1), (262, 3, 1),
            (273, 4, None), (277, 3, 1), (278, 4, 100000), (279, 4, 16)]
    pixels = 8 + 2 + 12 * len(tags) + 4
    out = b"II*\x00" + struct.pack("<IH", 8, len(tags))
    for tag, kind, value in tags:
        value = pixels if value is None else value
        field = struct.pack("<HH", value, 0) if kind == 3 else struct.pack("<I", value)
        out += struct.pack("<HHI", tag, kind, 1) + field
    return out + struct.pack("<I", 0) + bytes(16)


def bad_references(data):
    """name -> (bytes, what the error must say after the file name)."""
    brick = (data / "textures" / "brick.png").read_bytes()
    return {
        "huge.png": (huge_png(), "100000x100000 image (10000000000 pixels) is over the limit"),
        "huge.tif": (huge_tiff(), "100000x100000 image (10000000000 pixels) is over the limit"),
        "empty.png": (b"", "empty file (0 bytes), not an image"),
        "notes.png": (b"shopping list: eggs, milk\n", "not a PNG, JPEG, TIFF or OpenEXR image"),
        "cut.png": (brick[:len(brick) // 3], "unreadable or truncated image"),
    }


# ---- a raw client: the protocol by hand (proto/PROTOCOL.md) ------------------

def frame(kind, payload, ident):
    return FRAME_START + kind + struct.pack("<II", len(payload), ident) + payload


def string(b):
    return struct.pack("<H", len(b)) + b


class RawClient:
    def __init__(self, addr):
        host, port = addr.rsplit(":", 1)
        self.sock = socket.create_connection((host, int(port)), timeout=30)
        self.sock.sendall(frame(b"I", struct.pack("<BIHB", 3, 7, 0, 0) + string(b"raw-client"), 0))
        assert self.recv()[0] == b"I"

    def recv(self):
        head = self.read(12)
        assert head[:3] == FRAME_START, head
        n, ident = struct.unpack("<II", head[4:12])
        return head[3:4], ident, self.read(n)

    def read(self, n):
        buf = b""
        while len(buf) < n:
            chunk = self.sock.recv(n - len(buf))
            assert chunk, "coordinator closed the connection"
            buf += chunk
        return buf

    def submit(self, name, ref, ident):
        """(job id, None) or (None, (code, message))."""
        spec = f"size={SIZE[0]}x{SIZE[1]}\noutput=png\n".encode()
        body = struct.pack("<I", len(spec)) + spec + string(name.encode()) + struct.pack("<I", len(ref)) + ref
        self.sock.sendall(frame(b"S", body, ident))
        kind, got_id, payload = self.recv()
        assert got_id == ident
        if kind == b"S":
            return struct.unpack("<Q", payload)[0], None
        assert kind == b"E", kind
        code, = struct.unpack("<i", payload[:4])
        n, = struct.unpack("<H", payload[4:6])
        return None, (code, payload[6:6 + n].decode())

    def close(self):
        self.sock.close()


def job_state(cluster, job):
    return cluster.texsyn("status", job).stdout


def wait_running(cluster, job, timeout=30):
    deadline = time.time() + timeout
    while time.time() < deadline:
        out = job_state(cluster, job)
        if "running" in out or " done" in out:
            return out
        time.sleep(0.05)
    raise AssertionError(f"job {job} never started:\n{cluster.server.read_log()}")


def start_good_job(cluster, data, tmp_path):
    w, h = SIZE
    p = cluster.texsyn("synth", "--ref", data / "textures" / "brick.png", "-o", tmp_path / "good.png",
                       "--size", f"{w}x{h}", "--detach")
    job = p.stdout.strip()
    assert job.isdigit(), p.stdout
    return job


def finish_good_job(cluster, job, tmp_path):
    cluster.texsyn("watch", job, "--quiet")
    cluster.texsyn("fetch", job, "-o", tmp_path / "good.png")
    return (tmp_path / "good.png").read_bytes()


def test_bad_references_from_the_client_while_a_job_runs(texsyn, data, cluster, tmp_path):
    w, h = SIZE
    want = tmp_path / "want.png"
    synth(texsyn, data / "textures" / "brick.png", want, SIZE)
    cluster.start(1, 1)
    job = start_good_job(cluster, data, tmp_path)
    wait_running(cluster, job)
    for name, (ref, why) in bad_references(data).items():
        path = tmp_path / name
        path.write_bytes(ref)
        p = cluster.texsyn("synth", "--ref", path, "-o", tmp_path / f"out-{name}.png", "--size", f"{w}x{h}",
                           "--quiet", check=False)
        assert p.returncode != 0, name
        # One line says it all (libpng may add its own "libpng error:" line
        # on stderr; OpenImageIO gives no way to silence it).
        lines = [l for l in p.stderr.splitlines() if not l.startswith("libpng error:")]
        assert lines == [f"texsyn synth: {path}: {why}" + lines[0].split(why, 1)[1]], p.stderr
        if name.startswith("huge"):
            assert "over the limit of 268435456 pixels; raise it with --max-pixels" in p.stderr
        assert not (tmp_path / f"out-{name}.png").exists()
    assert "failed" not in job_state(cluster, job)
    assert finish_good_job(cluster, job, tmp_path) == want.read_bytes()
    assert cluster.server.alive()


@pytest.mark.sanitize
def test_bad_references_submitted_raw_get_a_clear_error(data, cluster, tmp_path):
    cluster.start(1, 1)
    job = start_good_job(cluster, data, tmp_path)
    wait_running(cluster, job)
    for i, (name, (ref, why)) in enumerate(bad_references(data).items()):
        raw = RawClient(cluster.server.addr)  # a malformed message closes it
        job_id, error = raw.submit(name, ref, 10 + i)
        raw.close()
        if name == "empty.png":  # refused by the message reader already
            why = "empty reference image"
            assert error is not None and why in error[1], error
            continue
        assert job_id is None, f"{name} was queued as job {job_id}"
        code, message = error
        assert code < 0
        assert message.startswith(f"{name}: {why}"), message
        if name.startswith("huge"):
            assert message.endswith(SERVER_LIMIT), message
    good = finish_good_job(cluster, job, tmp_path)
    assert good[:8] == b"\x89PNG\r\n\x1a\n" and len(good) > 1000
    log = cluster.server.read_log()
    assert "refused a job" in log and "100000x100000" in log
    assert cluster.server.alive()
    assert cluster.pool()
