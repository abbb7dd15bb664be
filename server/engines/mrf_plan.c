/* mrf_plan.c - see mrf_plan.h. */
#include "mrf_plan.h"

#include <stdlib.h>
#include <string.h>

/* Refinement sweeps (--refine N). On every level but the finest: N sweeps
 * over the whole canvas, then SEAM_SWEEPS_PER_REFINE * N more over the
 * band of SEAM_BAND_COARSE block rows and columns along each side of the
 * torus seam. The coarse levels fix the layout, and where their scan
 * closed the torus two independently grown patterns meet (bricks out of
 * phase, say); a few sweeps mend the join locally but ICM moves the misfit
 * one block per sweep, so it takes more of them, on a wider band, to
 * spread it out. Measured on brick 256^2, 6 seeds: windows across the seam
 * went from 1.32x to 0.94x the error of windows across interior lines, for
 * ~10 % more time on the Table 3.3 job. On the finest level, which costs
 * 16x a level above and inherits the layout, the N sweeps cover the band
 * of SEAM_BAND_FINEST block rows and columns only: it needs no more (more
 * sweeps there did not lower the seam's error). */
#define SEAM_BAND_FINEST 3
#define SEAM_BAND_COARSE 6
#define SEAM_SWEEPS_PER_REFINE 4

typedef struct {
  int band, count; /* band 0: the whole canvas */
} sweep_pass;

/* The sweep passes of level l, in order; returns how many (at most 2). */
static int level_sweeps(const ts_mrf_params *p, int l, sweep_pass pass[2]) {
  if (p->refine == 0) return 0;
  if (l == 0) {
    pass[0] = (sweep_pass){SEAM_BAND_FINEST, p->refine};
    return 1;
  }
  pass[0] = (sweep_pass){0, p->refine};
  pass[1] = (sweep_pass){SEAM_BAND_COARSE, SEAM_SWEEPS_PER_REFINE * p->refine};
  return 2;
}

/* Blocks a sweep over `band` block rows and columns of the seam visits. */
static uint64_t band_blocks(uint64_t rows, uint64_t cols, uint64_t band) {
  if (band == 0 || rows <= 2 * band || cols <= 2 * band) return rows * cols;
  return rows * cols - (rows - 2 * band) * (cols - 2 * band);
}

/* Blocks searched at a level: the scan and the refinement sweeps. */
uint64_t mrf_level_blocks(const ts_mrf_params *p, int l, int w, int h) {
  uint64_t rows = (uint64_t)(h + p->wb - 1) / p->wb, cols = (uint64_t)(w + p->wb - 1) / p->wb;
  uint64_t n = rows * cols;
  sweep_pass pass[2];
  for (int i = 0, k = level_sweeps(p, l, pass); i < k; i++)
    n += band_blocks(rows, cols, (uint64_t)pass[i].band) * (uint64_t)pass[i].count;
  return n;
}

void mrf_plan_free(level_plan *pl) {
  for (int i = 0; i < pl->n; i++) ts_schedule_free(&pl->phase[i].sched);
  memset(pl, 0, sizeof(*pl));
}

int mrf_plan_level(level_plan *pl, const ts_mrf_params *p, int l, int w, int h) {
  sweep_pass pass[2];
  int npass = level_sweeps(p, l, pass);
  memset(pl, 0, sizeof(*pl));
  pl->n = 1 + npass;
  pl->phase[0].reps = 1;
  int rc = ts_schedule_wavefront(&pl->phase[0].sched, w, h, p->wb, p->wn);
  for (int i = 0; rc == 0 && i < npass; i++) {
    level_phase *ph = &pl->phase[1 + i];
    ph->refine = 1;
    ph->reps = pass[i].count;
    rc = ts_schedule_sweep(&ph->sched, w, h, p->wb, p->wn, pass[i].band);
  }
  for (int i = 0; i < pl->n; i++) pl->steps += (uint64_t)pl->phase[i].sched.nsteps * (uint64_t)pl->phase[i].reps;
  if (rc != 0) mrf_plan_free(pl);
  return rc;
}

/* Calls fn on every block of the plan's first `steps` steps, in order. */
void mrf_plan_walk(const level_plan *pl, uint64_t steps, void (*fn)(void *ctx, const ts_block *b), void *ctx) {
  for (int i = 0; i < pl->n && steps > 0; i++) {
    const ts_schedule *s = &pl->phase[i].sched;
    for (int r = 0; r < pl->phase[i].reps && steps > 0; r++) {
      uint32_t t = steps < s->nsteps ? (uint32_t)steps : s->nsteps;
      for (uint32_t b = 0; b < s->step_start[t]; b++) fn(ctx, &s->blocks[b]);
      steps -= t;
    }
  }
}
