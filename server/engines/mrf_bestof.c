/* mrf_bestof.c - see mrf_bestof.h. */
#include "mrf_bestof.h"

#include <stdlib.h>

#include "mrf_levels.h"
#include "mrf_plan.h"
#include "rng.h"
#include "util.h"

#define BEST_OF_STREAM (0x62657374ull << 32) /* "best": apart from the levels' noise streams */

/* The seed of candidate k: the job's own for the first (so the first
 * candidate is the plain run), the others drawn from it. */
static uint64_t candidate_seed(uint64_t seed, int k) {
  if (k == 0) return seed;
  ts_rng rng;
  ts_rng_seed(&rng, seed, BEST_OF_STREAM + (uint64_t)k);
  return ts_rng_next(&rng);
}

/* Back to before the coarsest level, for another candidate: every level's
 * state goes, and so does the backend's replica (each run opens its own). */
static void reset_run(engine *e) {
  mrf_drop_previous_level(e);
  free(e->prev_copy);
  e->prev_copy = NULL;
  for (int k = 0; k < TS_MAX_PLANES; k++) ts_pyramid_free(e->canvas[k], e->levels);
  if (e->image >= 0) ts_search_image_close(e->search, e->image);
  e->image = -1;
  e->accel_measured = e->accel_kept = 0;
}

/* Candidate k from noise down to level `last`, its usage variance there
 * and (unless it is a re-run) its time. */
static int run_candidate(engine *e, int k, int last, int rerun, char *err) {
  ts_mrf_candidate *c = &e->res->candidate[k];
  double t0 = ts_now(), mean;
  e->seed = c->seed = candidate_seed(e->p->seed, k);
  int rc = mrf_run_levels(e, e->levels - 1, last, NULL, err);
  if (rc == 0) ts_usage_stats(&e->usage, &mean, &c->variance);
  if (!rerun) c->seconds = ts_now() - t0;
  return rc;
}

/* The work of one candidate, for the progress bar. */
double mrf_candidate_work(const engine *e, int last) {
  double w = 0;
  for (int l = last; l < e->levels; l++) w += (double)mrf_level_blocks(e->p, l, e->cw[l], e->ch[l]) * mrf_level_cost(l);
  return w;
}

/* Runs best_of candidates through the coarse levels and keeps the one
 * whose usage map has the least variance at the last of them (ties: the
 * lowest number): the coarse levels fix the layout and the global use of
 * the reference, and cost a few per cent of a run. The engine is left as
 * the chosen one left that level, the next level to run in *next. When
 * the chosen one was not the last run, it is run again: runs are
 * deterministic, so that gives its state exactly (and a plain run with its
 * seed the same bytes), for less memory than keeping every candidate's
 * canvas and replica. */
int mrf_choose_candidate(engine *e, int *next, char *err) {
  const ts_mrf_params *p = e->p;
  ts_mrf_result *res = e->res;
  int last = mrf_candidate_last_level(p), rc = 0;
  res->best_of_level = last;
  e->candidate_phase = 1;
  for (int k = 0; rc == 0 && k < p->best_of; k++) {
    if (k > 0) reset_run(e);
    rc = run_candidate(e, k, last, 0, err);
    res->ncandidates = k + 1;
    if (rc == 0 && res->candidate[k].variance < res->candidate[res->chosen].variance) res->chosen = k;
  }
  if (rc == 0 && res->chosen != p->best_of - 1) {
    reset_run(e);
    e->prog.work_total += mrf_candidate_work(e, last);
    rc = run_candidate(e, res->chosen, last, 1, err);
  }
  e->candidate_phase = 0;
  if (rc == 0 && last > p->stop_level) rc = mrf_level_end(e, last, err);
  *next = last - 1;
  return rc;
}
