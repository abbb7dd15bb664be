/* mrf_accel.h - the copy-map shortcut of MRF synthesis (seed 002 §3.6.6).
 *
 * Small blocks grow into large coherent regions: in the copy map a region
 * copied from one place of the reference is a homogeneous gradient of
 * slope 1 (source = position + one offset). The regions are laid out at
 * the coarse levels and stay largely where they are; finer levels mostly
 * rework the transitions between them. So a finer level can copy the
 * blocks that lie deep inside a coherent region of the level above
 * straight from their predicted source (ts_copy_predict) and search only
 * the rest.
 *
 * Coherent: a pixel of the level above's copy map is coherent when every
 * pixel of the n x n kernel around it (on the torus) has its offset. The
 * kernel's half-width is the buffer zone kept between a copied block and
 * the nearest transition. A block is a candidate when every coarse pixel
 * under it is coherent, its predicted sources form one reference block
 * (slope 1 at this level too, nothing clamped at the reference's edge) and
 * that block is a reference vector of the block's class (its anchor; with
 * parity control, of the same parity).
 *
 * Which blocks are candidates is a function of the level above's copy map
 * and the parameters alone, so it is the same on any number of workers.
 * The shortcut changes the model (a candidate might have found another
 * source when searched): it is lossy, opt-in, and only enabled where the
 * levels above showed their regions constant (mrf.c). */
#ifndef TS_MRF_ACCEL_H
#define TS_MRF_ACCEL_H

#include <stdint.h>

#include "anchors.h"

/* Per block of a level's grid (W_B x W_B tiles, row-major, the last row
 * and column clipped), what the shortcut does with it. */
enum {
  TS_ACCEL_SEARCH = 0,  /* not a candidate: searched as usual */
  TS_ACCEL_MEASURE = 1, /* a candidate searched anyway, to measure constancy */
  TS_ACCEL_COPY = 2     /* a candidate copied from its predicted source */
};

typedef struct {
  int rows, cols, wb;
  uint8_t *what;     /* rows * cols: TS_ACCEL_* */
  int32_t *src;      /* rows * cols x 2: a candidate's predicted source (x, y) */
  uint32_t candidates;
} ts_accel_map;

/* The candidates of a w x h level (blocks of wb) from the copy map of the
 * level above (pw x ph, x then y per pixel, into a reference of half the
 * size of this level's rw x rh), with an n x n kernel (odd n >= 1). grid:
 * this level's reference vectors; parity: classes are (x & 1) | (y & 1) << 1.
 * Every candidate starts as TS_ACCEL_MEASURE. 0 or TS_ENOMEM. */
int ts_accel_map_build(ts_accel_map *m, const uint32_t *prev, int pw, int ph, int w, int h, int wb, int n,
                       int rw, int rh, const ts_anchors *grid, int parity);
void ts_accel_map_free(ts_accel_map *m);

/* Turns all but every `every`-th candidate (in row-major order, the first
 * included) into TS_ACCEL_COPY; those few stay measured. */
void ts_accel_map_enable(ts_accel_map *m, uint32_t every);

/* Whether the block at (bx, by) is to be treated as `what` (TS_ACCEL_*);
 * if so, its predicted source in *sx, *sy. */
int ts_accel_block(const ts_accel_map *m, int bx, int by, int what, int *sx, int *sy);

/* Of the measured candidates, how many hold their predicted source in the
 * level's copy map (w wide, x then y per pixel) now: *kept of *measured. */
void ts_accel_constancy(const ts_accel_map *m, const uint32_t *copy, int w, uint64_t *measured, uint64_t *kept);

#endif
