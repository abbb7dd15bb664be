/* outputs.c - see outputs.h. */
#include "outputs.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "error.h"
#include "image.h"
#include "neigh.h"
#include "util.h"

int ts_write_copy_map_image(const char *path, const uint32_t *map, int w, int h, int ref_w,
                            int ref_h, char *err) {
  ts_image img;
  int rc = ts_image_alloc(&img, w, h, 3, TS_PIX_U16, err);
  if (rc != 0) return rc;
  uint16_t *px = img.pixels;
  double sx = ref_w > 1 ? 65535.0 / (ref_w - 1) : 0, sy = ref_h > 1 ? 65535.0 / (ref_h - 1) : 0;
  for (long i = 0; i < (long)w * h; i++) {
    px[3 * i] = (uint16_t)(map[2 * i] * sx + 0.5);
    px[3 * i + 1] = (uint16_t)(map[2 * i + 1] * sy + 0.5);
    px[3 * i + 2] = 0;
  }
  rc = ts_image_write(path, &img, NULL, err);
  ts_image_free(&img);
  return rc;
}

/* Writes to a temporary file and renames, like ts_image_write. */
int ts_write_copy_map_raw(const char *path, const uint32_t *map, int w, int h, char *err) {
  char tmp[TS_FILE_TMP_LEN];
  FILE *f = ts_file_create(path, tmp, err);
  if (f == NULL) return TS_EIO;
  uint8_t buf[8];
  int ok = 1;
  for (long i = 0; ok && i < 2L * w * h; i++) {
    for (int b = 0; b < 4; b++) buf[b] = (uint8_t)(map[i] >> (8 * b));
    ok = fwrite(buf, 4, 1, f) == 1;
  }
  return ts_file_commit(f, tmp, path, ok, err);
}

static int has_ext(const char *path, const char *ext) {
  size_t n = strlen(path), e = strlen(ext);
  return n >= e && strcasecmp(path + n - e, ext) == 0;
}

int ts_write_usage_map(const char *path, const uint32_t *usage, int w, int h, char *err) {
  ts_image img;
  int rc = ts_image_alloc(&img, w, h, 1, TS_PIX_F32, err);
  if (rc != 0) return rc;
  int raw = has_ext(path, ".tif") || has_ext(path, ".tiff") || has_ext(path, ".exr");
  uint32_t max = 1;
  for (long i = 0; i < (long)w * h; i++)
    if (usage[i] > max) max = usage[i];
  float *px = img.pixels;
  for (long i = 0; i < (long)w * h; i++) px[i] = raw ? (float)usage[i] : (float)usage[i] / (float)max;
  rc = ts_image_write(path, &img, NULL, err);
  ts_image_free(&img);
  return rc;
}

int ts_write_float_map(const char *path, const float *map, int w, int h, char *err) {
  ts_image img;
  int rc = ts_image_alloc(&img, w, h, 1, TS_PIX_F32, err);
  if (rc != 0) return rc;
  int raw = has_ext(path, ".tif") || has_ext(path, ".tiff") || has_ext(path, ".exr");
  float max = 0;
  for (long i = 0; i < (long)w * h; i++)
    if (map[i] > max) max = map[i];
  float *px = img.pixels;
  for (long i = 0; i < (long)w * h; i++) px[i] = raw || max == 0 ? map[i] : map[i] / max;
  rc = ts_image_write(path, &img, NULL, err);
  ts_image_free(&img);
  return rc;
}
