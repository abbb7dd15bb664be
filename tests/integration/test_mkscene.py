"""bench/mkscene, the scene generator for aerial tests and benchmarks, at
512x512: the class map holds exactly the classes asked for, each over a
fair share and in many separate regions; the road raster holds roads and
paths and nothing else; the same seed gives the same bytes, another seed
other ones; a WxH size is kept; bad options are refused with status 2.
With --gis, the same map as a georeferenced tiled GeoTIFF (read back with
GDAL's own gdalinfo and oiiotool), the roads and paths as a GeoJSON layer
in the same CRS with kind and width, and line rules for them.
The images are read back through oiiotool (PGM), not through texsyn.
Also bench/aerial_refs.sh, which cuts the references of a catalogue for
these scenes from aero1.jpg."""
import json
import os
import subprocess

import pytest

from conftest import BUILD, REPO
from pnm import pixels_of

MKSCENE = BUILD / "bench" / "mkscene"
NAMES = ["forest", "water", "town", "sand", "grassland", "arable", "industrial", "wetland"]


def mkscene(*args, check=True):
    assert MKSCENE.exists(), f"{MKSCENE} is missing: run make first"
    p = subprocess.run([str(MKSCENE), *map(str, args)], capture_output=True, text=True, timeout=300)
    if check:
        assert p.returncode == 0, f"mkscene {' '.join(map(str, args))} failed ({p.returncode}):\n{p.stderr}"
    return p


def regions(w, h, pixels):
    """The number of 4-connected regions of equal value."""
    seen = bytearray(w * h)
    count = 0
    for start in range(w * h):
        if seen[start]:
            continue
        count += 1
        value, stack = pixels[start], [start]
        seen[start] = 1
        while stack:
            i = stack.pop()
            x, y = i % w, i // w
            for j, ok in ((i - 1, x > 0), (i + 1, x < w - 1), (i - w, y > 0), (i + w, y < h - 1)):
                if ok and not seen[j] and pixels[j] == value:
                    seen[j] = 1
                    stack.append(j)
    return count


@pytest.mark.parametrize("classes,seed", [(4, 1), (4, 2), (8, 3), (1, 4)])
def test_the_map_holds_the_classes_asked_for(tmp_path, classes, seed):
    p = mkscene("--size", 512, "--seed", seed, "--classes", classes, "-o", tmp_path / "s")
    w, h, _, pixels = pixels_of(tmp_path / "s-classes.png", tmp_path)
    assert (w, h) == (512, 512)
    counts = {v: pixels.count(v) for v in set(pixels)}
    assert sorted(counts) == list(range(1, classes + 1))
    for v, n in counts.items():
        share = n / (w * h)
        # Each class a fair share: none swamped, none a speck.
        assert 0.02 <= share <= (1 if classes == 1 else 0.75), f"class {v} covers {share:.1%}"
        # The shares it prints are the image's.
        assert f"class {v} {NAMES[v - 1]:<10s} {100 * share:5.1f}%" in p.stdout
    if classes > 1:
        # Irregular regions, not a few big blocks: a Voronoi of ~256 cells
        # merged by class leaves dozens of separate regions.
        assert regions(w, h, pixels) >= 30


@pytest.mark.sanitize
def test_the_road_raster_holds_roads_and_paths(tmp_path):
    mkscene("--size", 512, "--seed", 1, "-o", tmp_path / "s")
    w, h, _, pixels = pixels_of(tmp_path / "s-roads.png", tmp_path)
    assert (w, h) == (512, 512)
    values = set(pixels)
    assert values == {0, 128, 255}, f"values {sorted(values)}"
    roads, paths = pixels.count(255) / (w * h), pixels.count(128) / (w * h)
    # Three roads 3..9 px wide across 512 px cover about 1..6%; paths less.
    assert 0.005 <= roads <= 0.1, f"roads cover {roads:.2%}"
    assert 0 < paths < roads
    # Roads cross the image: some road pixel on at least two of its edges.
    rows = [pixels[y * w:(y + 1) * w] for y in range(h)]
    edges = [rows[0], rows[-1], bytes(r[0] for r in rows), bytes(r[-1] for r in rows)]
    assert sum(255 in e for e in edges) >= 2


@pytest.mark.sanitize
def test_same_seed_same_bytes_other_seed_other_bytes(tmp_path):
    mkscene("--size", 512, "--seed", 42, "-o", tmp_path / "a")
    mkscene("--size", 512, "--seed", 42, "-o", tmp_path / "b")
    mkscene("--size", 512, "--seed", 43, "-o", tmp_path / "c")
    for kind in ("classes", "roads"):
        a, b, c = ((tmp_path / f"{p}-{kind}.png").read_bytes() for p in "abc")
        assert a == b, f"{kind}: the same seed gave other bytes"
        assert a != c, f"{kind}: another seed gave the same bytes"


def test_a_rectangle_is_kept(tmp_path):
    mkscene("--size", "320x200", "--seed", 5, "-o", tmp_path / "r")
    for kind in ("classes", "roads"):
        w, h, _, _ = pixels_of(tmp_path / f"r-{kind}.png", tmp_path)
        assert (w, h) == (320, 200)


