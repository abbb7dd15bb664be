/* region_file.c - region.h's source and sink on the image library's region
 * reader and band writer (image.h: OpenImageIO). */
#include "region.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"

typedef struct {
  ts_region_source ops;
  ts_image_regions *r;
  ts_pixtype type; /* U8, U16 or F32 */
  void *scratch;   /* the samples of the last read */
  size_t cap;      /* its bytes */
} file_source;

static int32_t value_of(ts_pixtype t, const void *px, size_t i) {
  switch (t) {
  case TS_PIX_U8: return ((const uint8_t *)px)[i];
  case TS_PIX_U16: return ((const uint16_t *)px)[i];
  default: {
    float v = ((const float *)px)[i];
    return v >= 0 && v <= TS_REGION_MAX_VALUE ? (int32_t)lrintf(v) : -1;
  }
  }
}

static int file_read(ts_region_source *s, int x, int y, int w, int h, int32_t *dst, char *err) {
  file_source *f = (file_source *)s;
  size_t n = (size_t)w * (size_t)h, bytes = n * ts_pixtype_size(f->type);
  if (bytes > f->cap) {
    free(f->scratch);
    f->cap = 0;
    if ((f->scratch = malloc(bytes)) == NULL) return ts_error(err, TS_ENOMEM, "out of memory reading a region");
    f->cap = bytes;
  }
  int rc = ts_image_regions_read(f->r, x, y, w, h, f->scratch, err);
  for (size_t i = 0; rc == 0 && i < n; i++) dst[i] = value_of(f->type, f->scratch, i);
  return rc;
}

static void file_close(ts_region_source *s) {
  file_source *f = (file_source *)s;
  ts_image_regions_close(f->r);
  free(f->scratch);
  free(f);
}

int ts_region_source_open_image(const char *path, ts_meta **meta, ts_region_source **out, char *err) {
  *out = NULL;
  file_source *f = calloc(1, sizeof(*f));
  if (f == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  ts_image_limits none = {UINT64_MAX, NULL};
  ts_image_info info;
  int rc = ts_image_regions_open(path, &none, &info, meta, &f->r, err);
  if (rc != 0) {
    free(f);
    return rc;
  }
  f->type = info.type;
  f->ops = (ts_region_source){info.width, info.height, file_read, file_close, NULL};
  *out = &f->ops;
  return 0;
}

typedef struct {
  ts_tile_sink ops;
  ts_image_writer *wr;
} file_sink;

static int sink_put(ts_tile_sink *s, int x, int y, int w, int h, const uint8_t *rgb, char *err) {
  (void)x, (void)w; /* whole-width bands (region.h) */
  return ts_image_writer_put(((file_sink *)s)->wr, y, h, rgb, err);
}

static int sink_finish(ts_tile_sink *s, char *err) {
  int rc = ts_image_writer_finish(((file_sink *)s)->wr, err);
  free(s);
  return rc;
}

static void sink_abort(ts_tile_sink *s) {
  if (s == NULL) return;
  ts_image_writer_abort(((file_sink *)s)->wr);
  free(s);
}

int ts_tile_sink_open_image(const char *path, int w, int h, int tile, const ts_meta *meta_from, ts_tile_sink **out,
                            char *err) {
  *out = NULL;
  file_sink *f = calloc(1, sizeof(*f));
  if (f == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  int rc = ts_image_writer_create(path, w, h, 3, tile, meta_from, &f->wr, err);
  if (rc != 0) {
    free(f);
    return rc;
  }
  f->ops = (ts_tile_sink){sink_put, sink_finish, sink_abort};
  *out = &f->ops;
  return 0;
}
