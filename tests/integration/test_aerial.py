"""texsyn aerial: a synthetic aerial image from a class map (bench/mkscene)
and a catalogue of references cut from aero1.jpg (bench/aerial_refs.sh).
Checked: lines are drawn in their colours and every other pixel comes from
its own class's reference; the same bytes in-process and on a cluster, with
a worker killed mid-job too; the report's classes in fill order (stochastic
first); class ids without a catalogue entry named with their pixel counts;
and a catalogue error reaching the user with its line and column."""
import json
import re
import struct
import subprocess
import time

import pytest

from conftest import BUILD, REPO, dropped_during_the_job, modbus_registers, run
from pnm import oiiotool, read_pnm


def scene(d, size, seed=7):
    run(BUILD / "bench/mkscene", "--size", size, "--seed", seed, "-o", d / "scene")
    subprocess.run(["bash", REPO / "bench/aerial_refs.sh", d], check=True, capture_output=True, timeout=120)
    return d / "scene-classes.png", d / "catalogue.json"


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    return scene(tmp_path_factory.mktemp("aerial"), 256)


def aerial(texsyn, classes, cat, out, *extra, check=True):
    return run(texsyn, "aerial", "--classes", classes, "--catalogue", cat, "-o", out, "--quiet", *extra, check=check)


def test_lines_keep_their_colours_and_classes_come_from_their_references(texsyn, small, tmp_path):
    classes, cat = small
    out, report = tmp_path / "out.png", tmp_path / "r.json"
    aerial(texsyn, classes, cat, out, "--report", report)
    for name, img in (("out", out), ("classes", classes), ("roads", classes.parent / "scene-roads.png")):
        oiiotool(img, "-o", tmp_path / f"{name}.pnm")
    w, h, _, px = read_pnm(tmp_path / "out.pnm")
    _, _, _, ids = read_pnm(tmp_path / "classes.pnm")
    _, _, _, roads = read_pnm(tmp_path / "roads.pnm")
    c = json.loads(cat.read_text())
    colours = {int(k): bytes(v) for k, v in c["lines"]["colours"].items()}
    refs = {}
    for k in c["classes"]:
        oiiotool(cat.parent / k["reference"], "-o", tmp_path / f"{k['name']}.pnm")
        refs[k["id"]] = set()
        _, _, _, rpx = read_pnm(tmp_path / f"{k['name']}.pnm")
        refs[k["id"]] = {rpx[i:i + 3] for i in range(0, len(rpx), 3)}
    for i in range(w * h):
        rgb = px[3 * i:3 * i + 3]
        if roads[i] in colours:
            assert rgb == colours[roads[i]], f"line pixel {i % w},{i // w}"
        else:
            assert rgb in refs[ids[i]], f"pixel {i % w},{i // w} of class {ids[i]} is no colour of its reference"
    r = json.loads(report.read_text())
    assert r["engine"] == "aerial" and r["search"]["lossy"] == []
    kinds = [k["kind"] for k in r["classes"]]
    assert kinds == sorted(kinds, key=lambda k: k != "stochastic"), kinds  # stochastic classes first
    assert all(k["blocks"] > 0 for k in r["classes"])


@pytest.mark.sanitize
def test_the_same_bytes_on_a_cluster(texsyn, small, cluster, tmp_path):
    classes, cat = small
    aerial(texsyn, classes, cat, tmp_path / "e.png", "--threads", "1")
    cluster.start(3, 1)
    cluster.texsyn("aerial", "--classes", classes, "--catalogue", cat, "-o", tmp_path / "c.png", "--quiet")
    assert (tmp_path / "c.png").read_bytes() == (tmp_path / "e.png").read_bytes()


def test_a_killed_worker_changes_nothing(texsyn, cluster, tmp_path):
    """512x512 on 3 workers; one is killed once it holds a slice of level 0
    (Modbus: its vectors; level 0 has 6600 forest and 15000 town vectors,
    level 1 at most 3400)."""
    classes, cat = scene(tmp_path, 512, seed=3)
    aerial(texsyn, classes, cat, tmp_path / "e.png")
    for _ in range(3):
        cluster.worker(1, "--modbus", "0")
    cluster.start()
    job = subprocess.Popen([str(texsyn), "aerial", "--classes", str(classes), "--catalogue", str(cat), "-o",
                            str(tmp_path / "c.png"), "--quiet", "--server", cluster.server.addr],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    victim = cluster.workers[1]
    deadline = time.time() + 120
    while int(modbus_registers(victim.modbus)["vectors"]) < 1500:
        assert time.time() < deadline and job.poll() is None, "the victim never held a level-0 slice"
        time.sleep(0.005)
    victim.proc.kill()
    out, err = job.communicate(timeout=600)
    assert job.returncode == 0, err
    dropped_during_the_job(cluster.server.read_log(), victim.addr)
    assert (tmp_path / "c.png").read_bytes() == (tmp_path / "e.png").read_bytes()


def test_class_ids_without_an_entry_are_named(texsyn, small, tmp_path):
    classes, cat = small
    c = json.loads(cat.read_text())
    c["classes"] = [k for k in c["classes"] if k["name"] != "water"]
    for k in c["classes"]:
        k["reference"] = str(cat.parent / k["reference"])
    c["lines"]["raster"] = str(cat.parent / c["lines"]["raster"])
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(c))
    p = aerial(texsyn, classes, bad, tmp_path / "x.png", check=False)
    assert p.returncode == 2
    assert "class ids the catalogue has no entry for: 2 (" in p.stderr, p.stderr


