"""Texture collages with a known truth, for `texsyn segment` (the test
test_segment.py and the benchmark bench/segment.py).

A class is a grey texture: one crop of a picture for training, another,
disjoint crop for the collage. The collage is drawn pixel by pixel from
shapes (a disk, a triangle, an L, a band: not quadrants), each filled with
its class's texture (the texture's pixel at the pixel's offset in the
shape's bounding box, so a small source fills a shape as large as itself),
and the truth raster is drawn the same way. oiiotool reads each picture
once (resized, turned grey) and writes every PNG in one run; the pixels
pass through binary PGM (8-bit: oiiotool garbles 16-bit PGM samples),
which Python reads, crops and writes without numpy.
"""
import re
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

from pnm import oiiotool, read_pnm


def read_grey(path):
    """(width, height, values) of a one-channel image file, the values as
    stored (oiiotool --dumpdata; its PGM writer garbles 16-bit samples)."""
    out = subprocess.run(["oiiotool", "--dumpdata", path], capture_output=True, text=True, check=True).stdout
    head = re.search(r":\s+(\d+) x\s+(\d+), 1 channel", out)
    assert head, f"{path}: not a one-channel image"
    values = [int(v) for v in re.findall(r"^\s+Pixel \(\d+, \d+\): (\d+)", out, re.M)]
    return int(head.group(1)), int(head.group(2)), values


def write_pngs(images):
    """8-bit grey PNGs, (path, w, h, bytes) each, in one oiiotool run."""
    args = []
    for path, w, h, pixels in images:
        pgm = Path(str(path) + ".pgm")
        pgm.write_bytes(b"P5\n%d %d\n255\n" % (w, h) + bytes(pixels))
        args += [pgm, "-d", "uint8", "-o", path]
    oiiotool(*args)
    for path, *_ in images:
        Path(str(path) + ".pgm").unlink()


@dataclass
class Source:
    """A picture, optionally resized first (WxH), in grey."""
    path: Path
    resize: str = None
    pixels: tuple = field(default=None, repr=False)  # (w, h, bytes), read once

    def grey(self, tmp):
        if self.pixels is None:
            info = subprocess.run(["oiiotool", "--info", self.path], capture_output=True, text=True,
                                  check=True).stdout
            args = [self.path] + (["--resize", self.resize] if self.resize else [])
            if " 1 channel" not in info:
                args += ["--ch", "R,G,B", "--chsum:weight=.299,.587,.114"]
            pgm = Path(tmp) / f"source-{abs(hash((str(self.path), self.resize)))}.pgm"
            oiiotool(*args, "-d", "uint8", "-o", pgm)
            w, h, _, px = read_pnm(pgm)
            self.pixels = (w, h, px)
            pgm.unlink()
        return self.pixels

    def crop(self, box, tmp):
        """The crop WxH+X+Y: (w, h, bytes)."""
        size, x, y = box.split("+")
        cw, ch = map(int, size.split("x"))
        x, y = int(x), int(y)
        w, h, px = self.grey(tmp)
        assert x + cw <= w and y + ch <= h, f"{box} is outside {self.path} ({w}x{h})"
        return cw, ch, b"".join(px[(y + j) * w + x:(y + j) * w + x + cw] for j in range(ch))


@dataclass
class TextureClass:
    name: str
    label: int
    source: Source
    train: str    # crop WxH+X+Y of the training image
    collage: str  # crop WxH+X+Y the collage's shapes of this class read


# Shapes on a size x size collage, in fractions of the size: each a test
# of (x, y) and its bounding box (x0, y0, x1, y1), fractions too.
def disk(cx, cy, r):
    return (lambda x, y: (x - cx) ** 2 + (y - cy) ** 2 <= r * r), (cx - r, cy - r, cx + r, cy + r)


def triangle(a, b, c):
    def inside(x, y):
        def side(p, q):
            return (q[0] - p[0]) * (y - p[1]) - (q[1] - p[1]) * (x - p[0])
        s = (side(a, b), side(b, c), side(c, a))
        return all(v >= 0 for v in s) or all(v <= 0 for v in s)
    xs, ys = (a[0], b[0], c[0]), (a[1], b[1], c[1])
    return inside, (min(xs), min(ys), max(xs), max(ys))


def ell(x0, y0, x1, y1, thick):
    """An L: the left bar and the bottom bar of the box, thick wide."""
    return (lambda x, y: x0 <= x < x1 and y0 <= y < y1 and (x < x0 + thick or y >= y1 - thick)), (x0, y0, x1, y1)


def band(x0, y0, x1, y1):
    return (lambda x, y: x0 <= x < x1 and y0 <= y < y1), (x0, y0, x1, y1)


def build(classes, layout, size, out):
    """Writes into out: train{k}.png and labels{k}.png per class k (the
    label raster holds the class's label everywhere), input.png and
    truth.png (size x size). layout: the background class's index, then
    (class index, shape) pairs, later shapes drawn over earlier ones.
    Returns the paths: {"train": [...], "labels": [...], "input", "truth"}."""
    out = Path(out)
    paths = {"train": [], "labels": []}
    pngs, textures = [], []
    for k, c in enumerate(classes):
        w, h, px = c.source.crop(c.train, out)
        pngs += [(out / f"train{k}.png", w, h, px), (out / f"labels{k}.png", w, h, bytes([c.label]) * (w * h))]
        paths["train"].append(out / f"train{k}.png")
        paths["labels"].append(out / f"labels{k}.png")
        textures.append(c.source.crop(c.collage, out))
    background, shapes = layout[0], layout[1:]
    img, truth = bytearray(size * size), bytearray(size * size)
    for y in range(size):
        for x in range(size):
            k, ox, oy = background, x, y
            for cls, (inside, box) in shapes:
                if inside((x + 0.5) / size, (y + 0.5) / size):
                    k, ox, oy = cls, x - int(box[0] * size), y - int(box[1] * size)
            tw, th, tpx = textures[k]
            assert 0 <= ox < tw and 0 <= oy < th, f"class {classes[k].name}: its collage crop is too small for its shape"
            img[y * size + x] = tpx[oy * tw + ox]
            truth[y * size + x] = classes[k].label
    pngs += [(out / "input.png", size, size, img), (out / "truth.png", size, size, truth)]
    write_pngs(pngs)
    paths["input"], paths["truth"] = out / "input.png", out / "truth.png"
    return paths
