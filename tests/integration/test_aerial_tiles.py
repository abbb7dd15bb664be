"""texsyn aerial in tiles (server/engines/tile_grid.h, aerial_tiles.c):
scenes cut into tiles on a fixed grid, synthesised in four phases, each
joined to its finished neighbours through a halo; the class map read by
regions and the output streamed band by band. Checked on small scenes with
small tiles: every pixel still comes from its own class's reference or is a
line; the decoded bytes depend neither on where the job runs (embedded, 1,
2 or 3 workers, a worker killed mid-scene) nor on how many tiles run side by
side; a tiled TIFF holds the same pixels as a PNG; a coordinator
killed mid-scene resumes at its unfinished tiles with the same bytes; grid
parameters that do not fit are refused before any work."""
import json
import re
import signal
import struct
import time

import pytest

from conftest import BUILD, REPO, SANITIZED, dropped_during_the_job, run
from pnm import oiiotool, pixels_of, read_pnm
from test_aerial import GEOREF, gdal_georef, read_tiff_tags, write_geotiff

TILE = ["--tile", "64"]


def scene(d, size, seed=7):
    run(BUILD / "bench/mkscene", "--size", size, "--seed", seed, "-o", d / "scene")
    run("bash", REPO / "bench/aerial_refs.sh", d)
    return d / "scene-classes.png", d / "catalogue.json"


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    return scene(tmp_path_factory.mktemp("tiles"), 256)


def aerial(texsyn, classes, cat, out, *extra, check=True):
    return run(texsyn, "aerial", "--classes", classes, "--catalogue", cat, "-o", out, "--quiet", *extra, check=check)


def test_every_pixel_of_a_tiled_scene_is_a_line_or_its_class(texsyn, small, tmp_path):
    classes, cat = small
    out, report = tmp_path / "out.png", tmp_path / "r.json"
    aerial(texsyn, classes, cat, out, *TILE, "--report", report)
    r = json.loads(report.read_text())
    assert r["tiles"]["grid"] == [4, 4] and r["tiles"]["halo"] == 20 and r["tiles"]["tile"] == 64, r["tiles"]
    w, h, _, px = pixels_of(out, tmp_path)
    _, _, _, ids = pixels_of(classes, tmp_path)
    _, _, _, roads = pixels_of(classes.parent / "scene-roads.png", tmp_path)
    c = json.loads(cat.read_text())
    colours = {int(k): bytes(v) for k, v in c["lines"]["colours"].items()}
    refs = {}
    for k in c["classes"]:
        _, _, _, rpx = pixels_of(cat.parent / k["reference"], tmp_path)
        refs[k["id"]] = {rpx[i:i + 3] for i in range(0, len(rpx), 3)}
    for i in range(w * h):
        rgb = px[3 * i:3 * i + 3]
        if roads[i] in colours:
            assert rgb == colours[roads[i]], f"line pixel {i % w},{i // w}"
        else:
            assert rgb in refs[ids[i]], f"pixel {i % w},{i // w} of class {ids[i]} is no colour of its reference"
    assert sum(k["blocks"] for k in r["classes"]) == r["levels"][-1]["blocks"]


def test_a_scene_within_one_tile_is_one_tile(texsyn, small, tmp_path):
    classes, cat = small
    aerial(texsyn, classes, cat, tmp_path / "a.png", "--report", tmp_path / "r.json")
    r = json.loads((tmp_path / "r.json").read_text())
    assert r["tiles"]["grid"] == [1, 1], r["tiles"]
    # The tile's seed is the job's mixed with tile 0: without lines (which
    # give every area a context) areas start from drawn blocks, and another
    # job seed gives other bytes; the same seed, the same bytes.
    c = json.loads(cat.read_text())
    del c["lines"]
    for k in c["classes"]:
        k["reference"] = str(cat.parent / k["reference"])
    bare = tmp_path / "bare.json"
    bare.write_text(json.dumps(c))
    got = []
    for name, seed in (("s1", "1"), ("s2", "2"), ("s1b", "1")):
        aerial(texsyn, classes, bare, tmp_path / f"{name}.png", "--seed", seed)
        got.append(pixels_of(tmp_path / f"{name}.png", tmp_path)[3])
    assert got[0] != got[1] and got[0] == got[2]


