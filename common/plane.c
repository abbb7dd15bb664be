/* plane.c - see plane.h. */
#include "plane.h"

#include <stdlib.h>
#include <string.h>

#include "error.h"

int ts_plane_alloc(ts_plane *p, int w, int h) {
  p->w = w;
  p->h = h;
  p->px = NULL;
  if (w <= 0 || h <= 0) return TS_EINVAL;
  p->px = calloc((size_t)w * (size_t)h, 1);
  return p->px != NULL ? 0 : TS_ENOMEM;
}

void ts_plane_free(ts_plane *p) {
  free(p->px);
  p->px = NULL;
  p->w = p->h = 0;
}

static const int kTaps[5] = {1, 5, 8, 5, 1}; /* sum 20 */

/* Mirror an index into [0, n) without repeating the edge sample. */
static int mirror(int i, int n) {
  if (n == 1) return 0;
  while (i < 0 || i >= n) {
    if (i < 0) i = -i;
    if (i >= n) i = 2 * (n - 1) - i;
  }
  return i;
}

int ts_plane_reduce(const ts_plane *src, ts_plane *dst) {
  int w = src->w / 2, h = src->h / 2;
  int rc = ts_plane_alloc(dst, w, h);
  if (rc != 0) return rc;
  /* Horizontal pass at even columns into 32-bit rows, then vertical. */
  uint32_t *rows = malloc(sizeof(uint32_t) * (size_t)w * (size_t)src->h);
  if (rows == NULL) {
    ts_plane_free(dst);
    return TS_ENOMEM;
  }
  for (int y = 0; y < src->h; y++) {
    const uint8_t *s = src->px + (long)y * src->w;
    for (int x = 0; x < w; x++) {
      uint32_t acc = 0;
      for (int i = -2; i <= 2; i++) acc += kTaps[i + 2] * s[mirror(2 * x + i, src->w)];
      rows[(long)y * w + x] = acc;
    }
  }
  for (int y = 0; y < h; y++) {
    for (int x = 0; x < w; x++) {
      uint32_t acc = 0;
      for (int j = -2; j <= 2; j++) acc += kTaps[j + 2] * rows[(long)mirror(2 * y + j, src->h) * w + x];
      dst->px[(long)y * w + x] = (uint8_t)((acc + 200) / 400);
    }
  }
  free(rows);
  return 0;
}

int ts_pyramid_build(const ts_plane *base, int nlevels, ts_plane *levels) {
  for (int l = 0; l < nlevels; l++) levels[l].px = NULL;
  int rc = ts_plane_alloc(&levels[0], base->w, base->h);
  if (rc != 0) return rc;
  memcpy(levels[0].px, base->px, (size_t)base->w * base->h);
  for (int l = 1; l < nlevels; l++) {
    if (levels[l - 1].w < 2 || levels[l - 1].h < 2) rc = TS_EINVAL;
    else rc = ts_plane_reduce(&levels[l - 1], &levels[l]);
    if (rc != 0) {
      ts_pyramid_free(levels, l);
      return rc;
    }
  }
  return 0;
}

void ts_pyramid_free(ts_plane *levels, int nlevels) {
  for (int l = 0; l < nlevels; l++) ts_plane_free(&levels[l]);
}