def test_a_catalogue_error_names_its_place(texsyn, small, tmp_path):
    classes, cat = small
    bad = tmp_path / "typo.json"
    bad.write_text(cat.read_text().replace('"usage_weight"', '"usage_wieght"', 1))
    p = aerial(texsyn, classes, bad, tmp_path / "x.png", check=False)
    assert p.returncode == 2
    assert "typo.json:2:" in p.stderr and "usage_wieght" in p.stderr, p.stderr


GEO_TAGS = {33550: (12, [0.5, 0.5, 0.0]),                       # ModelPixelScale (DOUBLE)
            33922: (12, [0.0, 0.0, 0.0, 500000.0, 5300000.0, 0.0]),  # ModelTiepoint
            34735: (3, [1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, 32632])}  # GeoKeyDirectory (SHORT)


def write_geotiff(path, w, h, pixels):
    """A little-endian 8-bit grey TIFF of `pixels` with the GeoTIFF tags
    above (UTM 32N, 0.5 m pixels), written by hand: no tool here makes one."""
    tags = {256: (3, [w]), 257: (3, [h]), 258: (3, [8]), 259: (3, [1]), 262: (3, [1]), 273: (4, [0]),
            277: (3, [1]), 278: (3, [h]), 279: (4, [w * h]), 284: (3, [1]), **GEO_TAGS}
    fmt = {3: "H", 4: "I", 12: "d"}
    ifd_at = 8
    data_at = ifd_at + 2 + 12 * len(tags) + 4
    long_values = sum(len(struct.pack(f"<{len(v)}{fmt[t]}", *v)) for t, v in tags.values()
                      if len(struct.pack(f"<{len(v)}{fmt[t]}", *v)) > 4)
    pix_at = data_at + long_values  # every long value is of doubles or shorts in pairs: even
    extra, entries = b"", b""
    for tag, (typ, vals) in sorted(tags.items()):
        raw = struct.pack(f"<{len(vals)}{fmt[typ]}", *([pix_at] if tag == 273 else vals))
        if len(raw) <= 4:
            entries += struct.pack("<HHI", tag, typ, len(vals)) + raw.ljust(4, b"\0")
        else:
            entries += struct.pack("<HHII", tag, typ, len(vals), data_at + len(extra))
            extra += raw
    path.write_bytes(b"II*\0" + struct.pack("<I", ifd_at) + struct.pack("<H", len(tags)) + entries +
                     b"\0\0\0\0" + extra + pixels)


# GEO_TAGS as GDAL reads them: the geotransform and the CRS's EPSG code.
GEOREF = ([500000.0, 0.5, 0.0, 5300000.0, 0.0, -0.5], 32632)


def gdal_georef(path):
    """(geotransform, EPSG code of the CRS) of a raster, read by gdalinfo:
    an independent reader of what the output claims."""
    info = json.loads(subprocess.run(["gdalinfo", "-json", str(path)], check=True, capture_output=True,
                                     text=True).stdout)
    codes = re.findall(r'ID\["EPSG",(\d+)\]\]$', info["coordinateSystem"]["wkt"])
    return info.get("geoTransform"), int(codes[-1]) if codes else None


def read_tiff_tags(path):
    """{tag: raw value bytes} of a little-endian TIFF's first directory."""
    data = path.read_bytes()
    assert data[:4] == b"II*\0", "not a little-endian TIFF"
    (ifd,) = struct.unpack_from("<I", data, 4)
    (n,) = struct.unpack_from("<H", data, ifd)
    out = {}
    for i in range(n):
        tag, typ, count, off = struct.unpack_from("<HHII", data, ifd + 2 + 12 * i)
        size = {1: 1, 2: 1, 3: 2, 4: 4, 12: 8}.get(typ, 1) * count
        out[tag] = data[ifd + 10 + 12 * i:ifd + 10 + 12 * i + size] if size <= 4 else data[off:off + size]
    return out


def test_a_geotiff_class_map_keeps_its_georeferencing(texsyn, small, tmp_path):
    classes, cat = small
    oiiotool(classes, "-o", tmp_path / "c.pnm")
    w, h, _, ids = read_pnm(tmp_path / "c.pnm")
    write_geotiff(tmp_path / "map.tif", w, h, ids)
    c = json.loads(cat.read_text())
    for k in c["classes"]:
        k["reference"] = str(cat.parent / k["reference"])
    del c["lines"]
    (tmp_path / "cat.json").write_text(json.dumps(c))
    aerial(texsyn, tmp_path / "map.tif", tmp_path / "cat.json", tmp_path / "out.tif")
    assert gdal_georef(tmp_path / "out.tif") == GEOREF