def test_an_odd_grid_with_a_merged_last_row(texsyn, tmp_path):
    """320x200 in tiles of 64: 5 columns, and 3 rows, the last 72 high
    (the 8 rows left are merged into it); the same pixels whether 1 or 2
    tiles run at once, and the lines where the line raster has them."""
    classes, cat = scene(tmp_path, "320x200")
    aerial(texsyn, classes, cat, tmp_path / "a.png", *TILE, "--tile-jobs", "1", "--report", tmp_path / "r.json")
    assert json.loads((tmp_path / "r.json").read_text())["tiles"]["grid"] == [5, 3]
    aerial(texsyn, classes, cat, tmp_path / "b.png", *TILE, "--tile-jobs", "2")
    w, h, _, a = pixels_of(tmp_path / "a.png", tmp_path)
    assert (w, h) == (320, 200) and a == pixels_of(tmp_path / "b.png", tmp_path)[3]
    _, _, _, roads = pixels_of(classes.parent / "scene-roads.png", tmp_path)
    colours = {int(k): bytes(v) for k, v in json.loads(cat.read_text())["lines"]["colours"].items()}
    assert all(a[3 * i:3 * i + 3] == colours[v] for i, v in enumerate(roads) if v in colours)


def test_a_tiled_tiff_holds_the_pixels_of_the_png(texsyn, small, tmp_path):
    classes, cat = small
    aerial(texsyn, classes, cat, tmp_path / "o.png", *TILE)
    aerial(texsyn, classes, cat, tmp_path / "o.tif", *TILE)
    aerial(texsyn, classes, cat, tmp_path / "o.exr", *TILE)
    data = (tmp_path / "o.tif").read_bytes()
    assert data[:4] == b"II*\0"
    (ifd,) = struct.unpack_from("<I", data, 4)
    (n,) = struct.unpack_from("<H", data, ifd)
    tags = {struct.unpack_from("<HHII", data, ifd + 2 + 12 * i)[0]: struct.unpack_from("<HHII", data, ifd + 2 + 12 * i)
            for i in range(n)}
    assert 322 in tags and 323 in tags, "not a tiled TIFF"  # TileWidth, TileLength
    assert tags[259][3] & 0xFFFF in (8, 32946), "not zip-compressed"  # Compression: Adobe deflate
    png = pixels_of(tmp_path / "o.png", tmp_path)[3]
    assert pixels_of(tmp_path / "o.tif", tmp_path)[3] == png
    oiiotool(tmp_path / "o.exr", "-d", "uint8", "-o", tmp_path / "exr.ppm")
    assert read_pnm(tmp_path / "exr.ppm")[3] == png


def test_a_tiled_geotiff_keeps_the_class_maps_georeferencing(texsyn, small, tmp_path):
    classes, cat = small
    w, h, _, ids = pixels_of(classes, tmp_path)
    write_geotiff(tmp_path / "map.tif", w, h, ids)
    c = json.loads(cat.read_text())
    for k in c["classes"]:
        k["reference"] = str(cat.parent / k["reference"])
    del c["lines"]
    (tmp_path / "cat.json").write_text(json.dumps(c))
    aerial(texsyn, tmp_path / "map.tif", tmp_path / "cat.json", tmp_path / "out.tif", *TILE)
    got = read_tiff_tags(tmp_path / "out.tif")
    assert 322 in got, "not a tiled TIFF"
    assert gdal_georef(tmp_path / "out.tif") == GEOREF


def test_grid_parameters_that_do_not_fit_are_refused(texsyn, small, tmp_path):
    classes, cat = small
    p = aerial(texsyn, classes, cat, tmp_path / "x.png", "--tile", "100", check=False)
    assert p.returncode == 2 and "--tile 100: need a multiple of 16" in p.stderr, p.stderr
    p = aerial(texsyn, classes, cat, tmp_path / "x.png", "--tile", "16", check=False)
    assert p.returncode == 2 and "--halo 20: at most half a tile (--tile 16)" in p.stderr, p.stderr
    p = aerial(texsyn, classes, cat, tmp_path / "x.png", "--tile", "96", "--max-pixels", "20000", check=False)
    assert p.returncode == 2 and "184x184 pixels exceeds the limit of 20000" in p.stderr, p.stderr
    assert not (tmp_path / "x.png").exists()


