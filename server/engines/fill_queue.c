/* fill_queue.c - see fill_queue.h. */
#include "fill_queue.h"

#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "window.h"

#define NOT_QUEUED (-2)
#define STEP_CAP 32768 /* blocks per step: a bound on the batch, not on the order */

void ts_fill_queue_block_xy(const ts_fill_queue *q, uint32_t b, int *x, int *y) {
  *x = (int)(b % (uint32_t)q->bw) * q->wb;
  *y = (int)(b / (uint32_t)q->bw) * q->wb;
}

/* Whether the block at (x, y) holds a pixel of class c. */
static int block_has(const uint8_t *state, int w, int h, int wb, int x, int y, int c) {
  for (int dy = 0; dy < wb && y + dy < h; dy++)
    for (int dx = 0; dx < wb && x + dx < w; dx++)
      if (state[(size_t)(y + dy) * (size_t)w + (size_t)(x + dx)] == c) return 1;
  return 0;
}

uint64_t ts_fill_class_blocks(const uint8_t *state, int w, int h, int c, int wb) {
  uint64_t n = 0;
  for (int y = 0; y < h; y += wb)
    for (int x = 0; x < w; x += wb) n += (uint64_t)block_has(state, w, h, wb, x, y, c);
  return n;
}

uint64_t ts_fill_level_blocks(const uint8_t *state, int w, int h, int nclass, int wb) {
  uint64_t n = 0;
  for (int c = 1; c <= nclass; c++) n += ts_fill_class_blocks(state, w, h, c, wb);
  return n;
}

static void unlink_block(ts_fill_queue *q, uint32_t b) {
  int k = q->count[b];
  int32_t p = q->prev[b], n = q->next[b];
  if (p >= 0) q->next[p] = n;
  else q->head[k] = n;
  if (n >= 0) q->prev[n] = p;
  else q->tail[k] = p;
  q->prev[b] = NOT_QUEUED;
}

static void append_block(ts_fill_queue *q, uint32_t b) {
  int k = q->count[b];
  q->next[b] = -1;
  q->prev[b] = q->tail[k];
  if (q->tail[k] >= 0) q->next[q->tail[k]] = (int32_t)b;
  else q->head[k] = (int32_t)b;
  q->tail[k] = (int32_t)b;
  if (k > q->top) q->top = k;
}

/* Known pixels of the window of the block at (x, y), from the summed-area
 * table t of the known pixels ((w+1) x (h+1)). */
static uint16_t window_known(const ts_fill_queue *q, const uint32_t *t, int x, int y) {
  int x0 = x - q->halo, y0 = y - q->halo, x1 = x + q->wb + q->halo, y1 = y + q->wb + q->halo;
  x0 = x0 < 0 ? 0 : x0;
  y0 = y0 < 0 ? 0 : y0;
  x1 = x1 > q->w ? q->w : x1;
  y1 = y1 > q->h ? q->h : y1;
  size_t w1 = (size_t)q->w + 1;
  return (uint16_t)(t[(size_t)y1 * w1 + (size_t)x1] - t[(size_t)y0 * w1 + (size_t)x1] -
                    t[(size_t)y1 * w1 + (size_t)x0] + t[(size_t)y0 * w1 + (size_t)x0]);
}

static uint32_t *known_table(const uint8_t *done, int w, int h) {
  size_t w1 = (size_t)w + 1;
  uint32_t *t = calloc(w1 * ((size_t)h + 1), sizeof(uint32_t));
  if (t == NULL) return NULL;
  for (int y = 0; y < h; y++) {
    uint32_t row = 0;
    for (int x = 0; x < w; x++) {
      uint8_t d = done[(size_t)y * (size_t)w + (size_t)x];
      row += d == TS_DONE_PLACED || d == TS_DONE_FIXED;
      t[(size_t)(y + 1) * w1 + (size_t)x + 1] = t[(size_t)y * w1 + (size_t)x + 1] + row;
    }
  }
  return t;
}

void ts_fill_queue_free(ts_fill_queue *q) {
  free(q->next);
  free(q->prev);
  free(q->head);
  free(q->tail);
  free(q->count);
  free(q->stamp);
  free(q->step);
  free(q->round);
  memset(q, 0, sizeof(*q));
}

int ts_fill_queue_init(ts_fill_queue *q, const uint8_t *done, const uint8_t *state, int c, int w, int h,
                       const ts_fill_params *p) {
  memset(q, 0, sizeof(*q));
  q->w = w;
  q->h = h;
  q->wb = p->wb;
  q->halo = (p->wn - p->wb) / 2;
  q->r = (q->halo + p->wb - 1) / p->wb;
  q->bw = (w + p->wb - 1) / p->wb;
  q->bh = (h + p->wb - 1) / p->wb;
  q->nblocks = (uint32_t)q->bw * (uint32_t)q->bh;
  q->nbuckets = p->wn * p->wn + 1;
  q->order = p->order;
  q->slack = p->wn;
  q->threshold = (int)(p->threshold * p->wn * p->wn + 0.999999);
  q->next = malloc(sizeof(int32_t) * q->nblocks);
  q->prev = malloc(sizeof(int32_t) * q->nblocks);
  q->count = malloc(sizeof(uint16_t) * q->nblocks);
  q->stamp = calloc(q->nblocks, sizeof(uint32_t));
  q->head = malloc(sizeof(int32_t) * (size_t)q->nbuckets);
  q->tail = malloc(sizeof(int32_t) * (size_t)q->nbuckets);
  q->cap = q->nblocks < STEP_CAP ? q->nblocks : STEP_CAP;
  q->step = malloc(sizeof(uint32_t) * q->cap);
  uint32_t *t = known_table(done, w, h);
  if (!q->next || !q->prev || !q->count || !q->stamp || !q->head || !q->tail || !q->step || !t) {
    free(t);
    ts_fill_queue_free(q);
    return TS_ENOMEM;
  }
  for (int k = 0; k < q->nbuckets; k++) q->head[k] = q->tail[k] = -1;
  for (uint32_t b = 0; b < q->nblocks; b++) {
    int x, y;
    ts_fill_queue_block_xy(q, b, &x, &y);
    q->prev[b] = NOT_QUEUED;
    if (!block_has(state, w, h, q->wb, x, y, c)) continue;
    q->count[b] = window_known(q, t, x, y);
    append_block(q, b);
    q->queued++;
  }
  free(t);
  return 0;
}

