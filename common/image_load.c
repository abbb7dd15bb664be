/* image_load.c - image.h's file functions in the programs: each loads
 * libtexsyn-image.so on first use and forwards through its table (see
 * image_lib.h for why the image code is a library of its own, dl_lib.h for
 * where it is looked for and how it is loaded). */
#include "image_lib.h"

#include <string.h>

#include "dl_lib.h"
#include "error.h"
#include "image_meta.h"

static ts_dl_lib image_lib = {TS_IMAGE_LIB_NAME, TS_IMAGE_LIB_ENV, TS_IMAGE_LIB_TABLE_NAME, "image library"};
/* The table, valid once ts_image_lib_load returned 0. */
#define ts_lib ((const ts_image_lib *)image_lib.table)

int ts_image_lib_load(char *err) { return ts_dl_lib_load(&image_lib, err); }

/* --- image.h's file functions, forwarded -------------------------------- */

int ts_image_read(const char *path, ts_image *img, const ts_image_limits *limits, char *err) {
  if (img != NULL) memset(img, 0, sizeof(*img)); /* freeable even if nothing loads */
  int rc = ts_image_lib_load(err);
  return rc != 0 ? rc : ts_lib->read(path, img, limits, err);
}

int ts_image_read_mem(const char *name, const void *data, size_t len, ts_image *img,
                      const ts_image_limits *limits, char *err) {
  if (img != NULL) memset(img, 0, sizeof(*img));
  int rc = ts_image_lib_load(err);
  return rc != 0 ? rc : ts_lib->read_mem(name, data, len, img, limits, err);
}

int ts_image_probe_mem(const char *name, const void *data, size_t len,
                       const ts_image_limits *limits, ts_image_info *info, char *err) {
  int rc = ts_image_lib_load(err);
  return rc != 0 ? rc : ts_lib->probe_mem(name, data, len, limits, info, err);
}

int ts_image_write(const char *path, const ts_image *img, const ts_meta *meta_from, char *err) {
  int rc = ts_image_lib_load(err);
  return rc != 0 ? rc : ts_lib->write(path, img, meta_from, err);
}

int ts_movie_probe(const char *path, const ts_image_limits *limits, ts_movie_info *info, char *err) {
  int rc = ts_image_lib_load(err);
  return rc != 0 ? rc : ts_lib->movie_probe(path, limits, info, err);
}

int ts_movie_read(const char *path, long first, long last, const ts_image_limits *limits, ts_movie_frame_fn each,
                  void *ctx, char *err) {
  int rc = ts_image_lib_load(err);
  return rc != 0 ? rc : ts_lib->movie_read(path, first, last, limits, each, ctx, err);
}

int ts_image_write_animation(const char *path, const ts_image *frames, int n, double fps, char *err) {
  int rc = ts_image_lib_load(err);
  return rc != 0 ? rc : ts_lib->write_animation(path, frames, n, fps, err);
}

int ts_image_regions_open(const char *path, const ts_image_limits *limits, ts_image_info *info, ts_meta **meta,
                          ts_image_regions **out, char *err) {
  *out = NULL;
  if (meta != NULL) *meta = NULL;
  int rc = ts_image_lib_load(err);
  return rc != 0 ? rc : ts_lib->regions_open(path, limits, info, meta, out, err);
}

/* A reader or writer exists only if the library loaded. */
int ts_image_regions_read(ts_image_regions *r, int x, int y, int w, int h, void *dst, char *err) {
  return ts_lib->regions_read(r, x, y, w, h, dst, err);
}

void ts_image_regions_close(ts_image_regions *r) {
  if (r != NULL) ts_lib->regions_close(r);
}

int ts_image_writer_create(const char *path, int w, int h, int channels, int tile, const ts_meta *meta_from,
                           ts_image_writer **out, char *err) {
  *out = NULL;
  int rc = ts_image_lib_load(err);
  return rc != 0 ? rc : ts_lib->writer_create(path, w, h, channels, tile, meta_from, out, err);
}

int ts_image_writer_put(ts_image_writer *wr, int y, int h, const uint8_t *px, char *err) {
  return ts_lib->writer_put(wr, y, h, px, err);
}

int ts_image_writer_finish(ts_image_writer *wr, char *err) { return ts_lib->writer_finish(wr, err); }

void ts_image_writer_abort(ts_image_writer *wr) {
  if (wr != NULL) ts_lib->writer_abort(wr);
}

/* Metadata only ever comes from the library: with some at hand it is
 * loaded; with none there is nothing to look up or free, and nothing is
 * loaded (every ts_image_free of an image without metadata lands in
 * ts_meta_free). */
int ts_meta_get(const ts_meta *meta, const char *name, char *out, size_t outlen) {
  if (meta == NULL || ts_image_lib_load(NULL) != 0) return TS_ENOENT;
  return ts_lib->meta_get(meta, name, out, outlen);
}

void ts_meta_free(ts_meta *meta) {
  if (meta != NULL && ts_image_lib_load(NULL) == 0) ts_lib->meta_free(meta);
}

int ts_meta_set(ts_meta **meta, const char *name, const char *value) {
  int rc = ts_image_lib_load(NULL);
  return rc != 0 ? rc : ts_lib->meta_set(meta, name, value);
}

int ts_meta_copy(const ts_meta *from, ts_meta **to) {
  int rc = ts_image_lib_load(NULL);
  return rc != 0 ? rc : ts_lib->meta_copy(from, to);
}