@pytest.mark.sanitize
def test_the_same_bytes_embedded_and_on_3_2_1_workers_with_1_or_2_tile_jobs(texsyn, small, cluster, tmp_path):
    classes, cat = small
    aerial(texsyn, classes, cat, tmp_path / "e.png", *TILE, "--threads", "1", "--tile-jobs", "1")
    expected = pixels_of(tmp_path / "e.png", tmp_path)[3]
    aerial(texsyn, classes, cat, tmp_path / "e2.png", *TILE, "--tile-jobs", "2", "--report", tmp_path / "r.json")
    assert json.loads((tmp_path / "r.json").read_text())["tiles"]["tile_jobs"] == 2
    assert pixels_of(tmp_path / "e2.png", tmp_path)[3] == expected, "embedded, 2 tile jobs"
    cluster.start(3, 1)
    runs = [(3, "1"), (3, "2"), (2, "2"), (1, "2"), (1, "1")]
    for n, jobs in runs:
        while len([w for w in cluster.workers if w.proc.poll() is None]) > n:
            next(w for w in cluster.workers if w.proc.poll() is None).proc.kill()
        out = tmp_path / f"c{n}-{jobs}.png"
        cluster.texsyn("aerial", "--classes", classes, "--catalogue", cat, "-o", out, "--quiet", *TILE,
                       "--tile-jobs", jobs)
        assert pixels_of(out, tmp_path)[3] == expected, f"{n} workers, {jobs} tile jobs"


def whole_pieces(jobdir):
    """The tiles saved as checkpoint pieces (a piece is written to a
    temporary name, then renamed)."""
    return [f for f in jobdir.glob("piece-tile-*") if ".tmp" not in f.name]


def test_a_worker_killed_mid_scene_changes_nothing(texsyn, cluster, tmp_path):
    """512x512 in 64 tiles (sanitized: 384x384, 36) on 2 workers, 2 tiles
    at a time; one worker is killed once a dozen tiles are finished."""
    classes, cat = scene(tmp_path, 384 if SANITIZED else 512, seed=3)
    aerial(texsyn, classes, cat, tmp_path / "e.png", *TILE)
    cluster.start(2, 1)
    p = cluster.texsyn("aerial", "--classes", classes, "--catalogue", cat, "-o", tmp_path / "unused.png", *TILE,
                       "--tile-jobs", "2", "--detach")
    job_id = p.stdout.split()[-1]
    jobdir = cluster.tmp / "spool" / "jobs" / job_id
    deadline = time.time() + 120
    while len(whole_pieces(jobdir)) < 12:
        assert time.time() < deadline, cluster.server.read_log()
        time.sleep(0.01)
    victim = cluster.workers[1]
    victim.proc.kill()
    w = cluster.texsyn("watch", job_id, "--quiet", check=False, timeout=300)
    assert w.returncode == 0, w.stderr + cluster.server.read_log()
    dropped_during_the_job(cluster.server.read_log(), victim.addr)
    cluster.texsyn("fetch", job_id, "-o", tmp_path / "c.png")
    assert pixels_of(tmp_path / "c.png", tmp_path)[3] == pixels_of(tmp_path / "e.png", tmp_path)[3]


