/* image.h - image files in and out. Decoding and encoding go through
 * OpenImageIO in image_oiio.cpp (the only C++ in texsyn), after the checks
 * of image_check.c, with GeoTIFF tags by tiff_tags.c; this header is their
 * C API, plus pixel helpers in image.c. The file functions live in a
 * shared library of their own, libtexsyn-image.so, loaded on the first
 * call (image_lib.h says why and how); if it cannot be loaded they return
 * TS_ENOTSUP, naming the path tried and the loader's reason.
 *
 * An image keeps the pixel type it had on disk where it matters (8-bit,
 * 16-bit, half and float), so a 16-bit TIFF in gives a 16-bit TIFF out, and
 * carries the file's metadata (GeoTIFF georeferencing, resolution, ICC
 * profile, ...) so outputs derived from one input can pass it through. */
#ifndef TS_IMAGE_H
#define TS_IMAGE_H

#include <stddef.h>
#include <stdint.h>

typedef enum {
  TS_PIX_U8 = 0, /* uint8 */
  TS_PIX_U16,    /* uint16 */
  TS_PIX_F16,    /* IEEE half, stored as its raw uint16 bits */
  TS_PIX_F32     /* float */
} ts_pixtype;

typedef struct ts_meta ts_meta; /* opaque: the source file's metadata */

typedef struct {
  int width, height, channels;
  ts_pixtype type;
  void *pixels;  /* width*height*channels samples, interleaved, row-major */
  ts_meta *meta; /* NULL, or metadata read from the file */
} ts_image;

typedef struct {
  uint64_t max_pixels; /* width*height limit; refuse larger headers (0: default) */
  const char *option;  /* how to raise it, named in the message; NULL: "--max-pixels" */
} ts_image_limits;

/* What a header says, without the pixels. */
typedef struct {
  int width, height, channels;
  ts_pixtype type; /* the type ts_image_read would keep */
} ts_image_info;

#define TS_IMAGE_DEFAULT_MAX_PIXELS (256ull * 1024 * 1024)

size_t ts_pixtype_size(ts_pixtype t);
const char *ts_pixtype_name(ts_pixtype t);

/* Allocates a zeroed image (no metadata). 0, TS_EINVAL or TS_ENOMEM. */
int ts_image_alloc(ts_image *img, int width, int height, int channels,
                   ts_pixtype type, char *err);
void ts_image_free(ts_image *img);

/* Loads libtexsyn-image.so now rather than at the first image call; any
 * later call then costs no loading. Idempotent and thread-safe: the
 * library is loaded once per process and never unloaded. 0, or TS_ENOTSUP
 * with a message naming the paths tried and why they failed (set
 * TEXSYN_IMAGE_LIB to the library's path to override the search). */
int ts_image_lib_load(char *err);

/* Reads PNG, JPEG, TIFF (incl. tiled and BigTIFF) and OpenEXR files. The
 * format is told by the file's first bytes, never by its name, and only
 * these four decoders are ever reached: a daemon reads references from the
 * network, and OpenImageIO's other readers (video, DICOM, camera raw, ...)
 * are no surface to offer. Other sample types are converted to the nearest
 * kept type (e.g. int8 and uint32 -> float). limits may be NULL for the
 * defaults. The header is checked (size against limits, channels, no
 * volume or deep data, tile size) before any pixel memory is taken. Errors
 * name the file and the reason: TS_ENOENT, TS_EFORMAT (empty, not one of
 * the four formats, unreadable or truncated), TS_ETOOBIG (over limits,
 * naming the size, the limit and limits->option), TS_ENOMEM. */
int ts_image_read(const char *path, ts_image *img,
                  const ts_image_limits *limits, char *err);

/* ts_image_read on a file's bytes held in memory (len bytes at data, not
 * copied); name is what messages call it (e.g. a client's file name). Same
 * checks, same code path, same results as reading those bytes from a
 * file. */
int ts_image_read_mem(const char *name, const void *data, size_t len,
                      ts_image *img, const ts_image_limits *limits,
                      char *err);

/* The checks of ts_image_read_mem up to the pixels: the format, the header
 * and the limits; no pixel is decoded, so this is cheap whatever the size
 * the header claims. info may be NULL. Same errors as ts_image_read_mem
 * (a file cut inside its pixels passes: only reading them tells). */
int ts_image_probe_mem(const char *name, const void *data, size_t len,
                       const ts_image_limits *limits, ts_image_info *info,
                       char *err);

/* Writes img to path, the format chosen from the extension. If meta_from is
 * not NULL, its metadata is passed through (the geometry and pixel type are
 * img's own). A type the format cannot store is converted by OpenImageIO
 * (e.g. float to 8-bit for PNG). Writes to a temporary name in the same
 * directory and renames, so a failed write never leaves a partial file. */
int ts_image_write(const char *path, const ts_image *img,
                   const ts_meta *meta_from, char *err);

/* --- large images by regions (tiled aerial scenes) -------------------------
 *
 * A scene too large to hold whole is read a region at a time and written a
 * band of rows at a time (server/engines/region.h builds its sources and
 * sinks on these). */

