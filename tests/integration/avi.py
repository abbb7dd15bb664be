"""Movies the tests can make without a video encoder (Debian's OpenImageIO
reads movies but writes none, and ffmpeg's command is not installed): an
AVI of uncompressed 24-bit frames (BI_RGB, bottom-up BGR rows padded to 4
bytes), which FFmpeg decodes losslessly, so a decoded frame can be
compared byte for byte with the pixels that went in; and a Motion JPEG
AVI of JPEG files, a compressed codec."""
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


def _write(path, chunks, w, h, fps, handler, compression, bits):
    n, size = len(chunks), max(len(c) for c in chunks)
    avih = struct.pack("<14I", 1000000 // fps, size * fps, 0, 0x10, n, 0, 1, size, w, h, 0, 0, 0, 0)
    strh = struct.pack("<4s4sIHHIIIIIIIIhhhh", b"vids", handler, 0, 0, 0, 0, 1, fps, 0, n, size, 0xFFFFFFFF, 0,
                       0, 0, w, h)
    strf = struct.pack("<IiiHHIIiiII", 40, w, h, 1, bits, compression, size, 0, 0, 0, 0)
    hdrl = _list(b"hdrl", _chunk(b"avih", avih) + _list(b"strl", _chunk(b"strh", strh) + _chunk(b"strf", strf)))
    movi = _list(b"movi", b"".join(_chunk(b"00dc", c) for c in chunks))
    index, off = b"", 4
    for c in chunks:
        index += struct.pack("<4sIII", b"00dc", 0x10, off, len(c))
        off += 8 + len(c) + len(c) % 2
    body = b"AVI " + hdrl + movi + _chunk(b"idx1", index)
    with open(path, "wb") as f:
        f.write(b"RIFF" + struct.pack("<I", len(body)) + body)


def write_avi(path, frames, w, h, fps=10):
    """frames: the RGB bytes (w * h * 3, rows top-down) of each frame."""
    _write(path, [_dib(f, w, h) for f in frames], w, h, fps, b"DIB ", 0, 24)


def write_mjpeg_avi(path, jpegs, w, h, fps=10):
    """jpegs: each frame as a JPEG file's bytes (Motion JPEG: compressed,
    decoded by FFmpeg's own JPEG decoder)."""
    _write(path, jpegs, w, h, fps, b"MJPG", struct.unpack("<I", b"MJPG")[0], 24)