/* Whether no block taken in this step lies within r of block b. */
static int independent(const ts_fill_queue *q, uint32_t b) {
  int bx = (int)(b % (uint32_t)q->bw), by = (int)(b / (uint32_t)q->bw);
  for (int j = by - q->r; j <= by + q->r; j++)
    for (int i = bx - q->r; i <= bx + q->r; i++)
      if (i >= 0 && j >= 0 && i < q->bw && j < q->bh && q->stamp[(size_t)j * (size_t)q->bw + (size_t)i] == q->step_id)
        return 0;
  return 1;
}

static void take(ts_fill_queue *q, uint32_t b) {
  q->stamp[b] = q->step_id;
  q->step[q->nstep++] = b;
}

static void top_down(ts_fill_queue *q) {
  while (q->top > 0 && q->head[q->top] < 0) q->top--;
}

/* The independent blocks of the top buckets. At the coarsest level a block
 * with nothing known around it is never searched: when no other is left,
 * the first one is seeded. */
static int puzzle_step(ts_fill_queue *q, int coarse_known) {
  top_down(q);
  q->step_id++;
  q->nstep = 0;
  if (q->top == 0 && !coarse_known) {
    take(q, (uint32_t)q->head[0]);
    return 0;
  }
  int floor = coarse_known ? 0 : 1;
  int lo = q->top - q->slack < floor ? floor : q->top - q->slack;
  for (int k = q->top; k >= lo && q->nstep < q->cap; k--)
    for (int32_t b = q->head[k]; b >= 0 && q->nstep < q->cap; b = q->next[b])
      if (independent(q, (uint32_t)b)) take(q, (uint32_t)b);
  return 1;
}

/* The blocks a threshold round takes: every queued block whose P_def has
 * reached the threshold, best first. */
static int round_start(ts_fill_queue *q) {
  if (q->round == NULL && (q->round = malloc(sizeof(uint32_t) * q->nblocks)) == NULL) return TS_ENOMEM;
  q->nround = 0;
  top_down(q);
  for (int k = q->top; k >= q->threshold && k > 0; k--)
    for (int32_t b = q->head[k]; b >= 0; b = q->next[b]) q->round[q->nround++] = (uint32_t)b;
  return 0;
}

/* Independent blocks of the round, in its order; the rest stay for the
 * round's next steps. */
static void round_step(ts_fill_queue *q) {
  q->step_id++;
  q->nstep = 0;
  uint32_t keep = 0;
  for (uint32_t i = 0; i < q->nround; i++) {
    uint32_t b = q->round[i];
    if (q->nstep < q->cap && independent(q, b)) take(q, b);
    else q->round[keep++] = b;
  }
  q->nround = keep;
}

int ts_fill_queue_step(ts_fill_queue *q, int coarse_known, const uint32_t **blocks, uint32_t *n) {
  int search = 1;
  if (q->order == TS_FILL_THRESHOLD && q->nround == 0 && round_start(q) != 0) q->order = TS_FILL_PUZZLE;
  if (q->order == TS_FILL_THRESHOLD && q->nround > 0) round_step(q);
  else search = puzzle_step(q, coarse_known);
  *blocks = q->step;
  *n = q->nstep;
  return search;
}

void ts_fill_queue_placed(ts_fill_queue *q, uint32_t b, const uint8_t *done) {
  if (q->prev[b] != NOT_QUEUED) {
    unlink_block(q, b);
    q->queued--;
    q->placed++;
  }
  int x, y;
  ts_fill_queue_block_xy(q, b, &x, &y);
  int bx = x / q->wb, by = y / q->wb;
  for (int j = by - q->r; j <= by + q->r; j++)
    for (int i = bx - q->r; i <= bx + q->r; i++) {
      if (i < 0 || j < 0 || i >= q->bw || j >= q->bh) continue;
      uint32_t nb = (uint32_t)j * (uint32_t)q->bw + (uint32_t)i;
      if (q->prev[nb] == NOT_QUEUED) continue;
      /* The placed pixels of b inside nb's window. */
      int wx0 = i * q->wb - q->halo, wy0 = j * q->wb - q->halo;
      int wx1 = i * q->wb + q->wb + q->halo, wy1 = j * q->wb + q->wb + q->halo;
      int inc = 0;
      for (int py = y; py < y + q->wb && py < q->h; py++)
        for (int px = x; px < x + q->wb && px < q->w; px++)
          inc += px >= wx0 && px < wx1 && py >= wy0 && py < wy1 &&
                 done[(size_t)py * (size_t)q->w + (size_t)px] == TS_DONE_PLACED;
      if (inc == 0) continue;
      unlink_block(q, nb);
      q->count[nb] = (uint16_t)(q->count[nb] + inc);
      append_block(q, nb);
    }
}
