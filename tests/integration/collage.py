"""Texture collages with a known truth, for `texsyn segment` (the test
test_segment.py and the benchmark bench/segment.py).

A class is a grey texture: one crop of a picture for training, another,
disjoint crop for the collage. The collage is drawn pixel by pixel from
shapes (a disk, a triangle, an L, a band: not quadrants), each filled with
its class's texture (the texture's pixel at the pixel's offset in the
shape's bounding box, so a small source fills a shape as large as itself),
and the truth raster is drawn the same way. oiiotool crops, converts to
grey and writes PNG; the pixels pass through binary PGM, which Python
reads and writes without numpy.
"""
import subprocess
from dataclasses import dataclass
from pathlib import Path


def oiiotool(*args):
    subprocess.run(["oiiotool", *map(str, args)], check=True, capture_output=True, timeout=120)


def read_pgm(path):
    """(width, height, bytes) of a binary 8-bit PGM."""
    data = Path(path).read_bytes()
    fields, pos = [], 0
    while len(fields) < 4:
        while data[pos:pos + 1].isspace():
            pos += 1
        end = pos
        while not data[end:end + 1].isspace():
            end += 1
        fields.append(data[pos:end])
        pos = end
    assert fields[0] == b"P5" and fields[3] == b"255", f"{path}: not an 8-bit binary PGM"
    w, h = int(fields[1]), int(fields[2])
    return w, h, data[pos + 1:pos + 1 + w * h]


def write_png(path, w, h, pixels):
    """An 8-bit grey PNG of w x h bytes (through a PGM beside it)."""
    pgm = Path(str(path) + ".pgm")
    pgm.write_bytes(b"P5\n%d %d\n255\n" % (w, h) + bytes(pixels))
    oiiotool(pgm, "-d", "uint8", "-o", path)
    pgm.unlink()


@dataclass
class Source:
    """A picture, optionally resized first (WxH), cut to grey crops."""
    path: Path
    resize: str = None

    def grey(self, crop, out):
        """The crop WxH+X+Y as grey bytes: (w, h, bytes)."""
        args = [self.path]
        if self.resize:
            args += ["--resize", self.resize]
        args += ["--cut", crop]
        if self.colour():
            args += ["--ch", "R,G,B", "--chsum:weight=.299,.587,.114"]
        pgm = Path(str(out) + ".pgm")
        oiiotool(*args, "-d", "uint8", "-o", pgm)
        w, h, px = read_pgm(pgm)
        pgm.unlink()
        return w, h, px

    def colour(self):
        out = subprocess.run(["oiiotool", "--info", self.path], capture_output=True, text=True, check=True).stdout
        return " 1 channel" not in out


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
    textures = []
    for k, c in enumerate(classes):
        w, h, px = c.source.grey(c.train, out / f"train{k}")
        write_png(out / f"train{k}.png", w, h, px)
        write_png(out / f"labels{k}.png", w, h, bytes([c.label]) * (w * h))
        paths["train"].append(out / f"train{k}.png")
        paths["labels"].append(out / f"labels{k}.png")
        textures.append(c.source.grey(c.collage, out / f"collage{k}"))
    background, shapes = layout[0], layout[1:]
    img, truth = bytearray(size * size), bytearray(size * size)
    for y in range(size):
        for x in range(size):
            k, ox, oy = background, x, y
            for cls, (inside, box) in shapes:
                fx, fy = (x + 0.5) / size, (y + 0.5) / size
                if inside(fx, fy):
                    k, ox, oy = cls, x - int(box[0] * size), y - int(box[1] * size)
            tw, th, tpx = textures[k]
            assert 0 <= ox < tw and 0 <= oy < th, f"class {classes[k].name}: its collage crop is too small for its shape"
            img[y * size + x] = tpx[oy * tw + ox]
            truth[y * size + x] = classes[k].label
    write_png(out / "input.png", size, size, img)
    write_png(out / "truth.png", size, size, truth)
    paths["input"], paths["truth"] = out / "input.png", out / "truth.png"
    return paths