@pytest.mark.parametrize("args,message", [
    (["--size", "32"], "--size 32: need N or WxH, 64..16384 a side"),
    (["--size", "100x20000"], "--size 100x20000: need N or WxH, 64..16384 a side"),
    (["--classes", "9"], "--classes 9: need 1..8"),
    (["--classes", "0"], "--classes 0: need 1..8"),
    (["--seed", "-1"], "--seed -1: need a whole number 0..2^64-1"),
    (["--size", "20000"], "--size 20000: need N or WxH, 64..16384 a side"),
    (["--gis", "--size", "70000"], "--size 70000: need N or WxH, 64..65536 a side"),
    (["--gis", "--crs", "UTM32"], "--crs UTM32: need EPSG:N"),
    (["--gis", "--crs", "EPSG:999999"], "--crs EPSG:999999 is not a CRS GDAL knows"),
    (["--crs", "EPSG:32633"], "--crs and --pixel-size place the --gis files: add --gis"),
    (["--gis", "--pixel-size", "0"], "--pixel-size 0: need 0.01..100 (metres)"),
    (["--colour"], "unknown option or missing value: --colour"),
    (["extra"], "unexpected argument: extra"),
])
def test_bad_options_are_refused(tmp_path, args, message):
    p = mkscene("-o", tmp_path / "x", *args, check=False)
    assert p.returncode == 2
    assert f"mkscene: {message}" in p.stderr
    assert not list(tmp_path.iterdir()), "a refused run wrote files"


def test_output_is_required_and_write_errors_are_named(tmp_path):
    p = mkscene("--size", 64, check=False)
    assert p.returncode == 2 and "mkscene: -o PREFIX is required" in p.stderr
    p = mkscene("--size", 64, "-o", tmp_path / "missing" / "s", check=False)
    assert p.returncode == 1
    assert str(tmp_path / "missing") in p.stderr


def test_aerial_refs_cut_a_catalogue_for_the_scene(tmp_path, data):
    env = dict(os.environ, TEXSYN_DATA=str(data))
    script = REPO / "bench" / "aerial_refs.sh"
    p = subprocess.run(["bash", str(script), str(tmp_path), "--roads", "s-roads.png"], capture_output=True,
                       text=True, env=env, timeout=120)
    assert p.returncode == 0, p.stderr
    cat = json.loads((tmp_path / "catalogue.json").read_text())
    # mkscene's ids and names, a reference each, and its road raster's values.
    assert [(c["id"], c["name"]) for c in cat["classes"]] == list(enumerate(NAMES[:4], 1))
    assert [c["kind"] for c in cat["classes"]] == ["stochastic", "stochastic", "structured", "stochastic"]
    assert cat["lines"]["raster"] == "s-roads.png"
    assert sorted(cat["lines"]["colours"]) == ["128", "255"]
    sizes = {"forest": (112, 68), "water": (80, 32), "town": (160, 104), "sand": (96, 52)}
    for c in cat["classes"]:
        info = subprocess.run(["oiiotool", "--info", str(tmp_path / c["reference"])], capture_output=True,
                              text=True, check=True).stdout
        w, h = sizes[c["name"]]
        assert f"{w} x {h:4d}, 3 channel, uint8 png" in info, info


@pytest.mark.sanitize
def test_gis_files_hold_the_same_map_georeferenced_and_the_roads_as_lines(tmp_path):
    mkscene("--size", "320x256", "--seed", 3, "--classes", 8, "-o", tmp_path / "png")
    p = mkscene("--size", "320x256", "--seed", 3, "--classes", 8, "--gis", "--pixel-size", "0.5",
                "-o", tmp_path / "g")
    assert sorted(f.name for f in tmp_path.iterdir() if f.name.startswith("g-")) == [
        "g-classes.tif", "g-lines.json", "g-roads.geojson"]
    # The map: the PNG's pixels, placed in UTM 32N at 0.5 m, tiled, DEFLATE.
    _, _, _, want = pixels_of(tmp_path / "png-classes.png", tmp_path)
    w, h, ch, got = pixels_of(tmp_path / "g-classes.tif", tmp_path)
    assert (w, h, ch) == (320, 256, 1) and got == want
    info = json.loads(subprocess.run(["gdalinfo", "-json", str(tmp_path / "g-classes.tif")], capture_output=True,
                                     text=True, check=True).stdout)
    assert info["geoTransform"] == [500000.0, 0.5, 0.0, 5700000.0, 0.0, -0.5]
    assert 'PROJCRS["WGS 84 / UTM zone 32N"' in info["coordinateSystem"]["wkt"]
    assert info["bands"][0]["block"] == [512, 512] and info["bands"][0]["type"] == "Byte"
    assert info["metadata"]["IMAGE_STRUCTURE"]["COMPRESSION"] == "DEFLATE"
    # The lines: paths then roads, in the map's CRS and extent, widths in metres.
    layer = json.loads((tmp_path / "g-roads.geojson").read_text())
    assert layer["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::32632"
    kinds = [f["properties"]["kind"] for f in layer["features"]]
    assert kinds == ["path"] * kinds.count("path") + ["road"] * kinds.count("road")
    assert kinds.count("road") == 3 and kinds.count("path") == 2
    assert f"3 roads, 2 paths as lines" in p.stdout
    for f in layer["features"]:
        width = f["properties"]["width"]
        assert width == 1.0 if f["properties"]["kind"] == "path" else width in (1.5, 2.5, 3.5, 4.5)
        for x, y in f["geometry"]["coordinates"]:
            assert 500000 - 40 <= x <= 500000 + 160 + 40 and 5700000 - 128 - 40 <= y <= 5700000 + 40
    ogr = subprocess.run(["ogrinfo", "-so", "-al", str(tmp_path / "g-roads.geojson")], capture_output=True,
                         text=True, check=True).stdout
    assert "Feature Count: 5" in ogr and "UTM zone 32N" in ogr
    rules = json.loads((tmp_path / "g-lines.json").read_text())
    assert rules["field"] == "kind" and rules["width_field"] == "width"
    assert [(r["match"], r["value"], r["order"]) for r in rules["rules"]] == [("road", 255, 2), ("path", 128, 1)]
