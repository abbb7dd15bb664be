"""Messages in pieces: a worker whose frame limit is far below its slice
gets the slice (and the query batches) in pieces and answers with the
embedded run's bytes; a worker that cannot take its slice at all is left
out of that set's slicing; malformed piece sequences from a raw peer get a
clear error, and both daemons go on serving."""
import re
import socket
import struct

import pytest

from conftest import FRAME_START, SANITIZED, synth

# Under ASan+UBSan (several times slower) a smaller job takes the same paths.
SIZE = (192, 144) if SANITIZED else (256, 192)


def ref_of(data):
    return data / "textures" / "brick.png"


def embedded(texsyn, data, tmp_path, *extra):
    out = tmp_path / "embedded.png"
    synth(texsyn, ref_of(data), out, SIZE, *extra)
    return out.read_bytes()


def remote(cluster, data, tmp_path, *extra):
    out = tmp_path / "remote.png"
    w, h = SIZE
    cluster.texsyn("synth", "--ref", ref_of(data), "-o", out, "--size", f"{w}x{h}", "--quiet", *extra)
    return out.read_bytes()


def pieces_logged(worker):
    """(bytes, pieces) of every slice message the worker took in pieces."""
    return [(int(b), int(n)) for b, n in re.findall(r"from a message of (\d+) bytes in (\d+) pieces",
                                                     worker.read_log())]


