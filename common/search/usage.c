/* usage.c - see usage.h. */
#include "usage.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"

/* Pixels covered by at least one valid block: the rectangle the box of
 * anchors covers, unless a validity plane left holes in it (then counted,
 * from the anchors' index, which holds the whole box there). */
static int usable_pixels(const ts_anchors *g, int wb, uint64_t *usable) {
  *usable = (uint64_t)(g->nx + wb - 1) * (uint64_t)(g->ny + wb - 1);
  if (!g->indexed || g->total == (uint64_t)g->nx * (uint64_t)g->ny) return 0;
  int cw = g->nx + wb - 1, ch = g->ny + wb - 1;
  uint8_t *covered = calloc((size_t)cw * (size_t)ch, 1);
  if (covered == NULL) return TS_ENOMEM;
  for (int y = 0; y < g->ny; y++)
    for (int x = 0; x < g->nx; x++)
      if (ts_anchors_index(g, g->x0 + x, g->y0 + y) >= 0)
        for (int dy = 0; dy < wb; dy++) memset(covered + (size_t)(y + dy) * (size_t)cw + (size_t)x, 1, (size_t)wb);
  uint64_t n = 0;
  for (size_t i = 0; i < (size_t)cw * (size_t)ch; i++) n += covered[i];
  free(covered);
  *usable = n;
  return 0;
}

int ts_usage_init(ts_usage *u, const ts_anchors *g, int wb, int with_blocks) {
  u->grid = *g;
  u->wb = wb;
  u->total = 0;
  u->count = calloc((size_t)g->w * (size_t)g->h, sizeof(uint32_t));
  u->u = with_blocks ? calloc(g->total ? g->total : 1, sizeof(uint32_t)) : NULL;
  if (u->count == NULL || (with_blocks && u->u == NULL) || usable_pixels(g, wb, &u->usable) != 0) {
    ts_usage_free(u);
    return TS_ENOMEM;
  }
  return 0;
}

void ts_usage_free(ts_usage *u) {
  free(u->count);
  free(u->u);
  u->count = NULL;
  u->u = NULL;
}

/* Pixels [a0, a0 + an) and [b0, b0 + bn) have in common. */
static int overlap(int a0, int an, int b0, int bn) {
  int lo = a0 > b0 ? a0 : b0, hi = a0 + an < b0 + bn ? a0 + an : b0 + bn;
  return hi > lo ? hi - lo : 0;
}

/* Every valid block overlapping the copied rectangle gains delta uses per
 * pixel in common: (w + wb - 1) x (h + wb - 1) block sums for a w x h copy,
 * instead of wb^2 per copied pixel. */
void ts_usage_commit(ts_usage *u, int x, int y, int w, int h, int delta) {
  for (int dy = 0; dy < h; dy++)
    for (int dx = 0; dx < w; dx++) u->count[(long)(y + dy) * u->grid.w + x + dx] += (uint32_t)delta;
  u->total += (uint64_t)((int64_t)delta * w * h);
  if (u->u == NULL) return;
  for (int by = y - u->wb + 1; by < y + h; by++) {
    int oy = overlap(by, u->wb, y, h);
    for (int bx = x - u->wb + 1; bx < x + w; bx++) {
      int64_t j = ts_anchors_index(&u->grid, bx, by);
      if (j >= 0) u->u[j] += (uint32_t)(delta * oy * overlap(bx, u->wb, x, w));
    }
  }
}

void ts_usage_load(ts_usage *u, const uint32_t *count) {
  size_t n = (size_t)u->grid.w * (size_t)u->grid.h;
  memcpy(u->count, count, n * sizeof(uint32_t));
  u->total = 0;
  for (size_t i = 0; i < n; i++) u->total += count[i];
  ts_usage_sum_blocks(u, 0, u->grid.h);
}

void ts_usage_sum_blocks(ts_usage *u, int y0, int y1) {
  const ts_anchors *g = &u->grid;
  if (u->u == NULL) return;
  for (int by = y0 > g->y0 ? y0 : g->y0; by + u->wb <= y1 && by < g->y0 + g->ny; by++)
    for (int bx = g->x0; bx < g->x0 + g->nx; bx++) {
      int64_t j = ts_anchors_index(g, bx, by);
      if (j < 0) continue;
      uint32_t sum = 0;
      for (int dy = 0; dy < u->wb; dy++)
        for (int dx = 0; dx < u->wb; dx++) sum += u->count[(size_t)(by + dy) * (size_t)g->w + (size_t)(bx + dx)];
      u->u[j] = sum;
    }
}

uint64_t ts_usage_factor(const ts_usage *u, double alpha, uint64_t d1) {
  if (u->total == 0 || !(alpha > 0.0)) return 0;
  /* K = alpha * d1 * usable / (total * wb^2), alpha in 1/256 steps. */
  unsigned __int128 num = (unsigned __int128)(uint64_t)llround(alpha * 256.0) * d1 * u->usable;
  unsigned __int128 den = (unsigned __int128)256 * u->total * (uint64_t)(u->wb * u->wb);
  unsigned __int128 k = (num << 32) / den;
  return k > UINT64_MAX ? UINT64_MAX : (uint64_t)k;
}

void ts_usage_stats(const ts_usage *u, double *mean, double *variance) {
  const ts_anchors *g = &u->grid;
  double sum = 0.0, sum2 = 0.0;
  for (int y = g->y0; y < g->y0 + g->ny + u->wb - 1; y++)
    for (int x = g->x0; x < g->x0 + g->nx + u->wb - 1; x++) {
      double c = u->count[(long)y * g->w + x];
      sum += c;
      sum2 += c * c;
    }
  double n = (double)u->usable;
  *mean = n > 0 ? sum / n : 0.0;
  *variance = n > 0 ? sum2 / n - (*mean) * (*mean) : 0.0;
}
