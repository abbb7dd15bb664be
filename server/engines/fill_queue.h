/* fill_queue.h - which blocks constrained synthesis (fill.h) searches
 * next: the "puzzle" order of seed 002 §3.2.4 as steps of blocks that can
 * be searched together.
 *
 * The blocks of one class at one level - the W_B x W_B tiles of the block
 * grid holding any pixel of the class, clipped at the image's edges - wait
 * in a bucket queue keyed by their P_def, the known (given or placed)
 * pixels of their W_N window. The block grid is the spatial index: placing a
 * block re-sorts only the blocks whose windows it touches (those within r
 * = ceil(((W_N - W_B) / 2) / W_B) block rows and columns), by the pixels it
 * placed inside their windows.
 *
 * A step takes the blocks of the top buckets - the best described: those
 * whose P_def is within W_N (a window's row) of the best - that are
 * independent: no two within r of each other, so none lies in another's
 * window, and the result of searching them together is the result of
 * placing them one by one in that order. (The slack of a row cuts the steps
 * of a large area fourfold against the top bucket alone - 1148 against 4713
 * at level 0 of a 512x512 aerial scene - with no difference to be seen.) Within a bucket blocks keep the order they came
 * in (first raster order, then the order they were re-sorted), so steps
 * are a pure function of the states. The threshold order (§3.2.5) instead
 * takes, in rounds, every block whose P_def reached a share of the window
 * when the round began, independent sets of them step by step, without
 * re-sorting; a round that finds none takes one puzzle step. */
#ifndef TS_FILL_QUEUE_H
#define TS_FILL_QUEUE_H

#include <stdint.h>

#include "fill.h"

typedef struct {
  int w, h, wb, halo;   /* image, block width, (W_N - W_B) / 2 */
  int bw, bh, r;        /* block grid, re-sort and conflict radius */
  uint32_t nblocks;
  int32_t *next, *prev; /* bucket links per block; prev -2: not queued */
  int32_t *head, *tail; /* per bucket */
  uint16_t *count;      /* P_def per block */
  uint32_t *stamp;      /* the step that took a block */
  uint32_t step_id;
  int top, nbuckets;
  uint64_t queued, placed;
  int order, threshold, slack;
  uint32_t *step, nstep, cap; /* the step's blocks */
  uint32_t *round, nround;    /* threshold order: the round's blocks left */
} ts_fill_queue;

/* Queues the blocks of class c (state == c) of a w x h level whose pixel
 * states are done (window.h). 0 or TS_ENOMEM. */
int ts_fill_queue_init(ts_fill_queue *q, const uint8_t *done, const uint8_t *state, int c, int w, int h,
                       const ts_fill_params *p);
void ts_fill_queue_free(ts_fill_queue *q);

static inline int ts_fill_queue_empty(const ts_fill_queue *q) { return q->queued == 0; }

/* The next step (the queue must not be empty): returns 1 with blocks to
 * search, or 0 with one block to seed - when nothing is known around any
 * block and coarse_known is 0 (the coarsest level: no coarse part). */
int ts_fill_queue_step(ts_fill_queue *q, int coarse_known, const uint32_t **blocks, uint32_t *n);

/* Block b was placed (its pixels of the class are PLACED in done): it
 * leaves the queue and its neighbours are re-sorted. */
void ts_fill_queue_placed(ts_fill_queue *q, uint32_t b, const uint8_t *done);

/* The top-left pixel of block b. */
void ts_fill_queue_block_xy(const ts_fill_queue *q, uint32_t b, int *x, int *y);

/* Blocks holding a pixel of class c; of all classes (counted per class). */
uint64_t ts_fill_class_blocks(const uint8_t *state, int w, int h, int c, int wb);
uint64_t ts_fill_level_blocks(const uint8_t *state, int w, int h, int nclass, int wb);

#endif
