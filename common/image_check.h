/* image_check.h - what is checked of an image before OpenImageIO opens it:
 * that a file is there and regular, the format by the first bytes (PNG,
 * JPEG, TIFF and OpenEXR only: OpenImageIO would otherwise try every
 * plugin it has, FFmpeg, DICOM, camera raw, ..., on whatever a client
 * sends), and the sizes a PNG's chunks or an OpenEXR header claim against
 * the bytes there are (libpng and OpenEXR allocate what a header claims
 * before reading it). Plain byte parsing; the image shim (image_oiio.cpp)
 * runs these before any decoder. */
#ifndef TS_IMAGE_CHECK_H
#define TS_IMAGE_CHECK_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Where an image comes from: a file, or a file's bytes in memory.
 * Messages call it name. */
typedef struct {
  const char *name;
  const char *path; /* NULL: the bytes are data[0, len) */
  const uint8_t *data;
  size_t len;
} ts_image_src;

/* The OpenImageIO reader for src by its first bytes: "png", "jpeg",
 * "tiff" (classic or BigTIFF, either byte order) or "openexr". A file is
 * opened here first, because OpenImageIO reports a missing file, a
 * directory and a permission problem all as "could not open". 0, or
 * TS_ENOENT, TS_EIO, TS_EFORMAT (not a regular file, empty, none of the
 * four formats) with a message naming src. */
int ts_image_sniff(const ts_image_src *src, const char **format, char *err);

/* For "png" and "openexr", every chunk length or header attribute size
 * (every header of a multi-part file) checked against the bytes left, up
 * to IEND or the end of the headers; a file cut short fails as truncated.
 * Only the sizes are judged: the decoder parses the rest. Other formats
 * pass. 0, or TS_EFORMAT with a message naming src and the size at
 * fault. */
int ts_image_check_sizes(const ts_image_src *src, const char *format, char *err);

/* src as a FILE to read: the file, or fmemopen over the bytes. NULL if it
 * cannot be opened. */
FILE *ts_image_src_open(const ts_image_src *src);

#ifdef __cplusplus
}
#endif

#endif
