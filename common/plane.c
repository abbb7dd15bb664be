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

int ts_plane_parity(ts_plane *p, int w, int h) {
  if (ts_plane_alloc(p, w, h) != 0) return TS_ENOMEM;
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) p->px[(size_t)y * (size_t)w + (size_t)x] = (uint8_t)ts_parity_class(x, y);
  return 0;
}

void ts_plane_free(ts_plane *p) {
  free(p->px);
  p->px = NULL;
  p->w = p->h = 0;
}

static const int kTaps[5] = {1, 5, 8, 5, 1}; /* sum 20 */

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
      for (int i = -2; i <= 2; i++) acc += kTaps[i + 2] * s[ts_plane_mirror(2 * x + i, src->w)];
      rows[(long)y * w + x] = acc;
    }
  }
  for (int y = 0; y < h; y++) {
    for (int x = 0; x < w; x++) {
      uint32_t acc = 0;
      for (int j = -2; j <= 2; j++) acc += kTaps[j + 2] * rows[(long)ts_plane_mirror(2 * y + j, src->h) * w + x];
      dst->px[(long)y * w + x] = (uint8_t)((acc + 200) / 400);
    }
  }
  free(rows);
  return 0;
}

/* Horizontal pass of the masked reduction: per source row and output
 * column, the weighted sum of the defined taps and their weight. */
static void masked_rows(const ts_plane *src, const ts_plane *mask, int w, uint32_t *val, uint32_t *wt) {
  for (int y = 0; y < src->h; y++) {
    const uint8_t *s = src->px + (long)y * src->w, *m = mask->px + (long)y * src->w;
    for (int x = 0; x < w; x++) {
      uint32_t acc = 0, sum = 0;
      for (int i = -2; i <= 2; i++) {
        int sx = ts_plane_mirror(2 * x + i, src->w);
        uint32_t k = m[sx] ? (uint32_t)kTaps[i + 2] : 0;
        acc += k * s[sx];
        sum += k;
      }
      val[(long)y * w + x] = acc;
      wt[(long)y * w + x] = sum;
    }
  }
}

int ts_plane_reduce_masked(const ts_plane *src, const ts_plane *mask, int ceil_size, ts_plane *dst) {
  int w = ceil_size ? (src->w + 1) / 2 : src->w / 2, h = ceil_size ? (src->h + 1) / 2 : src->h / 2;
  int rc = ts_plane_alloc(dst, w, h);
  if (rc != 0) return rc;
  uint32_t *val = malloc(sizeof(uint32_t) * (size_t)w * (size_t)src->h);
  uint32_t *wt = malloc(sizeof(uint32_t) * (size_t)w * (size_t)src->h);
  if (val == NULL || wt == NULL) {
    free(val);
    free(wt);
    ts_plane_free(dst);
    return TS_ENOMEM;
  }
  masked_rows(src, mask, w, val, wt);
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      uint64_t acc = 0, sum = 0;
      for (int j = -2; j <= 2; j++) {
        long o = (long)ts_plane_mirror(2 * y + j, src->h) * w + x;
        acc += (uint64_t)kTaps[j + 2] * val[o];
        sum += (uint64_t)kTaps[j + 2] * wt[o];
      }
      dst->px[(long)y * w + x] = sum ? (uint8_t)((acc + sum / 2) / sum) : 0;
    }
  free(val);
  free(wt);
  return 0;
}

int ts_plane_reduce_all(const ts_plane *mask, int ceil_size, ts_plane *dst) {
  int w = ceil_size ? (mask->w + 1) / 2 : mask->w / 2, h = ceil_size ? (mask->h + 1) / 2 : mask->h / 2;
  int rc = ts_plane_alloc(dst, w, h);
  if (rc != 0) return rc;
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      int all = 1;
      for (int j = 0; j < 2 && 2 * y + j < mask->h; j++)
        for (int i = 0; i < 2 && 2 * x + i < mask->w; i++) all &= ts_plane_at(mask, 2 * x + i, 2 * y + j) != 0;
      dst->px[(long)y * w + x] = (uint8_t)all;
    }
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
