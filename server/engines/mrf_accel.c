/* mrf_accel.c - see mrf_accel.h. */
#include "mrf_accel.h"

#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "replica.h"

/* The offset (source - position) of coarse pixel (x, y), given unwrapped:
 * a neighbour across the torus seam is read at its wrapped place but
 * compared at its unwrapped one, so a region continues across the seam
 * only if its source does. */
static void offset_at(const uint32_t *prev, int pw, int ph, int x, int y, long *ox, long *oy) {
  int wx = ((x % pw) + pw) % pw, wy = ((y % ph) + ph) % ph;
  size_t o = (size_t)wy * (size_t)pw + (size_t)wx;
  *ox = (long)prev[2 * o] - x;
  *oy = (long)prev[2 * o + 1] - y;
}

/* 1 where every pixel of the n x n kernel around a coarse pixel shares
 * its offset. */
static uint8_t *coherent_map(const uint32_t *prev, int pw, int ph, int n) {
  uint8_t *c = malloc((size_t)pw * (size_t)ph);
  if (c == NULL) return NULL;
  int r = n / 2;
  for (int y = 0; y < ph; y++)
    for (int x = 0; x < pw; x++) {
      long ox, oy;
      offset_at(prev, pw, ph, x, y, &ox, &oy);
      int same = 1;
      for (int dy = -r; same && dy <= r; dy++)
        for (int dx = -r; same && dx <= r; dx++) {
          long qx, qy;
          offset_at(prev, pw, ph, x + dx, y + dy, &qx, &qy);
          same = qx == ox && qy == oy;
        }
      c[(size_t)y * (size_t)pw + (size_t)x] = (uint8_t)same;
    }
  return c;
}

typedef struct {
  const uint32_t *prev;
  const uint8_t *coherent;
  int pw, ph, w, h, rw, rh;
} level_pair;

/* Whether the bw x bh block at (bx, by) is a candidate: every coarse pixel
 * under it coherent, and its predicted sources one reference block from
 * (*sx, *sy) (the same mapping as ts_copy_predict). */
static int block_candidate(const level_pair *lp, int bx, int by, int bw, int bh, int *sx, int *sy) {
  ts_copy_predict(lp->prev, lp->pw, lp->ph, lp->w, lp->h, lp->rw, lp->rh, bx, by, sx, sy);
  for (int dy = 0; dy < bh; dy++)
    for (int dx = 0; dx < bw; dx++) {
      int x = bx + dx, y = by + dy;
      long cx = (long)x * lp->pw / lp->w, cy = (long)y * lp->ph / lp->h;
      if (!lp->coherent[cy * lp->pw + cx]) return 0;
      int px, py;
      ts_copy_predict(lp->prev, lp->pw, lp->ph, lp->w, lp->h, lp->rw, lp->rh, x, y, &px, &py);
      if (px != *sx + dx || py != *sy + dy) return 0;
    }
  return 1;
}

/* Whether (sx, sy) is a reference vector of the block's class. */
static int anchor_of_class(const ts_anchors *grid, int parity, int bx, int by, int sx, int sy) {
  int64_t g = ts_anchors_index(grid, sx, sy);
  if (g < 0) return 0;
  int klass = parity ? ((bx & 1) | (by & 1) << 1) : 0;
  return ts_anchors_class(grid, (uint32_t)g) == klass;
}

int ts_accel_map_build(ts_accel_map *m, const uint32_t *prev, int pw, int ph, int w, int h, int wb, int n,
                       int rw, int rh, const ts_anchors *grid, int parity) {
  memset(m, 0, sizeof(*m));
  m->wb = wb;
  m->rows = (h + wb - 1) / wb;
  m->cols = (w + wb - 1) / wb;
  size_t nb = (size_t)m->rows * (size_t)m->cols;
  m->what = calloc(nb, 1);
  m->src = malloc(sizeof(int32_t) * 2 * nb);
  uint8_t *coherent = coherent_map(prev, pw, ph, n);
  if (m->what == NULL || m->src == NULL || coherent == NULL) {
    free(coherent);
    ts_accel_map_free(m);
    return TS_ENOMEM;
  }
  level_pair lp = {prev, coherent, pw, ph, w, h, rw, rh};
  for (int r = 0; r < m->rows; r++)
    for (int c = 0; c < m->cols; c++) {
      int bx = c * wb, by = r * wb, bw = w - bx < wb ? w - bx : wb, bh = h - by < wb ? h - by : wb;
      int sx, sy;
      size_t i = (size_t)r * (size_t)m->cols + (size_t)c;
      if (!block_candidate(&lp, bx, by, bw, bh, &sx, &sy) || !anchor_of_class(grid, parity, bx, by, sx, sy))
        continue;
      m->what[i] = TS_ACCEL_MEASURE;
      m->src[2 * i] = sx;
      m->src[2 * i + 1] = sy;
      m->candidates++;
    }
  free(coherent);
  return 0;
}

void ts_accel_map_free(ts_accel_map *m) {
  free(m->what);
  free(m->src);
  memset(m, 0, sizeof(*m));
}

void ts_accel_map_enable(ts_accel_map *m, uint32_t every) {
  uint32_t rank = 0;
  for (size_t i = 0; i < (size_t)m->rows * (size_t)m->cols; i++)
    if (m->what[i] != TS_ACCEL_SEARCH && rank++ % every != 0) m->what[i] = TS_ACCEL_COPY;
}

int ts_accel_block(const ts_accel_map *m, int bx, int by, int what, int *sx, int *sy) {
  if (m->what == NULL) return 0;
  size_t i = (size_t)(by / m->wb) * (size_t)m->cols + (size_t)(bx / m->wb);
  if (m->what[i] != what) return 0;
  *sx = m->src[2 * i];
  *sy = m->src[2 * i + 1];
  return 1;
}

void ts_accel_constancy(const ts_accel_map *m, const uint32_t *copy, int w, uint64_t *measured, uint64_t *kept) {
  *measured = *kept = 0;
  for (int r = 0; r < m->rows; r++)
    for (int c = 0; c < m->cols; c++) {
      size_t i = (size_t)r * (size_t)m->cols + (size_t)c;
      if (m->what[i] != TS_ACCEL_MEASURE) continue;
      size_t o = (size_t)r * (size_t)m->wb * (size_t)w + (size_t)c * (size_t)m->wb;
      (*measured)++;
      *kept += copy[2 * o] == (uint32_t)m->src[2 * i] && copy[2 * o + 1] == (uint32_t)m->src[2 * i + 1];
    }
}
