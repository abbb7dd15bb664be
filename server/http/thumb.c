/* thumb.c - see thumb.h. */
#include "thumb.h"

#include <inttypes.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "error.h"
#include "util.h"

#define THUMB_MAX_BYTES (4u << 20) /* a 160 px PNG is far smaller */

/* One thumbnail is made at a time: decoding a large result takes its full
 * size in memory, and page loads asking for the same one at once make it
 * once (the second finds the file). */
static pthread_mutex_t g_making = PTHREAD_MUTEX_INITIALIZER;

/* dst side for a src side, the long side scaled to long_dst. */
static int scaled(int side, int long_src, int long_dst) {
  int v = (int)(((int64_t)side * long_dst + long_src / 2) / long_src);
  return v < 1 ? 1 : v;
}

int ts_thumb_scale(const ts_image *src, int max_side, ts_image *dst, char *err) {
  if (max_side < 1) return ts_error(err, TS_EINVAL, "thumbnail side %d: must be positive", max_side);
  int long_src = src->width > src->height ? src->width : src->height;
  int long_dst = long_src < max_side ? long_src : max_side;
  int w = scaled(src->width, long_src, long_dst), h = scaled(src->height, long_src, long_dst);
  /* PNG holds grey, grey+alpha, RGB or RGBA: more channels keep the first four. */
  int channels = src->channels < 4 ? src->channels : 4;
  int rc = ts_image_alloc(dst, w, h, channels, TS_PIX_U8, err);
  if (rc != 0) return rc;
  uint8_t *out = dst->pixels;
  for (int y = 0; y < h; y++) {
    int y0 = (int)((int64_t)y * src->height / h), y1 = (int)((int64_t)(y + 1) * src->height / h);
    if (y1 <= y0) y1 = y0 + 1;
    for (int x = 0; x < w; x++) {
      int x0 = (int)((int64_t)x * src->width / w), x1 = (int)((int64_t)(x + 1) * src->width / w);
      if (x1 <= x0) x1 = x0 + 1;
      for (int c = 0; c < channels; c++) {
        double sum = 0;
        for (int sy = y0; sy < y1; sy++)
          for (int sx = x0; sx < x1; sx++) sum += ts_image_sample(src, sx, sy, c);
        double v = sum / ((double)(y1 - y0) * (x1 - x0));
        v = v < 0 ? 0 : v > 1 ? 1 : v; /* float images may exceed [0, 1] */
        *out++ = (uint8_t)(v * 255 + 0.5);
      }
    }
  }
  return 0;
}

/* The result image's path among the job's files: the output "out.EXT". */
static int result_path(ts_jobs *j, uint64_t id, char *path, size_t cap, char *err) {
  char names[TS_FETCH_MAX_FILES][TS_MSG_NAME_MAX];
  char(*paths)[4096] = malloc(sizeof(char[TS_FETCH_MAX_FILES][4096]));
  if (paths == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  uint32_t n;
  int rc = ts_jobs_files(j, id, names, paths, &n, err);
  int found = 0;
  for (uint32_t i = 0; rc == 0 && i < n && !found; i++)
    if (strncmp(names[i], "out.", 4) == 0) {
      snprintf(path, cap, "%s", paths[i]);
      found = 1;
    }
  free(paths);
  if (rc == 0 && !found) rc = ts_error(err, TS_ENOENT, "job %" PRIu64 " has no result image", id);
  return rc;
}

static int make_thumb(const char *from, const char *to, int side, char *err) {
  ts_image img, small;
  int rc = ts_image_read(from, &img, NULL, err);
  if (rc != 0) return rc;
  rc = ts_thumb_scale(&img, side, &small, err);
  ts_image_free(&img);
  if (rc != 0) return rc;
  rc = ts_image_write(to, &small, NULL, err);
  ts_image_free(&small);
  return rc;
}

/* The thumbnail's source: the job's preview when it has one (a running
 * job's growing picture; a done tiled scene's, far cheaper than its
 * result), else its result image. *growing: it may still change. */
static int source_path(ts_jobs *j, uint64_t id, char *path, size_t cap, int *growing, char *err) {
  int running = 0;
  *growing = 0;
  if (ts_jobs_preview(j, id, path, cap, &running, err) == 0) {
    *growing = running;
    return 0;
  }
  return result_path(j, id, path, cap, err);
}

int ts_thumb_get(ts_jobs *j, uint64_t id, const char *name, int side, uint8_t **png, size_t *len, int *growing,
                 char *err) {
  char from[4096], to[4096 + 64];
  int rc = source_path(j, id, from, sizeof(from), growing, err);
  if (rc != 0) return rc;
  const char *slash = strrchr(from, '/');
  int dir_len = slash != NULL ? (int)(slash - from) : 1;
  /* A growing one is made afresh each time, under a name of its own. */
  snprintf(to, sizeof(to), "%.*s/%s%s", dir_len, slash != NULL ? from : ".", *growing ? "live-" : "", name);
  pthread_mutex_lock(&g_making);
  if (*growing || access(to, F_OK) != 0) rc = make_thumb(from, to, side, err);
  if (rc == 0) rc = ts_file_read(to, THUMB_MAX_BYTES, png, len, err);
  pthread_mutex_unlock(&g_making);
  return rc;
}
