/* schedule.c - see schedule.h. */
#include "schedule.h"

#include <stdlib.h>
#include <string.h>

#include "error.h"

#define MAX_SPAN 64 /* block rows/cols a window can touch (W_N <= 41) */

static int ceil_div(int a, int b) { return (a + b - 1) / b; }

static ts_block block_at(const ts_schedule *s, int r, int c) {
  ts_block b;
  b.x = c * s->wb;
  b.y = r * s->wb;
  b.w = (uint16_t)(b.x + s->wb <= s->width ? s->wb : s->width - b.x);
  b.h = (uint16_t)(b.y + s->wb <= s->height ? s->wb : s->height - b.y);
  return b;
}

/* Distinct block indices (rows or cols) touched by pixels [lo, hi) on a
 * torus of size n; returns how many were written to out. */
static int span_blocks(int lo, int hi, int n, int wb, int *out) {
  int k = 0;
  for (int p = lo; p < hi && k < MAX_SPAN; p++) {
    int q = ((p % n) + n) % n;
    int b = q / wb;
    int seen = 0;
    for (int i = 0; i < k; i++) seen |= out[i] == b;
    if (!seen) out[k++] = b;
  }
  return k;
}

/* Calls visit(d) for every block d != b whose pixels meet b's full window. */
typedef int visit_fn(void *ctx, int d);
static int for_window_blocks(const ts_schedule *s, int r, int c, visit_fn *visit, void *ctx) {
  ts_block b = block_at(s, r, c);
  int rows[MAX_SPAN], cols[MAX_SPAN];
  int nr = span_blocks(b.y - s->halo, b.y + b.h + s->halo, s->height, s->wb, rows);
  int nc = span_blocks(b.x - s->halo, b.x + b.w + s->halo, s->width, s->wb, cols);
  for (int i = 0; i < nr; i++)
    for (int j = 0; j < nc; j++) {
      int d = rows[i] * s->cols + cols[j];
      if (d != r * s->cols + c && visit(ctx, d)) return 1;
    }
  return 0;
}

typedef struct {
  const uint32_t *step;
  uint32_t mine;
  uint64_t hits;
} conflict_ctx;

static int count_same_step(void *p, int d) {
  conflict_ctx *cc = p;
  if (cc->step[d] == cc->mine) cc->hits++;
  return 0;
}

static uint64_t conflicts_of(const ts_schedule *s, const uint32_t *step) {
  conflict_ctx cc = {step, 0, 0};
  for (int r = 0; r < s->rows; r++)
    for (int c = 0; c < s->cols; c++) {
      cc.mine = step[r * s->cols + c];
      if (cc.mine != UINT32_MAX) for_window_blocks(s, r, c, count_same_step, &cc);
    }
  return cc.hits;
}

/* Orders the blocks with step[] != UINT32_MAX by step, row-major inside. */
static int build_lists(ts_schedule *s, const uint32_t *step) {
  uint32_t nsteps = 0, nblocks = 0;
  int n = s->rows * s->cols;
  for (int i = 0; i < n; i++)
    if (step[i] != UINT32_MAX) {
      nblocks++;
      if (step[i] + 1 > nsteps) nsteps = step[i] + 1;
    }
  s->step_start = calloc((size_t)nsteps + 1, sizeof(uint32_t));
  s->blocks = malloc(sizeof(ts_block) * (nblocks ? nblocks : 1));
  if (s->step_start == NULL || s->blocks == NULL) return TS_ENOMEM;
  for (int i = 0; i < n; i++)
    if (step[i] != UINT32_MAX) s->step_start[step[i] + 1]++;
  for (uint32_t t = 0; t < nsteps; t++) s->step_start[t + 1] += s->step_start[t];
  uint32_t *fill = malloc(sizeof(uint32_t) * (nsteps ? nsteps : 1));
  if (fill == NULL) return TS_ENOMEM;
  memcpy(fill, s->step_start, sizeof(uint32_t) * nsteps);
  for (int i = 0; i < n; i++)
    if (step[i] != UINT32_MAX) s->blocks[fill[step[i]]++] = block_at(s, i / s->cols, i % s->cols);
  free(fill);
  s->nsteps = nsteps;
  s->nblocks = nblocks;
  return 0;
}

static int schedule_init(ts_schedule *s, int width, int height, int wb, int wn, uint32_t **step) {
  memset(s, 0, sizeof(*s));
  if (width < 1 || height < 1 || wb < 1 || wn < wb) return TS_EINVAL;
  s->width = width;
  s->height = height;
  s->wb = wb;
  s->halo = (wn - wb) / 2;
  s->rows = ceil_div(height, wb);
  s->cols = ceil_div(width, wb);
  *step = malloc(sizeof(uint32_t) * (size_t)s->rows * s->cols);
  return *step != NULL ? 0 : TS_ENOMEM;
}

