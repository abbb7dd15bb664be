/* schedule.h - which synthesis blocks may be searched together.
 *
 * Blocks are W_B x W_B tiles of the canvas (the last row and column are
 * clipped when W_B does not divide the size). A schedule groups them into
 * steps; all blocks of a step are queried as one batch against the canvas
 * as it was at the end of the previous step, then written. That is exact
 * only if no block of a step lies in the neighbourhood window of another
 * block of the same step, which every schedule here guarantees and
 * ts_schedule_conflicts checks. The steps are a pure function of the canvas
 * geometry, so the result never depends on threads, workers or how a
 * backend splits a batch (invariant 1).
 *
 * Full synthesis uses a skewed wavefront (seed 002 digest §5.2): block
 * (r, c) goes to step c + s*r. With s = ceil(h/W_B) + 1, h = (W_N-W_B)/2,
 * every block already sees all blocks of its causal L-shaped window that
 * precede it in row-major order, so away from the torus seam the result is
 * that of a row-major scan; ~min(rows, cols/s) blocks run per step. When a
 * canvas size makes the torus wrap put two blocks of one step into each
 * other's window, s grows until it does not (in the limit: row-major).
 *
 * A refinement sweep visits every block once more, one colour per step:
 * block rows and columns are coloured so that blocks of one colour lie
 * outside each other's windows, on the torus too (m x m colours, m =
 * ceil(h/W_B) + 1, by block row and column modulo m, plus a colour or two
 * for the last rows and columns where the wrap meets a size not divisible
 * by m or a clipped block). So the two sides of the torus seam are never
 * revised at once from each other's previous state. With band > 0 only
 * the blocks within `band` block rows or columns of the seam are visited. */
#ifndef TS_SCHEDULE_H
#define TS_SCHEDULE_H

#include <stdint.h>

typedef struct {
  int32_t x, y;  /* top-left pixel */
  uint16_t w, h; /* size after clipping at the canvas edge */
} ts_block;

typedef struct {
  int width, height, wb, halo; /* halo = (W_N - W_B) / 2 */
  int rows, cols;
  int skew; /* wavefront skew; 0 for the row-major fallback */
  uint32_t nsteps, nblocks;
  uint32_t *step_start; /* nsteps + 1 offsets into blocks */
  ts_block *blocks;     /* by step, row-major within a step */
} ts_schedule;

int ts_schedule_wavefront(ts_schedule *s, int width, int height, int wb,
                          int wn);
int ts_schedule_sweep(ts_schedule *s, int width, int height, int wb, int wn, int band);
void ts_schedule_free(ts_schedule *s);

/* Number of ordered pairs of distinct blocks in one step where one lies in
 * the other's full W_N window on the torus (0 for a valid schedule). */
uint64_t ts_schedule_conflicts(const ts_schedule *s);

#endif
