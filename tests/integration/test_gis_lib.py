"""GDAL is a shared library of its own (libtexsyn-gis.so, common/gis_lib.h),
loaded by what touches GIS files and by nothing else: no program links
GDAL, bench/mkscene loads it for --gis only, and a library that cannot be
found or loaded gives one clear error before any work."""
import json
import os
import subprocess

import pytest

from conftest import BUILD

LIB = "libtexsyn-gis.so"
MKSCENE = BUILD / "bench" / "mkscene"


def needed(exe):
    out = subprocess.run(["readelf", "-d", str(exe)], capture_output=True, text=True, check=True).stdout
    return [line.split("[", 1)[1].rstrip("]") for line in out.splitlines() if "(NEEDED)" in line]


@pytest.mark.sanitize
@pytest.mark.parametrize("exe", ["texsyn", "texsyn-server", "texsyn-worker", "bench/mkscene"])
def test_programs_do_not_link_gdal(exe):
    libs = needed(BUILD / exe)
    assert libs and not [n for n in libs if "gdal" in n], libs


@pytest.mark.sanitize
def test_the_library_exports_only_its_table():
    assert "libgdal.so.32" in needed(BUILD / LIB)
    out = subprocess.run(["nm", "-D", "--defined-only", str(BUILD / LIB)], capture_output=True, text=True,
                         check=True).stdout
    # (ASan adds its own marker symbol, __odr_asan.NAME, beside each global.)
    ours = [line.split()[-1] for line in out.splitlines() if "ts_" in line and "__odr_asan" not in line]
    assert ours == ["ts_gis_lib_v2"], ours


def mkscene(tmp_path, *args, env=None):
    return subprocess.run([str(MKSCENE), "--size", "64", "-o", str(tmp_path / "s"), *args], capture_output=True,
                          text=True, timeout=120, env={**os.environ, **(env or {})})


@pytest.mark.sanitize
def test_gdal_is_loaded_for_gis_files_only(tmp_path):
    # (libgdal itself may come with the image library: Debian's OpenImageIO
    # links OpenCV's imgcodecs, which links GDAL.)
    p = mkscene(tmp_path, env={"LD_DEBUG": "files"})
    assert p.returncode == 0, p.stderr[-2000:]
    assert LIB not in p.stderr
    p = mkscene(tmp_path, "--gis", env={"LD_DEBUG": "files"})
    assert p.returncode == 0, p.stderr[-2000:]
    assert LIB in p.stderr and "libgdal" in p.stderr


@pytest.mark.sanitize
def test_a_gis_library_that_does_not_load_is_named(tmp_path):
    bad = tmp_path / "nowhere" / LIB
    p = mkscene(tmp_path, "--gis", env={"TEXSYN_GIS_LIB": str(bad)})
    assert p.returncode == 1
    assert str(bad) in p.stderr and "TEXSYN_GIS_LIB" in p.stderr and "No such file" in p.stderr, p.stderr
    assert not list(tmp_path.glob("s-*")), "files were written before the library loaded"
    # A file that is not a library of this build: named, with what to do.
    other = tmp_path / "other.so"
    other.write_bytes((BUILD / "libtexsyn-image.so").read_bytes())
    p = mkscene(tmp_path, "--gis", env={"TEXSYN_GIS_LIB": str(other)})
    assert p.returncode == 1
    assert f"{other} (set by TEXSYN_GIS_LIB) is not the GIS library (GDAL) of this texsyn build" in p.stderr, p.stderr
    # Without --gis nothing needs it.
    assert mkscene(tmp_path, env={"TEXSYN_GIS_LIB": str(bad)}).returncode == 0


@pytest.mark.sanitize
def test_gdalinfo_reads_a_cog_written_tile_by_tile(tmp_path):
    out = tmp_path / "cog.tif"
    p = subprocess.run([str(BUILD / "bench" / "gis_write"), "-o", str(out), "--size", "600x400", "--tile", "128",
                        "--cog"], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert "600x400 tile 128 COG: puts" in p.stdout
    info = json.loads(subprocess.run(["gdalinfo", "-json", str(out)], capture_output=True, text=True,
                                     check=True).stdout)
    assert info["size"] == [600, 400]
    assert info["geoTransform"] == [500000.0, 0.25, 0.0, 5700000.0, 0.0, -0.25]
    assert 'PROJCRS["WGS 84 / UTM zone 32N"' in info["coordinateSystem"]["wkt"]
    assert info["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"] == "COG"
    assert info["metadata"]["IMAGE_STRUCTURE"]["COMPRESSION"] == "DEFLATE"
    for band in info["bands"]:
        assert band["block"] == [128, 128]
        assert [o["size"] for o in band["overviews"]] == [[300, 200], [150, 100], [75, 50]]  # down to one tile
    assert sorted(f.name for f in tmp_path.iterdir()) == ["cog.tif"]