typedef struct ts_image_regions ts_image_regions; /* a file open for reading */

/* Opens path (the four formats of ts_image_read, the same sniffing and
 * header checks, limits on its size included) without decoding pixels:
 * info as the header says, except that half floats read as float (region
 * reads give U8, U16 or F32 samples); *meta (may be NULL: not wanted) the
 * file's metadata, GeoTIFF tags included, for outputs to pass on. */
int ts_image_regions_open(const char *path, const ts_image_limits *limits, ts_image_info *info, ts_meta **meta,
                          ts_image_regions **out, char *err);
/* Channel 0 of [x, x + w) x [y, y + h), which must lie in the image, into
 * dst: w * h samples of info.type, row-major. Reads whole rows (strips or
 * tiles as the file has them) and keeps none. 0, or TS_EFORMAT naming the
 * file (a truncated or damaged file), TS_EINVAL, TS_ENOMEM. */
int ts_image_regions_read(ts_image_regions *r, int x, int y, int w, int h, void *dst, char *err);
void ts_image_regions_close(ts_image_regions *r);

typedef struct ts_image_writer ts_image_writer; /* a file written by bands */

/* Starts a w x h, `channels`-channel 8-bit image at path (the format from
 * the extension, as ts_image_write), written to a temporary name until
 * ts_image_writer_finish. TIFF and OpenEXR are tiled (tile x tile, a
 * multiple of 16) and compressed (zip), a TIFF BigTIFF when its pixels
 * pass 4 GiB; PNG and JPEG are written by scanlines. meta_from: metadata
 * to pass on (as ts_image_write; GeoTIFF tags to a TIFF). */
int ts_image_writer_create(const char *path, int w, int h, int channels, int tile, const ts_meta *meta_from,
                           ts_image_writer **out, char *err);
/* Rows [y, y + h), whole width, interleaved; bands come top to bottom, each
 * once, h a multiple of the tile size but for the last one. */
int ts_image_writer_put(ts_image_writer *wr, int y, int h, const uint8_t *px, char *err);
/* Closes the file, syncs it and gives it its name; frees wr (on failure
 * too, removing the temporary file). */
int ts_image_writer_finish(ts_image_writer *wr, char *err);
/* Removes the temporary file and frees wr (NULL: nothing). */
void ts_image_writer_abort(ts_image_writer *wr);

/* --- movies (texsyn video's --input and --preview) -------------------------
 *
 * Through OpenImageIO's FFmpeg reader (Debian's OpenImageIO has it): a
 * movie's frames are its subimages, 0 the first. Only texsyn video reaches
 * these, on a file the user names on its command line: ts_image_read and
 * its kin never hand bytes to the movie reader. */
typedef struct {
  int frames; /* as the container says */
  double fps; /* 0 if it does not say */
  ts_image_info frame;
} ts_movie_info;

/* The movie's header: 0, or TS_ENOENT / TS_EFORMAT (not a movie FFmpeg
 * reads, no frames) / TS_ETOOBIG (limits) with a message naming it. */
int ts_movie_probe(const char *path, const ts_image_limits *limits, ts_movie_info *info, char *err);

/* Decodes frames first..last in order, handing each to each(ctx, frame,
 * image, err), whose non-zero return stops the reading and is returned.
 * The image is freed after the call. 0, or an error naming the frame. */
typedef int (*ts_movie_frame_fn)(void *ctx, long frame, const ts_image *img, char *err);
int ts_movie_read(const char *path, long first, long last, const ts_image_limits *limits, ts_movie_frame_fn each,
                  void *ctx, char *err);

/* Writes n images of one size and channel count as an animation (GIF):
 * frame k shown for 1/fps s, looping. 0, or TS_EINVAL / TS_EIO naming the
 * file. Written to a temporary name and renamed, as ts_image_write. */
int ts_image_write_animation(const char *path, const ts_image *frames, int n, double fps, char *err);

/* Metadata value lookup for tests and reports: writes the attribute named
 * `name` as text into out (at most outlen bytes). 0 or TS_ENOENT. */
int ts_meta_get(const ts_meta *meta, const char *name, char *out,
                size_t outlen);

/* --- pixel helpers (image.c) --------------------------------------------- */

/* Sample (x, y, c) as a float in [0, 1] for integer types, as is for float. */
float ts_image_sample(const ts_image *img, int x, int y, int c);

/* 8-bit luminance plane (BT.601 weights on the first three channels; the
 * first channel of grey or grey+alpha images). Floats are clamped to [0, 1].
 * out holds width*height bytes. */
void ts_image_luma8(const ts_image *img, uint8_t *out);
/* 8-bit plane of channel c, same conversion rules. */
void ts_image_channel8(const ts_image *img, int c, uint8_t *out);

/* dst pixel (dx, dy) = src pixel (sx, sy), all channels; dst and src must
 * have the same channels and type. */
void ts_image_copy_pixel(ts_image *dst, int dx, int dy, const ts_image *src,
                         int sx, int sy);

#endif
