/* mrf_state.h - the MRF engine's state, shared by its files (mrf.h is
 * the face), each calling only into those listed above it:
 *
 *   mrf_plan.c    a level's work as steps: the scan, then the sweeps
 *   mrf.c         the checks, and the levels: noise or prediction, steps,
 *                 checkpoints, the copy-map shortcut, the output
 *   mrf_resume.c  a checkpoint judged and taken over
 *   mrf_bestof.c  best-of candidates through the coarse levels (§3.7.1)
 *   mrf_run.c     a synthesis from the reference to the result */
#ifndef TS_MRF_STATE_H
#define TS_MRF_STATE_H

#include <time.h>

#include "mrf.h"
#include "mrf_accel.h"
#include "plane.h"
#include "replica.h"
#include "schedule.h"
#include "usage.h"

/* A block is searched with the causal L-shaped neighbourhood (plain), or -
 * when its full window already holds placed blocks outside the L, which
 * happens only where the window wraps around the torus or meets the
 * clipped last row or column - with the full window and a variable mask
 * (§3.2.6) that keeps the L and every placed pixel. So the last column also
 * matches the first one on its right and the last row the first row below
 * it: the seams of the torus are matched from both sides. */
enum { SHAPE_PLAIN = 0, SHAPE_MASKED = 1 };

typedef struct {
  uint32_t n;
  uint32_t *pos; /* each query's canvas pixel */
  uint8_t *klass;
  uint32_t *block; /* index of each query's block within the step */
  ts_l1_best *best;
} query_group;

typedef struct {
  ts_schedule sched;
  int refine, reps;
} level_phase;

/* The work of a level as one sequence of steps: the wavefront scan, then
 * each sweep pass's schedule `reps` times. A checkpoint inside the level
 * names its place in it by the number of steps done. */
typedef struct {
  int n;
  level_phase phase[3];
  uint64_t steps;
} level_plan;

typedef struct {
  const ts_mrf_params *p;
  ts_search *search;
  const ts_mrf_hooks *hooks;
  ts_mrf_result *res;
  ts_progress prog;
  int nplanes;
  int levels;
  ts_plane ref[TS_MAX_PLANES][TS_MRF_MAX_LEVELS];
  /* Texture mixing (§4.3): the fine reference's pyramid, levels 0..mix
   * (mix: p->mix_level, 0 without mixing). */
  int mix;
  ts_plane fine_ref[TS_MAX_PLANES][TS_MRF_MAX_LEVELS];
  uint64_t seed;       /* the noise seed of the run under way (a best-of candidate's) */
  int candidate_phase; /* running best-of candidates, which take no checkpoints */
  /* The copy-map shortcut: this level's map (empty where it does not
   * apply), and the candidates measured so far over all levels and how
   * many of them kept their predicted source. */
  ts_accel_map accel;
  uint64_t accel_measured, accel_kept;
  ts_plane canvas[TS_MAX_PLANES][TS_MRF_MAX_LEVELS];
  int cw[TS_MRF_MAX_LEVELS], ch[TS_MRF_MAX_LEVELS];
  /* current level */
  int level;
  ts_levelplanes ref_lp, canvas_lp;
  ts_anchors grid;
  ts_plane parity; /* the class (label) of every reference pixel, with parity */
  ts_usage usage;
  uint32_t *copy; /* (x, y) per canvas pixel at this level */
  uint32_t *prev_copy; /* the same of the level above */
  uint8_t *done;  /* 1 where a block was placed at this level */
  ts_window shape[2]; /* SHAPE_PLAIN: causal L; SHAPE_MASKED: full window */
  int image; /* the backend's replica of the canvas (replica.h), or -1 */
  int set_ids[2];
  level_plan plan;
  uint64_t step; /* steps of the plan done */
  /* The level's statistics: carried over from a checkpoint inside it, and
   * the search counters when this run started it. */
  ts_mrf_level_stats carried;
  ts_search_stats base;
  double t0;
  double last_checkpoint; /* ts_now() then, or at the start */
  /* per-step scratch: one query group per shape */
  uint32_t cap;
  query_group group[2];
  uint32_t *direct, ndirect; /* blocks of the step copied by the shortcut */
  ts_place *places;
  uint8_t mask[TS_L1_MAX_CHUNKS * TS_L1_CHUNK];
} engine;

/* The pyramid level l is made from: the fine reference's below the mix
 * level, the reference's from it up. Its level l is the fine part of the
 * vectors, its level l + 1 the coarse part; the coarse part of the queries
 * is the canvas above, so at the switch the coarse layout made from the
 * reference is matched against the fine reference's coarse level. */
static inline const ts_plane *mrf_level_refs(const engine *e, int k, int l) { return l < e->mix ? e->fine_ref[k] : e->ref[k]; }

static inline double mrf_level_cost(int l) { return 1.0 / (double)(1ull << (2 * l)); }

/* Seconds since the epoch: a checkpoint's moment has to mean something to
 * the process that resumes from it, which the monotonic clock does not. */
static inline double mrf_wall_now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_REALTIME, &ts);
  return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* The last level the best-of candidates run: the best_of_levels coarsest
 * (by default all but the finest two), but not below the output's. */
static inline int mrf_candidate_last_level(const ts_mrf_params *p) {
  int n = p->best_of_levels > 0 ? p->best_of_levels : p->levels - 2;
  int last = p->levels - (n > 0 ? n : 1);
  return last > p->stop_level ? last : p->stop_level;
}

#endif