def test_a_killed_coordinator_resumes_at_its_unfinished_tiles(texsyn, cluster, tmp_path):
    """512x512 in 64 tiles of 64x64 (sanitized: 384x384, 36) on one
    worker; the coordinator is killed (SIGKILL) once a dozen tiles are
    saved as checkpoint pieces."""
    size = 384 if SANITIZED else 512
    tiles = (size // 64) ** 2
    classes, cat = scene(tmp_path, size, seed=3)
    aerial(texsyn, classes, cat, tmp_path / "e.png", *TILE)
    cluster.start(1, 1)
    p = cluster.texsyn("aerial", "--classes", classes, "--catalogue", cat, "-o", tmp_path / "unused.png", *TILE,
                       "--report", tmp_path / "unused.json", "--detach")
    job_id = p.stdout.split()[-1]
    jobdir = cluster.tmp / "spool" / "jobs" / job_id
    deadline = time.time() + 120
    while len(whole_pieces(jobdir)) < 12:
        assert time.time() < deadline, cluster.server.read_log()
        time.sleep(0.01)
    cluster.server.proc.send_signal(signal.SIGKILL)
    cluster.server.proc.wait()
    cluster.server.stop()
    saved = len(whole_pieces(jobdir))
    assert saved < tiles, "the job ended before the kill"
    cluster.restart_server()
    w = cluster.texsyn("watch", job_id, "--quiet", check=False, timeout=300)
    log = cluster.server.read_log()
    assert w.returncode == 0, w.stderr + log
    m = re.search(rf"job {job_id}: resuming with at least (\d+) of its {tiles} tiles finished from its checkpoint",
                  log)
    assert m and 1 <= int(m.group(1)) <= saved, log
    cluster.texsyn("fetch", job_id, "-o", tmp_path / "r.png", "--report", tmp_path / "r.json")
    assert json.loads((tmp_path / "r.json").read_text())["tiles"]["resumed"] == saved, "a saved tile made again"
    assert pixels_of(tmp_path / "r.png", tmp_path)[3] == pixels_of(tmp_path / "e.png", tmp_path)[3]
    assert not list(jobdir.glob("piece-*")), "pieces left behind a finished job"


def planes(png, tmp, name):
    """(colour bytes, alpha bytes) of an RGBA PNG."""
    oiiotool(png, "--ch", "R,G,B", "-o", tmp / f"{name}-rgb.pnm")
    oiiotool(png, "--ch", "A", "-o", tmp / f"{name}-a.pgm")
    return read_pnm(tmp / f"{name}-rgb.pnm"), read_pnm(tmp / f"{name}-a.pgm")


def test_a_running_scene_shows_a_growing_preview_on_the_page(texsyn, cluster, tmp_path):
    """The operations page's thumbnail of a running tiled scene is its
    preview as far as the rows written (preview.h): opaque above,
    transparent below, never cached; once done, the whole scene's."""
    import urllib.request
    size = 384 if SANITIZED else 512
    classes, cat = scene(tmp_path, size, seed=5)
    cluster.start(1, 1, "--http", "127.0.0.1:0")
    base = "http://" + cluster.server.wait_log(r"http page on (\S+?),").group(1)
    p = cluster.texsyn("aerial", "--classes", classes, "--catalogue", cat, "-o", tmp_path / "unused.png", *TILE,
                       "--detach")
    job_id = p.stdout.split()[-1]
    preview = cluster.tmp / "spool" / "jobs" / job_id / "preview.png"
    deadline = time.time() + 120
    while not preview.exists():
        assert time.time() < deadline, cluster.server.read_log()
        time.sleep(0.01)
    with urllib.request.urlopen(f"{base}/jobs/{job_id}/thumb.png", timeout=30) as r:
        assert r.status == 200 and r.headers["Cache-Control"] == "no-store", r.headers
        (tmp_path / "live.png").write_bytes(r.read())
    (w, h, _, rgb), (_, _, _, alpha) = planes(tmp_path / "live.png", tmp_path, "live")
    assert (w, h) == (160, 160)
    assert set(alpha[:w]) == {255}, "the first rows written are not shown"
    assert set(alpha[-w:]) == {0}, "rows not written yet are shown"
    assert cluster.texsyn("watch", job_id, "--quiet").returncode == 0
    cluster.texsyn("fetch", job_id, "-o", tmp_path / "r.png")
    with urllib.request.urlopen(f"{base}/jobs/{job_id}/thumb.png", timeout=30) as r:
        assert r.headers["Cache-Control"] != "no-store", r.headers
        (tmp_path / "done.png").write_bytes(r.read())
    (w, h, _, rgb), (_, _, _, alpha) = planes(tmp_path / "done.png", tmp_path, "done")
    assert set(alpha) == {255}
    full = pixels_of(tmp_path / "r.png", tmp_path)[3]
    for k in range(3):  # the preview averages the result: the same mean colour
        assert abs(sum(rgb[k::3]) / (w * h) - sum(full[k::3]) / (size * size)) < 1.5
