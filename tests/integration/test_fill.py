"""texsyn synth --input IMG --mask MASK: hole filling (constrained synthesis).
Checked: the given pixels keep their bytes and every filled pixel comes from
the image's own given part (through the copy map); the same bytes for any
thread count, either order, on a cluster, and with a worker killed mid-job;
masks of several shapes, an external --ref, and every input problem in one
error."""
import json
import struct
import subprocess
import time

import pytest

from conftest import dropped_during_the_job, modbus_registers, run
from pnm import oiiotool, pixels_of


@pytest.fixture(scope="module")
def scene(data, tmp_path_factory):
    """A 192x160 brick crop, a rectangle and an L-shaped stroke to fill."""
    d = tmp_path_factory.mktemp("fill")
    oiiotool(data / "textures/brick.png", "--cut", "192x160+40+60", "--origin", "+0+0", "-o", d / "brick.png")
    oiiotool("--create", "192x160", "1", "--fill:color=1", "40x30+70+60", "-d", "uint8", "-o", d / "rect.png")
    oiiotool("--create", "192x160", "1", "--fill:color=1", "12x90+20+30", "--fill:color=1", "100x10+20+110",
             "-d", "uint8", "-o", d / "stroke.png")
    oiiotool(data / "textures/brick.png", "--cut", "128x128+300+300", "--origin", "+0+0", "-o", d / "more.png")
    return d


def fill(texsyn, scene, mask, out, *extra, check=True):
    return run(texsyn, "synth", "--input", scene / "brick.png", "--mask", scene / mask, "-o", out, "--quiet",
               "--levels", "3", *extra, check=check)


@pytest.mark.sanitize
@pytest.mark.parametrize("mask", ["rect.png", "stroke.png"])
def test_given_pixels_keep_their_bytes_and_holes_come_from_the_rest(texsyn, scene, tmp_path, mask):
    out, cm = tmp_path / "out.png", tmp_path / "copy.raw"
    fill(texsyn, scene, mask, out, "--copy-map-raw", cm)
    w, h, _, src = pixels_of(scene / "brick.png", tmp_path)
    _, _, _, got = pixels_of(out, tmp_path)
    _, _, _, m = pixels_of(scene / mask, tmp_path)
    xy = struct.unpack(f"<{2 * w * h}I", cm.read_bytes())
    holes = 0
    for i in range(w * h):
        sx, sy = xy[2 * i], xy[2 * i + 1]
        if m[i] < 128:
            assert got[i] == src[i] and (sx, sy) == (i % w, i // w), f"given pixel {i % w},{i // w} changed"
        else:
            holes += 1
            assert m[sy * w + sx] < 128, f"pixel {i % w},{i // w} copies from the hole at {sx},{sy}"
            assert got[i] == src[sy * w + sx]
    assert holes > 1000


@pytest.mark.sanitize
def test_the_same_bytes_for_any_thread_count_and_on_a_cluster(texsyn, scene, cluster, tmp_path):
    fill(texsyn, scene, "rect.png", tmp_path / "t1.png", "--threads", "1", "--order", "threshold")
    fill(texsyn, scene, "rect.png", tmp_path / "t2.png", "--threads", "2", "--order", "threshold")
    assert (tmp_path / "t1.png").read_bytes() == (tmp_path / "t2.png").read_bytes()
    fill(texsyn, scene, "stroke.png", tmp_path / "e.png", "--parity", "--usage-weight", "1")
    cluster.start(3, 1)
    cluster.texsyn("synth", "--input", scene / "brick.png", "--mask", scene / "stroke.png", "-o", tmp_path / "c.png",
                   "--quiet", "--levels", "3", "--parity", "--usage-weight", "1")
    assert (tmp_path / "c.png").read_bytes() == (tmp_path / "e.png").read_bytes()


def test_a_killed_worker_changes_nothing(texsyn, data, scene, cluster, tmp_path):
    """A 512x512 brick with a 200x160 hole, filled on 3 workers; one is
    killed once it holds its slice of the finest level (Modbus)."""
    d = tmp_path
    oiiotool("--create", "512x512", "1", "--fill:color=1", "200x160+150+170", "-d", "uint8", "-o", d / "hole.png")
    args = ["synth", "--input", data / "textures/brick.png", "--mask", d / "hole.png", "--levels", "4"]
    run(texsyn, *args, "-o", d / "embedded.png", "--quiet")
    for _ in range(3):
        cluster.worker(1, "--modbus", "0")
    cluster.start()
    job = subprocess.Popen([str(texsyn), *map(str, args), "-o", d / "c.png", "--server", cluster.server.addr,
                            "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    victim = cluster.workers[1]
    deadline = time.time() + 120
    while int(modbus_registers(victim.modbus)["vectors"]) < 30000:  # level 0: ~219000 in all, level 1 ~55000
        assert time.time() < deadline and job.poll() is None, "the victim never held a level-0 slice"
        time.sleep(0.01)
    victim.proc.kill()
    out, err = job.communicate(timeout=600)
    assert job.returncode == 0, err
    dropped_during_the_job(cluster.server.read_log(), victim.addr)
    assert (d / "c.png").read_bytes() == (d / "embedded.png").read_bytes()


def test_an_external_reference_is_used(texsyn, scene, tmp_path):
    report = tmp_path / "r.json"
    fill(texsyn, scene, "rect.png", tmp_path / "ext.png", "--ref", scene / "more.png", "--no-self",
         "--report", report)
    r = json.loads(report.read_text())
    assert r["engine"] == "fill" and r["params"]["self"] is False and r["params"]["refs"] == 1
    assert r["search"]["mode"] == "exact" and r["search"]["lossy"] == []
    assert sum(level["blocks"] for level in r["levels"]) > 0
    # The repetition score counts the filled pixels only: the hole's.
    hole = sum(1 for v in pixels_of(scene / "rect.png", tmp_path)[3] if v > 127)
    rep = r["repetition"]
    assert rep["side"] == 16 and rep["filled"] == hole and 0 <= rep["repeated"] <= rep["in_large"] <= hole, rep


def test_every_problem_in_one_error(texsyn, scene, data, tmp_path):
    oiiotool("--create", "100x100", "1", "-d", "uint8", "-o", tmp_path / "small.png")
    p = fill(texsyn, scene, "rect.png", tmp_path / "x.png", "--wn", "8", "--ref", data / "aerial/aero1.jpg",
             check=False)
    assert p.returncode == 2
    assert "--wn 8" in p.stderr and "--ref 1 has 3 channels" in p.stderr, p.stderr
    p = run(texsyn, "synth", "--input", scene / "brick.png", "--mask", tmp_path / "small.png", "-o",
            tmp_path / "x.png", check=False)
    assert p.returncode == 2 and "--mask is 100x100, the input 192x160" in p.stderr, p.stderr
    oiiotool("--create", "192x160", "1", "-d", "uint8", "-o", tmp_path / "none.png")
    p = run(texsyn, "synth", "--input", scene / "brick.png", "--mask", tmp_path / "none.png", "-o",
            tmp_path / "x.png", check=False)
    assert p.returncode == 2 and "marks nothing to fill" in p.stderr, p.stderr
    p = run(texsyn, "synth", "--input", scene / "brick.png", "--mask", tmp_path / "none.png", "--no-self", "-o",
            tmp_path / "x.png", check=False)
    assert p.returncode == 2 and "--no-self needs at least one --ref" in p.stderr, p.stderr