# Not under ASan+UBSan: reassembly runs there in the malformed-pieces test
# below, in test_pieces (unit) and in fuzz_frame.
@pytest.mark.parametrize("extra", [[], ["--rgb-search", "--usage-weight", "2", "--levels", "4"]])
def test_slices_in_many_pieces_match_embedded(texsyn, data, cluster, tmp_path, extra):
    """--max-frame 1024 (the smallest a worker takes): every slice and query
    frame goes in pieces of 1007 bytes, and the bytes are the embedded run's."""
    want = embedded(texsyn, data, tmp_path, *extra)
    small = cluster.worker(1, "--max-frame", "1024")
    cluster.worker(1)
    cluster.start()
    assert remote(cluster, data, tmp_path, *extra) == want
    logged = pieces_logged(small)
    assert logged, "no slice came in pieces:\n" + small.read_log()
    for size, n in logged:
        assert n == -(-size // (1024 - 17)), f"a message of {size} bytes in {n} pieces"
    # A slice carries coarse rows (its fine rows come from the query image),
    # 20-30 KB at level 0 here: dozens of pieces.
    assert max(n for _, n in logged) > 20
    assert all(w["batches"] > 0 for w in cluster.pool()), "a worker never answered"


def test_a_slice_over_a_workers_message_limit_goes_to_the_others(texsyn, data, cluster, tmp_path):
    """A worker whose --max-message is below its slice stays in the pool but
    gets no slice (it would have to refuse it, be dropped and rejoin, over
    and over); the other worker scans everything, with the same bytes."""
    want = embedded(texsyn, data, tmp_path)
    tiny = cluster.worker(1, "--max-frame", "1024", "--max-message", "1024")
    cluster.worker(1)
    cluster.start()
    assert remote(cluster, data, tmp_path) == want
    log = cluster.server.read_log()
    assert re.search(r"worker \d+ \(\S+\) gets no slice of set \d+: it would need a message of \d+ bytes, over its "
                     r"limit of 1024 \(texsyn-worker --max-message\)", log), log
    assert "dropped" not in log
    pool = {w["addr"]: w for w in cluster.pool()}
    assert pool[tiny.addr]["state"] == "active" and pool[tiny.addr]["share"] == 0
    assert not pieces_logged(tiny)


# ---- malformed sequences from a raw peer -------------------------------------

def frame(t, payload=b"", ident=1):
    return FRAME_START + t.encode() + struct.pack("<II", len(payload), ident) + payload


def piece(t, total, offset, data, ident=7):
    return frame("M", t.encode() + struct.pack("<QQ", total, offset) + data, ident)


def ident_frame(role):
    name = b"fake-peer"
    return frame("I", struct.pack("<BIHB", role, 7, 0, 0) + struct.pack("<H", len(name)) + name)


def errors_after(addr, stream):
    """Sends a stream, reads until the peer closes; returns the texts of
    the 'E' frames it answered with."""
    host, port = addr.rsplit(":", 1)
    got = b""
    with socket.create_connection((host, int(port)), timeout=10) as s:
        try:
            s.sendall(stream)
            s.shutdown(socket.SHUT_WR)
            while chunk := s.recv(65536):
                got += chunk
        except (ConnectionResetError, BrokenPipeError):
            pass
    texts = []
    while len(got) >= 12:
        t, (n, _) = chr(got[3]), struct.unpack("<II", got[4:12])
        body, got = got[12:12 + n], got[12 + n:]
        if t == "E" and len(body) >= 6:
            texts.append(body[6:6 + struct.unpack("<H", body[4:6])[0]].decode())
    return texts


BODY = bytes(range(256)) * 4  # a 1024-byte message

BAD_SEQUENCES = {
    "out of order": (piece("N", 1024, 0, BODY[:100]) + piece("N", 1024, 200, BODY[200:300]),
                     "where 100 was next (pieces come in order)"),
    "interleaved frame": (piece("N", 1024, 0, BODY[:100]) + frame("H") + piece("N", 1024, 100, BODY[100:200]),
                          "a 'H' frame after 100 of the 1024 bytes of 'N' id 7"),
    "other message id": (piece("N", 1024, 0, BODY[:100]) + piece("N", 1024, 100, BODY[100:200], ident=8),
                         "a piece of 'N' id 8 (1024 bytes) inside 'N' id 7 (1024 bytes)"),
    "first not at 0": (piece("N", 1024, 100, BODY[:100]), "the first piece of 'N' id 7 is at offset 100, not 0"),
    "past the end": (piece("N", 150, 0, BODY[:100]) + piece("N", 150, 100, BODY[100:200]),
                     "runs past the end of 'N' id 7 (150 bytes)"),
    "over the limit": (piece("N", 1 << 40, 0, BODY[:100]),
                       "a 'N' message in pieces of 1099511627776 bytes exceeds the limit"),
    "piece of a piece": (piece("M", 1024, 0, BODY[:100]), "a piece of a piece"),
    "short header": (frame("M", b"N\x00\x04"), "shorter than its 17-byte header"),
    # Reassembled, then refused by the 'N' reader like any other frame.
    "whole but malformed": (piece("N", 1024, 0, BODY[:512]) + piece("N", 1024, 512, BODY[512:]),
                            "malformed 'N' message"),
}


@pytest.mark.sanitize
def test_malformed_pieces_get_a_clear_error_and_the_daemons_keep_serving(texsyn, data, cluster, tmp_path):
    want = embedded(texsyn, data, tmp_path)
    w = cluster.worker(1)
    for name, (stream, says) in BAD_SEQUENCES.items():
        texts = errors_after(w.addr, ident_frame(1) + stream)
        assert any(says in t for t in texts), f"{name}: the worker answered {texts!r}"
        assert w.alive(), f"worker died on {name}"
    log = w.read_log()
    for name, (_, says) in BAD_SEQUENCES.items():
        assert re.search(r"protocol error from \S+: .*" + re.escape(says), log), f"{name} not logged:\n{log}"
    cluster.start()
    # A client connection takes no pieces: the coordinator refuses them.
    texts = errors_after(cluster.server.addr, ident_frame(3) + BAD_SEQUENCES["out of order"][0])
    assert any("does not take" in t for t in texts), texts
    assert "protocol error from client" in cluster.server.read_log()
    # Before the connection start ends, pieces are refused too.
    texts = errors_after(w.addr, piece("I", 1024, 0, BODY[:100]))
    assert any("does not take" in t for t in texts), texts
    assert cluster.server.alive() and w.alive()
    assert remote(cluster, data, tmp_path) == want
