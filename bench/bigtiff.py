#!/usr/bin/python3
"""A GeoTIFF past 4 GiB through the GIS writer (common/gis.h), as a
tiled scene's output (issue 28: "BigTIFF past 4 GiB").

bench/gis_write --noise writes an N x N RGB image of incompressible hash
noise tile by tile, so the file is as large as its pixels; at the default
38000² that is 4.33 GB, past the 4 GiB a classic TIFF's 32-bit offsets
reach. Checked: the file's header is BigTIFF's, its size is past 4 GiB,
gdalinfo reads it with its georeferencing, and the last tile - stored
past 4 GiB - decodes (through GDAL) to the very bytes written. Writes
bigtiff.md into --out; the image is removed afterwards.

  bench/bigtiff.py --build build [--size 38000] [--out bench/results] [--tmp DIR]
"""
import argparse
import json
import platform
import struct
import subprocess
import time
from pathlib import Path

from osgeo import gdal

REPO = Path(__file__).resolve().parent.parent
TILE = 1024


def hashed(x):
    x ^= x >> 16
    x = (x * 0x7FEB352D) & 0xFFFFFFFF
    x ^= x >> 15
    x = (x * 0x846CA68B) & 0xFFFFFFFF
    return x ^ (x >> 16)


def expected(x0, y0, w, h):
    """gis_write --noise's bytes of the region, bands interleaved."""
    out = bytearray()
    for y in range(y0, y0 + h):
        for x in range(x0, x0 + w):
            n = hashed(((x * 0x9E3779B1) & 0xFFFFFFFF) ^ y)
            out += bytes((n & 255, (n >> 8) & 255, (n >> 16) & 255))
    return bytes(out)


def region(path, x0, y0, w, h):
    ds = gdal.Open(str(path))
    bands = [ds.GetRasterBand(b + 1).ReadRaster(x0, y0, w, h) for b in range(3)]
    return bytes(v for px in zip(*bands) for v in px)


def cpu():
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor()


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--build", type=Path, required=True)
    p.add_argument("--size", type=int, default=38000)
    p.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    p.add_argument("--tmp", type=Path, default=Path("/tmp"))
    a = p.parse_args()
    img = a.tmp / "texsyn-bigtiff.tif"
    t0 = time.monotonic()
    run = subprocess.run([a.build / "bench" / "gis_write", "--noise", "--size", str(a.size), "--tile", str(TILE),
                          "-o", img], check=True, capture_output=True, text=True)
    seconds = time.monotonic() - t0
    try:
        size = img.stat().st_size
        with open(img, "rb") as f:
            magic = f.read(4)
        info = json.loads(subprocess.run(["gdalinfo", "-json", str(img)], check=True, capture_output=True,
                                         text=True).stdout)
        side = 256
        x0 = y0 = a.size - side  # in the last tile, written last: past 4 GiB
        same = region(img, x0, y0, side, side) == expected(x0, y0, side, side)
    finally:
        img.unlink(missing_ok=True)
    big = magic in (b"II+\x00", b"MM\x00+")
    lines = [f"# A GeoTIFF past 4 GiB (`bench/bigtiff.py`)", "",
             f"CPU: {cpu()}, {platform.machine()}; GDAL {gdal.__version__}.", "",
             f"`gis_write --noise --size {a.size} --tile {TILE}`: {a.size}x{a.size} RGB of incompressible noise, "
             f"written tile by tile through the GIS writer (DEFLATE, `BIGTIFF=IF_SAFER`) in {seconds:.0f} s "
             f"({run.stdout.strip()}).", "",
             "| check | result |", "|---|---|",
             f"| file size | {size:,} bytes ({size / 2**30:.2f} GiB; {'past' if size > 2**32 else 'NOT past'} 4 GiB) |",
             f"| header | {magic!r}: {'BigTIFF' if big else 'classic TIFF'} |",
             f"| gdalinfo | {info['size'][0]}x{info['size'][1]}, {len(info['bands'])} bands, "
             f"CRS {'kept' if 'coordinateSystem' in info else 'missing'}, origin {info['geoTransform'][0]:.0f}, "
             f"{info['geoTransform'][3]:.0f} |",
             f"| last {side}x{side} pixels (stored past 4 GiB) decoded by GDAL | "
             f"{'the bytes written' if same else 'DIFFERENT from the bytes written'} |"]
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "bigtiff.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    ok = big and size > 2**32 and same
    raise SystemExit(0 if ok else 1)


if __name__ == "__main__":
    main()
