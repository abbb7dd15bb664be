"""Golden outputs: the bytes of four jobs recorded before the search service
was rebuilt for every engine (commit c8cebdc; the PNG hashes recorded again
when results moved to zlib level 1, with the copy maps, hence the pixels,
unchanged), checked embedded and on 1, 3 and 16 workers (16 worker
processes on loopback, 1 scan thread each). The Table 3.3 job, a third of
the suite's golden time on its own, runs embedded and on 16 workers (many
thin slices); the three small ones run everywhere.

Any change to the search service, the protocol or the engines must keep these
bytes: the engine decides what is searched and in which order, and the backend
returns the exact global minimum with ties to the lowest index, so neither the
backend nor the pool may show in the output. The output images are PNG
written by OpenImageIO; the copy maps are raw little-endian (x, y) uint32
pairs, so a change of PNG encoder would show in the image hashes only.
"""
import hashlib

import pytest

from conftest import run

# name: (reference, synth options, sha256 of out.png, sha256 of the raw copy map)
GOLDEN = {
    # The seed's Table 3.3 job: brick 512^2 -> 1024^2, L=5, W_N=7, W_B=3, parity.
    "table33": ("textures/brick.png",
                ["--size", "1024x1024", "--levels", "5", "--wn", "7", "--wb", "3", "--parity"],
                "6182d71bf941713a56d806030bcc975fa3e6595ce1c72baf91f7e94e89a7a2dd",
                "798f4938134f488eb34f591d3ac0b07ad129df80e7635e24aa0094c209b65e80"),
    # A wide colour window: 11x11, three planes.
    "grass-rgb-wn11": ("textures/grass.png", ["--size", "256x192", "--rgb-search", "--wn", "11"],
                       "15fbef3eba7b864e4db980849251a9c38563b3a0b473fc85dd51bdf3d0abc9d2",
                       "9b086381d809fb8ccd17eed92c7eecb79d8383e92c7f1fbebb968f4ff8917df7"),
    # A colour photograph searched on its colour channels.
    "aero-rgb": ("aerial/aero1.jpg", ["--size", "256x192", "--rgb-search"],
                 "8fb7a425e9498185a5402d4f89868f89dc73a93a40b1b1b1eaaa342fa4ca0df6",
                 "a3e8298093806a104c150e0d0f87a7d862157aed15a2e526ece7465e0765ce19"),
    # The usage penalty: replicas of the usage counters on every worker.
    "usage4": ("textures/brick.png", ["--size", "256x256", "--usage-weight", "4"],
               "576a9a1dab12bf89c4362264d859bb80b47a4d92e03852b007b59e166363c073",
               "0f2b26b1d1bc26b19cc9adc9e675ed581df03ade972d95177bf57e0b9a6af8c5"),
}


def sha256(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def run_golden(texsyn, data, tmp_path, name, *where):
    ref, opts, want_image, want_copy = GOLDEN[name]
    out, copy = tmp_path / f"{name}.png", tmp_path / f"{name}.cm"
    run(texsyn, "synth", "--ref", data / ref, "-o", out, "--copy-map-raw", copy, "--quiet", *opts, *where)
    return sha256(out) == want_image, sha256(copy) == want_copy


def assert_golden(texsyn, data, tmp_path, where, label, names=tuple(GOLDEN)):
    wrong = []
    for name in names:
        image_ok, copy_ok = run_golden(texsyn, data, tmp_path, name, *where)
        if not (image_ok and copy_ok):
            wrong.append(f"{name} ({'image' if not image_ok else ''}{' ' if not (image_ok or copy_ok) else ''}"
                         f"{'copy map' if not copy_ok else ''} differs)")
    assert not wrong, f"{label}: outputs differ from the golden bytes: {', '.join(wrong)}"


def test_golden_embedded(texsyn, data, tmp_path):
    assert_golden(texsyn, data, tmp_path, ["--embedded"], "embedded")


@pytest.mark.parametrize("workers", [1, 3, 16])
def test_golden_on_workers(texsyn, data, cluster, tmp_path, workers):
    cluster.start(workers, 1)
    names = [n for n in GOLDEN if n != "table33" or workers == 16]
    assert_golden(texsyn, data, tmp_path, ["--server", cluster.server.addr], f"{workers} workers", names)