int ts_schedule_wavefront(ts_schedule *s, int width, int height, int wb, int wn) {
  uint32_t *step;
  int rc = schedule_init(s, width, height, wb, wn, &step);
  if (rc != 0) return rc;
  int first = ceil_div(s->halo, wb) + 1;
  for (int skew = first;; skew++) {
    int sequential = skew > first + 8 || skew > s->cols;
    for (int r = 0; r < s->rows; r++)
      for (int c = 0; c < s->cols; c++)
        step[r * s->cols + c] = (uint32_t)(sequential ? r * s->cols + c : c + skew * r);
    if (sequential || conflicts_of(s, step) == 0) {
      s->skew = sequential ? 0 : skew;
      break;
    }
  }
  rc = build_lists(s, step);
  free(step);
  if (rc != 0) ts_schedule_free(s);
  return rc;
}

/* Colours the `count` blocks along one axis of a torus of n pixels so that
 * no block meets the window of another of its colour. Greedy in order:
 * away from the wrap this is block index modulo m = ceil(halo/W_B) + 1;
 * where the wrap meets a count not divisible by m, or a clipped last
 * block, the last blocks get a colour or two more. Returns the number of
 * colours. Meeting a window is symmetric, so checking each block's own
 * window against the blocks coloured before it suffices. */
static int colour_axis(int n, int wb, int halo, int count, int *colour) {
  int ncolours = 0;
  for (int i = 0; i < count; i++) colour[i] = -1;
  for (int i = 0; i < count; i++) {
    int near[MAX_SPAN], lo = i * wb, hi = lo + wb < n ? lo + wb : n;
    int k = span_blocks(lo - halo, hi + halo, n, wb, near);
    uint64_t used = 0;
    for (int j = 0; j < k; j++)
      if (near[j] != i && colour[near[j]] >= 0) used |= 1ull << colour[near[j]];
    int c = 0;
    while (c < 63 && (used >> c & 1)) c++;
    colour[i] = c;
    if (c + 1 > ncolours) ncolours = c + 1;
  }
  return ncolours;
}

int ts_schedule_sweep(ts_schedule *s, int width, int height, int wb, int wn, int band) {
  uint32_t *step;
  int rc = schedule_init(s, width, height, wb, wn, &step);
  if (rc != 0) return rc;
  int *row_colour = malloc(sizeof(int) * (size_t)s->rows), *col_colour = malloc(sizeof(int) * (size_t)s->cols);
  if (row_colour == NULL || col_colour == NULL) rc = TS_ENOMEM;
  if (rc == 0) {
    colour_axis(height, wb, s->halo, s->rows, row_colour);
    uint32_t ncols = (uint32_t)colour_axis(width, wb, s->halo, s->cols, col_colour);
    /* Two blocks of one step have rows of one colour (so the rows are the
     * same or out of each other's reach) and likewise columns. */
    for (int r = 0; r < s->rows; r++)
      for (int c = 0; c < s->cols; c++) {
        int near = r < band || r >= s->rows - band || c < band || c >= s->cols - band;
        step[r * s->cols + c] = band > 0 && !near ? UINT32_MAX : (uint32_t)row_colour[r] * ncols + (uint32_t)col_colour[c];
      }
    rc = build_lists(s, step);
  }
  free(row_colour);
  free(col_colour);
  free(step);
  if (rc != 0) ts_schedule_free(s);
  return rc;
}

void ts_schedule_free(ts_schedule *s) {
  free(s->step_start);
  free(s->blocks);
  s->step_start = NULL;
  s->blocks = NULL;
  s->nsteps = s->nblocks = 0;
}

uint64_t ts_schedule_conflicts(const ts_schedule *s) {
  uint32_t *step = malloc(sizeof(uint32_t) * (size_t)s->rows * s->cols);
  if (step == NULL) return UINT64_MAX;
  for (int i = 0; i < s->rows * s->cols; i++) step[i] = UINT32_MAX;
  for (uint32_t t = 0; t < s->nsteps; t++)
    for (uint32_t i = s->step_start[t]; i < s->step_start[t + 1]; i++) {
      const ts_block *b = &s->blocks[i];
      step[(b->y / s->wb) * s->cols + b->x / s->wb] = t;
    }
  uint64_t n = conflicts_of(s, step);
  free(step);
  return n;
}
