/* usage.h - the usage map and the active usage-variance penalty (seed 002
 * §3.7, eq. 3.5).
 *
 * Every reference pixel has a 32-bit counter, incremented for each pixel a
 * synthesis block copies from it. U_j, the usage of candidate block j, is
 * the sum of the counters under its W_B x W_B block (the digest's
 * recommended reading of U(B_j), kept as a sum to stay integral). The
 * penalty added to candidate j's distance is
 *
 *   f_j = alpha * D1 * U_j / E[U]
 *
 * where E[U] is the value U_j would have if all usable pixels had been used
 * equally so far, and D1 is the weighted distance of a one-grey-level error
 * in every component - so alpha = 1 charges a block used at the average rate
 * one grey level per component. It is evaluated as (U_j * K) >> 32 with the
 * per-batch factor K from ts_usage_factor, in exact integer arithmetic, so a
 * remote worker holding the same counters computes the same penalties. */
#ifndef TS_USAGE_H
#define TS_USAGE_H

#include <stdint.h>

#include "anchors.h"

typedef struct {
  ts_anchors grid; /* shares the anchors' index: they outlive the usage */
  int wb;
  uint32_t *count; /* grid.w * grid.h counters */
  uint32_t *u;     /* grid.total block sums, by global vector index; NULL
                      when only the map is kept (no penalty) */
  uint64_t total;  /* sum of all counters */
  uint64_t usable; /* pixels covered by at least one valid block */
} ts_usage;

/* with_blocks: also keep the block sums U_j the penalty needs (81 updates
 * per copied 3x3 block instead of 9). */
int ts_usage_init(ts_usage *u, const ts_anchors *g, int wb, int with_blocks);
void ts_usage_free(ts_usage *u);
/* Records that the w x h pixels at (x, y) of the reference were copied
 * (delta +1), or that such a copy was replaced (delta -1). */
void ts_usage_commit(ts_usage *u, int x, int y, int w, int h, int delta);
/* Sets the counters to count (grid.w * grid.h of them), and the total and
 * block sums to match: a usage state carried over (a resumed level). */
void ts_usage_load(ts_usage *u, const uint32_t *count);
/* Recomputes, from the counters, the block sums of the valid blocks that lie
 * within rows [y0, y1) (a no-op without block sums). */
void ts_usage_sum_blocks(ts_usage *u, int y0, int y1);
/* Penalty factor K (32.32 fixed point) for alpha and D1 (see above). */
uint64_t ts_usage_factor(const ts_usage *u, double alpha, uint64_t d1);

static inline uint32_t ts_usage_penalty(uint32_t uj, uint64_t k) {
  unsigned __int128 p = ((unsigned __int128)uj * k) >> 32;
  return p > UINT32_MAX ? UINT32_MAX : (uint32_t)p;
}

/* Mean and variance of the counters over the usable pixels. */
void ts_usage_stats(const ts_usage *u, double *mean, double *variance);

#endif
