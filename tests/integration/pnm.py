"""Image helpers the integration tests (and bench/segment.py, through
collage.py) share: oiiotool, and the pixels of the binary PGM/PPM files it
writes, read without PIL or numpy (neither is on the test machines)."""
import subprocess
from pathlib import Path


def oiiotool(*args):
    subprocess.run(["oiiotool", *map(str, args)], check=True, capture_output=True, timeout=120)


def read_pnm(path):
    """(width, height, channels, bytes) of a binary 8-bit PGM or PPM."""
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
    assert fields[0] in (b"P5", b"P6") and fields[3] == b"255", f"{path}: not an 8-bit binary PGM or PPM"
    w, h, ch = int(fields[1]), int(fields[2]), 1 if fields[0] == b"P5" else 3
    return w, h, ch, data[pos + 1:pos + 1 + w * h * ch]


def pixels_of(image, tmp):
    """(width, height, channels, bytes) of any image oiiotool reads, through
    a PNM it writes into tmp."""
    pnm = Path(tmp) / (Path(image).stem + ".pnm")
    oiiotool(image, "-o", pnm)
    return read_pnm(pnm)
