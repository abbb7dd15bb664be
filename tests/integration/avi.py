"""A movie the tests can make without an encoder: an AVI of uncompressed
24-bit frames (BI_RGB, bottom-up BGR rows padded to 4 bytes), which
FFmpeg decodes losslessly, so a decoded frame can be compared byte for
byte with the pixels that went in."""
import struct


def _chunk(tag, data):
    return tag + struct.pack("<I", len(data)) + data + (b"\0" if len(data) % 2 else b"")


def _list(kind, data):
    return _chunk(b"LIST", kind + data)


def _dib(rgb, w, h):
    """Top-down RGB rows as bottom-up BGR rows, each padded to 4 bytes."""
    pad = b"\0" * (((w * 3 + 3) & ~3) - w * 3)
    rows = []
    for y in range(h - 1, -1, -1):
        row = rgb[y * w * 3:(y + 1) * w * 3]
        bgr = bytearray(len(row))
        bgr[0::3], bgr[1::3], bgr[2::3] = row[2::3], row[1::3], row[0::3]
        rows.append(bytes(bgr) + pad)
    return b"".join(rows)


def write_avi(path, frames, w, h, fps=10):
    """frames: the RGB bytes (w * h * 3, rows top-down) of each frame."""
    size = ((w * 3 + 3) & ~3) * h
    n = len(frames)
    avih = struct.pack("<14I", 1000000 // fps, size * fps, 0, 0x10, n, 0, 1, size, w, h, 0, 0, 0, 0)
    strh = struct.pack("<4s4sIHHIIIIIIIIhhhh", b"vids", b"DIB ", 0, 0, 0, 0, 1, fps, 0, n, size, 0xFFFFFFFF, 0,
                       0, 0, w, h)
    strf = struct.pack("<IiiHHIIiiII", 40, w, h, 1, 24, 0, size, 0, 0, 0, 0)
    hdrl = _list(b"hdrl", _chunk(b"avih", avih) + _list(b"strl", _chunk(b"strh", strh) + _chunk(b"strf", strf)))
    movi = _list(b"movi", b"".join(_chunk(b"00db", _dib(f, w, h)) for f in frames))
    index = b"".join(struct.pack("<4sIII", b"00db", 0x10, 4 + k * (8 + size + size % 2), size) for k in range(n))
    body = b"AVI " + hdrl + movi + _chunk(b"idx1", index)
    with open(path, "wb") as f:
        f.write(b"RIFF" + struct.pack("<I", len(body)) + body)
