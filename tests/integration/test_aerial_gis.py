"""texsyn aerial with GIS data (issue 28; server/engines/region_gis.c): a
GeoTIFF class map read through GDAL, roads and paths as a vector layer
rasterised by regions at the scene's grid, the output a GeoTIFF (or a
Cloud-Optimised GeoTIFF) written through GDAL with the class map's
georeferencing. Scenes from `mkscene --gis`; everything read back with
GDAL's own tools and Python bindings, independent of texsyn's library.
Checked: the georeferencing kept, the lines in their rules' colours where
GDAL's own rasterisation of the buffered lines puts them (paths hidden
under forest), the same bytes embedded and on 2 workers, a COG with
overviews and the same pixels, and bad input refused before any work."""
import json
from pathlib import Path
import math
import subprocess

import pytest
from osgeo import gdal, ogr

from conftest import BUILD, REPO, run
from test_aerial import gdal_georef

gdal.UseExceptions()

SIZE = 1024
TILE = ["--tile", "256"]
ROAD, PATH = (90, 90, 90), (200, 180, 140)
FOREST = 1


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """The class map, a catalogue drawing the vector roads (paths hidden
    under forest), and the rules as mkscene wrote them."""
    d = tmp_path_factory.mktemp("gis")
    run(BUILD / "bench/mkscene", "--gis", "--size", SIZE, "--seed", 5, "-o", d / "s")
    run("bash", REPO / "bench/aerial_refs.sh", d)
    cat = json.loads((d / "catalogue.json").read_text())
    rules = json.loads((d / "s-lines.json").read_text())
    rules["rules"][1]["hidden_under"] = [FOREST]  # mkscene's rule 2 draws the paths
    assert [r["match"] for r in rules["rules"]] == ["road", "path"]
    cat["lines"] = {"vector": "s-roads.geojson", **rules, "colours": {"255": list(ROAD), "128": list(PATH)}}
    (d / "vcat.json").write_text(json.dumps(cat, indent=1))
    return d, rules


def aerial(texsyn, classes, cat, out, *extra, check=True):
    return run(texsyn, "aerial", "--classes", classes, "--catalogue", cat, "-o", out, "--quiet", *extra, check=check)


def rgb_of(path):
    """The decoded pixels, bands interleaved (GDAL's reader)."""
    ds = gdal.Open(str(path))
    bands = [ds.GetRasterBand(b + 1).ReadRaster() for b in range(3)]
    return ds.RasterXSize, ds.RasterYSize, bytes(v for px in zip(*bands) for v in px)


def ids_of(path):
    ds = gdal.Open(str(path))
    return ds.GetRasterBand(1).ReadRaster()


def expected_lines(d, rules):
    """The line value of every pixel as GDAL rasterises the layer itself:
    each feature buffered to half its width (its width attribute, in map
    units), burnt by pixel centres in draw order (paths, order 1, before
    roads, order 2)."""
    src = gdal.Open(str(d / "s-classes.tif"))
    mem = gdal.GetDriverByName("MEM").Create("", src.RasterXSize, src.RasterYSize, 1, gdal.GDT_Byte)
    mem.SetGeoTransform(src.GetGeoTransform())
    mem.SetProjection(src.GetProjection())
    vec = ogr.Open(str(d / "s-roads.geojson"))  # kept: its layer dies with it
    layer = vec.GetLayer(0)
    by_match = {r["match"]: r for r in rules["rules"]}
    for r in sorted(rules["rules"], key=lambda r: r["order"]):
        tmp = ogr.GetDriverByName("Memory").CreateDataSource("")
        out = tmp.CreateLayer("b", srs=layer.GetSpatialRef())
        layer.ResetReading()
        for f in layer:
            if f.GetField("kind") != r["match"]:
                continue
            g = ogr.Feature(out.GetLayerDefn())
            g.SetGeometry(f.GetGeometryRef().Buffer(f.GetField("width") / 2, 16))
            out.CreateFeature(g)
        gdal.RasterizeLayer(mem, [1], out, burn_values=[by_match[r["match"]]["value"]])
    return mem.GetRasterBand(1).ReadRaster()


def test_vector_roads_drawn_in_their_colours_and_the_georeferencing_kept(texsyn, scene, tmp_path):
    d, rules = scene
    out = tmp_path / "out.tif"
    aerial(texsyn, d / "s-classes.tif", d / "vcat.json", out, *TILE)
    assert gdal_georef(out) == gdal_georef(d / "s-classes.tif")
    assert gdal_georef(out)[0] == [500000.0, 0.25, 0.0, 5700000.0, 0.0, -0.25]
    w, h, px = rgb_of(out)
    assert (w, h) == (SIZE, SIZE)
    ids, want = ids_of(d / "s-classes.tif"), expected_lines(d, rules)
    drawn = {"road": 0, "path": 0, "hidden": 0}
    wrong = []
    for i in range(w * h):
        rgb = tuple(px[3 * i:3 * i + 3])
        v = want[i]
        if v == 255 or (v == 128 and ids[i] != FOREST):
            drawn["road" if v == 255 else "path"] += 1
            if rgb != (ROAD if v == 255 else PATH):
                wrong.append((i % w, i // w, v, rgb))
        elif v == 128:
            drawn["hidden"] += 1
            if rgb == PATH:
                wrong.append((i % w, i // w, "hidden path", rgb))
        elif rgb in (ROAD, PATH):
            wrong.append((i % w, i // w, "no line", rgb))
    # Buffers are polygons of segments (GEOS and texsyn's library may cut
    # the round caps alike or not): a pixel centre on a cap's edge may go
    # either way, never more than a few in a scene.
    assert len(wrong) <= 0.002 * (drawn["road"] + drawn["path"]), wrong[:20]
    assert drawn["road"] > 5000 and drawn["path"] > 300 and drawn["hidden"] > 300, drawn


def test_the_same_bytes_embedded_and_on_2_workers_and_a_cog_with_overviews(texsyn, scene, cluster, tmp_path):
    d, _ = scene
    aerial(texsyn, d / "s-classes.tif", d / "vcat.json", tmp_path / "e.tif", *TILE, "--tile-jobs", "2")
    expected = rgb_of(tmp_path / "e.tif")
    cluster.start(2, 1)
    cluster.texsyn("aerial", "--classes", d / "s-classes.tif", "--catalogue", d / "vcat.json", "-o",
                   tmp_path / "c.tif", "--quiet", *TILE, "--tile-jobs", "2")
    assert rgb_of(tmp_path / "c.tif") == expected, "2 workers"
    cog = tmp_path / "cog.tif"
    aerial(texsyn, d / "s-classes.tif", d / "vcat.json", cog, *TILE, "--cog")
    assert rgb_of(cog) == expected, "the COG's full resolution"
    info = json.loads(subprocess.run(["gdalinfo", "-json", str(cog)], check=True, capture_output=True,
                                     text=True).stdout)
    assert info["metadata"]["IMAGE_STRUCTURE"].get("LAYOUT") == "COG", info["metadata"]
    sizes = [tuple(o["size"]) for o in info["bands"][0].get("overviews", [])]
    assert sizes == [(512, 512), (256, 256)], sizes
    assert gdal_georef(cog) == gdal_georef(d / "s-classes.tif")
    assert not list(tmp_path.glob("*.part")), "partial files left"


def test_a_layer_in_another_crs_is_reprojected(texsyn, scene, tmp_path):
    """The roads in geographic coordinates (EPSG:4326) land where the UTM
    ones do, give or take the pixels along the buffers' edges that the
    curved reprojection moves."""
    d, _ = scene
    run("ogr2ogr", "-t_srs", "EPSG:4326", tmp_path / "ll.geojson", d / "s-roads.geojson")
    cat = json.loads((d / "vcat.json").read_text())
    cat["lines"]["vector"] = str(tmp_path / "ll.geojson")
    for k in cat["classes"]:
        k["reference"] = str(d / k["reference"])
    (tmp_path / "cat.json").write_text(json.dumps(cat))
    aerial(texsyn, d / "s-classes.tif", tmp_path / "cat.json", tmp_path / "ll.tif", *TILE)
    aerial(texsyn, d / "s-classes.tif", d / "vcat.json", tmp_path / "utm.tif", *TILE)
    _, _, a = rgb_of(tmp_path / "ll.tif")
    _, _, b = rgb_of(tmp_path / "utm.tif")
    road_a = {i for i in range(SIZE * SIZE) if a[3 * i:3 * i + 3] == bytes(ROAD)}
    road_b = {i for i in range(SIZE * SIZE) if b[3 * i:3 * i + 3] == bytes(ROAD)}
    assert len(road_b) > 5000 and len(road_a ^ road_b) <= 0.02 * len(road_b), (len(road_a), len(road_b))


def shifted(src, dst, dx):
    g = json.loads(src.read_text())
    for f in g["features"]:
        f["geometry"]["coordinates"] = [[x + dx, y] for x, y in f["geometry"]["coordinates"]]
    dst.write_text(json.dumps(g))


def catalogue_with(d, tmp_path, **lines):
    cat = json.loads((d / "vcat.json").read_text())
    cat["lines"].update(lines)
    for k in cat["classes"]:
        k["reference"] = str(d / k["reference"])
    if cat["lines"].get("vector"):
        cat["lines"]["vector"] = str(d / cat["lines"]["vector"]) if "/" not in cat["lines"]["vector"] \
            else cat["lines"]["vector"]
    p = tmp_path / "cat.json"
    p.write_text(json.dumps(cat))
    return p


def refused(p, out, *words):
    assert p.returncode == 2, (p.returncode, p.stderr)
    for w in words:
        assert w in p.stderr, p.stderr
    assert not out.exists() and not list(out.parent.glob(out.name + "*part")), "work was done"


def test_bad_input_is_refused_before_any_work(texsyn, scene, tmp_path):
    d, _ = scene
    out = tmp_path / "x.tif"
    # A layer lying outside the scene (shifted 100 km east).
    shifted(d / "s-roads.geojson", tmp_path / "far.geojson", 100000.0)
    p = aerial(texsyn, d / "s-classes.tif", catalogue_with(d, tmp_path, vector=str(tmp_path / "far.geojson")), out,
               *TILE, check=False)
    refused(p, out, "far.geojson")
    # A layer with a CRS on a class map without one (a PNG).
    run("gdal_translate", "-q", "-of", "PNG", d / "s-classes.tif", tmp_path / "plain.png")
    p = aerial(texsyn, tmp_path / "plain.png", catalogue_with(d, tmp_path), out, *TILE, check=False)
    refused(p, out, "s-roads.geojson")
    # A class id without a catalogue entry: sand (4) dropped.
    cat = json.loads(catalogue_with(d, tmp_path).read_text())
    sand = sum(1 for v in ids_of(d / "s-classes.tif") if v == 4)
    cat["classes"] = [k for k in cat["classes"] if k["id"] != 4]
    (tmp_path / "nosand.json").write_text(json.dumps(cat))
    p = aerial(texsyn, d / "s-classes.tif", tmp_path / "nosand.json", out, *TILE, check=False)
    refused(p, out, "class ids the catalogue has no entry for: 4 (")
    counted = int(p.stderr.split("no entry for: 4 (")[1].split(" ")[0])
    assert 0 < counted <= sand, (counted, sand)  # the roads cover some sand
    # A layer in a CRS PROJ has no transformation from (a local engineering
    # one): refused with both CRSs named, not drawn in the wrong place.
    local = 'ENGCRS["site grid",EDATUM["site"],CS[Cartesian,2],AXIS["x",east,LENGTHUNIT["metre",1]],' \
            'AXIS["y",north,LENGTHUNIT["metre",1]]]'
    run("ogr2ogr", "-a_srs", local, tmp_path / "local.gpkg", d / "s-roads.geojson")
    p = aerial(texsyn, d / "s-classes.tif", catalogue_with(d, tmp_path, vector=str(tmp_path / "local.gpkg")), out,
               *TILE, check=False)
    refused(p, out, "local.gpkg", "site grid", "UTM zone 32N")


def test_a_shapefile_goes_to_a_coordinator_as_one_file(texsyn, scene, cluster, tmp_path):
    """A Shapefile is four files (.shp, .shx, .dbf, .prj); sent to a
    coordinator it goes as one GeoPackage the client makes (gis_pack.c),
    and draws the same roads as the GeoJSON it came from, embedded and on
    a worker."""
    d, _ = scene
    run("ogr2ogr", tmp_path / "roads.shp", d / "s-roads.geojson")
    assert {f.suffix for f in tmp_path.glob("roads.*")} >= {".shp", ".shx", ".dbf", ".prj"}
    cat = catalogue_with(d, tmp_path, vector=str(tmp_path / "roads.shp"))
    aerial(texsyn, d / "s-classes.tif", d / "vcat.json", tmp_path / "json.tif", *TILE)
    aerial(texsyn, d / "s-classes.tif", cat, tmp_path / "shp.tif", *TILE)
    expected = rgb_of(tmp_path / "json.tif")
    assert rgb_of(tmp_path / "shp.tif") == expected, "embedded"
    cluster.start(1, 1)
    cluster.texsyn("aerial", "--classes", d / "s-classes.tif", "--catalogue", cat, "-o", tmp_path / "c.tif",
                   "--quiet", *TILE)
    assert rgb_of(tmp_path / "c.tif") == expected, "on a coordinator"
    sent = list((cluster.tmp / "spool" / "jobs").glob("*/lines.*"))
    assert [f.suffix for f in sent] == [".gpkg"], sent
    assert not list(Path("/tmp").glob("texsyn-*/roads.gpkg")), "the packed layer left behind"


def test_a_scene_larger_than_the_free_disk_is_refused_before_any_work(texsyn, scene, tmp_path):
    """A 1 MiB file system (a tmpfs in a mount namespace of its own) for
    a 1024² scene: 3 MiB of samples, 4.2 MB with the bound's margins, refused
    before a tile."""
    d, _ = scene
    mnt = tmp_path / "small"
    mnt.mkdir()
    cmd = (f"mount -t tmpfs -o size=1m tmpfs {mnt} && {texsyn} aerial --classes {d / 's-classes.tif'} "
           f"--catalogue {d / 'vcat.json'} -o {mnt / 'out.tif'} --quiet --tile 256 "
           f"--report {mnt / 'r.json'}; echo rc=$?; ls -A {mnt}")
    p = subprocess.run(["unshare", "-rm", "sh", "-c", cmd], capture_output=True, text=True, timeout=300)
    assert "rc=1" in p.stdout, (p.stdout, p.stderr)
    assert "may take up to 4.2 MB" in p.stderr and "1.0 MB free" in p.stderr, p.stderr
    assert p.stdout.strip().endswith("rc=1"), p.stdout  # nothing left in the mount
