/* stylit.c - the stylization's EM loop over the pyramid (stylit.h): the
 * NNF at each level's start, the vote, the search step through the search
 * service, the occurrence map. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "patchmatch.h"
#include "rng.h"
#include "stylit.h"
#include "util.h"

/* Queries per batch, and batches per query_many call (one round trip on
 * a cluster). Only the traffic's shape: results never depend on them. */
#define BATCH 4096
#define BATCHES_PER_CALL 16
/* With uniformity on, a search step goes in 16 sub-steps, the target
 * pixels of each (x mod 4, y mod 4) in turn; Ω is frozen within a sub-step
 * and updated after it (each of its patches leaves its old source patch
 * and takes the new one). Frozen for a whole step, Ω makes every patch
 * flee the same crowded source patches at once into the same few free
 * ones, and the next step back (the oscillation of a Jacobi update): on
 * the stylit scene the exemplar coverage fell as uniformity rose. The
 * order is fixed, so the result still depends on nothing but the job. */
#define SUBSTEP_SIDE 4

typedef struct {
  const ts_stylit_params *p;
  ts_search *search;
  const ts_progress_hooks *h;
  ts_stylit_planes pl;
  int levels, r, patch;
  double lambda;
  /* Pyramids of every plane: [plane][level]. */
  ts_plane src[TS_WIN_MAX_PLANES][TS_STYLIT_MAX_LEVELS], tgt[TS_WIN_MAX_PLANES][TS_STYLIT_MAX_LEVELS];
  ts_window win;
  uint64_t d1; /* the window's one-grey-level distance, the penalty's unit */
  /* The level under way: sizes, NNF (source centre x, y per target pixel),
   * the source patches (anchors: their top-left corners) and Ω. */
  int level, sw, sh, tw, th;
  uint32_t *nnf;
  ts_anchors grid;
  ts_usage omega; /* counters only: the backend sums them per patch */
  ts_plane est[TS_WIN_MAX_PLANES]; /* the style estimate, planes 0..nstyle-1 */
  ts_progress prog;
  uint64_t usage_k; /* patchmatch's penalty factor at this level */
  /* Every level's search mode, and auto's estimate of its exact time,
   * decided before the first level runs. */
  int mode[TS_STYLIT_MAX_LEVELS];
  double estimate[TS_STYLIT_MAX_LEVELS];
} run;

static uint32_t clampu(long v, long lo, long hi) { return (uint32_t)(v < lo ? lo : v > hi ? hi : v); }

/* ---- shared with energy and apply-nnf (stylit_input.h) ---------------- */

int ts_stylit_window(ts_window *win, const ts_stylit_params *p, const ts_stylit_planes *pl, char *err) {
  int16_t dx[TS_STYLIT_MAX_PATCH * TS_STYLIT_MAX_PATCH], dy[TS_STYLIT_MAX_PATCH * TS_STYLIT_MAX_PATCH];
  int n = 0;
  for (int y = 0; y < p->patch; y++)
    for (int x = 0; x < p->patch; x++) {
      dx[n] = (int16_t)x;
      dy[n++] = (int16_t)y;
    }
  ts_window_spec s = {.nplanes = {pl->nplanes, 0}, .noff = {n, 0}, .dx = {dx, NULL}, .dy = {dy, NULL},
                      .extent = {{0, 0, (int16_t)p->patch, (int16_t)p->patch}}, .block = p->patch,
                      .nparts = 1 + p->guides};
  s.part[0] = (ts_part){TS_SRC_FINE, 0, (uint8_t)pl->nstyle,
                        (uint32_t)llround(p->style_weight * TS_STYLIT_WEIGHT_STEPS / pl->nstyle)};
  int plane = pl->nstyle;
  for (int k = 0; k < p->guides; k++) {
    int ng = pl->nguide[k];
    s.part[1 + k] = (ts_part){TS_SRC_FINE, (uint8_t)plane, (uint8_t)ng,
                              (uint32_t)llround(ts_stylit_weight(p, k) * TS_STYLIT_WEIGHT_STEPS / ng)};
    plane += ng;
  }
  return ts_window_init(win, &s, err);
}

/* Ω: per source pixel, the target patches whose source patch covers it. */
void ts_stylit_occurrences(const uint32_t *nnf, size_t n, int r, int sw, uint32_t *counts, size_t ncounts) {
  memset(counts, 0, ncounts * sizeof(*counts));
  for (size_t i = 0; i < n; i++)
    for (int y = (int)nnf[2 * i + 1] - r; y <= (int)nnf[2 * i + 1] + r; y++)
      for (int x = (int)nnf[2 * i] - r; x <= (int)nnf[2 * i] + r; x++) counts[(size_t)y * (size_t)sw + (size_t)x]++;
}

void ts_stylit_vote(const uint32_t *nnf, int tw, int th, int r, const ts_plane *src, int n, uint8_t *const *out) {
  for (int y = 0; y < th; y++)
    for (int x = 0; x < tw; x++) {
      uint32_t sum[TS_WIN_MAX_PLANES] = {0}, votes = 0;
      for (int cy = y - r < 0 ? 0 : y - r; cy <= y + r && cy < th; cy++)
        for (int cx = x - r < 0 ? 0 : x - r; cx <= x + r && cx < tw; cx++) {
          const uint32_t *c = &nnf[2 * ((size_t)cy * (size_t)tw + (size_t)cx)];
          size_t at = ((size_t)c[1] + (size_t)(y - cy)) * (size_t)src[0].w + (size_t)c[0] + (size_t)(x - cx);
          for (int k = 0; k < n; k++) sum[k] += src[k].px[at];
          votes++;
        }
      for (int k = 0; k < n; k++) out[k][(size_t)y * (size_t)tw + (size_t)x] = (uint8_t)((sum[k] + votes / 2) / votes);
    }
}

int ts_stylit_pad(const ts_plane *const *t, int n, int r, ts_plane *pad) {
  int tw = t[0]->w, th = t[0]->h, pw = tw + 2 * r, ph = th + 2 * r;
  for (int k = 0; k < n; k++) {
    if (ts_plane_alloc(&pad[k], pw, ph) != 0) return TS_ENOMEM;
    for (int y = 0; y < ph; y++)
      for (int x = 0; x < pw; x++)
        pad[k].px[(size_t)y * (size_t)pw + (size_t)x] =
            ts_plane_at(t[k], (int)clampu(x - r, 0, tw - 1), (int)clampu(y - r, 0, th - 1));
  }
  return 0;
}

/* ---- set-up ------------------------------------------------------------ */

/* Every plane's pyramid, source and target; the style estimate's planes
 * at the target's sizes are made per level. */
static int build_pyramids(run *e) {
  for (int k = 0; k < e->pl.nplanes; k++) {
    if (ts_pyramid_build(&e->pl.src[k], e->levels, e->src[k]) != 0) return TS_ENOMEM;
    if (k >= e->pl.nstyle && ts_pyramid_build(&e->pl.tgt[k], e->levels, e->tgt[k]) != 0) return TS_ENOMEM;
  }
  return 0;
}

static int build_window(run *e, char *err) {
  int rc = ts_stylit_window(&e->win, e->p, &e->pl, err);
  if (rc == 0) e->d1 = ts_window_unit_distance(&e->win);
  return rc;
}

/* ---- the NNF ----------------------------------------------------------- */

/* The coarsest level's: seeded random source patches. */
static void nnf_random(run *e) {
  ts_rng rng;
  ts_rng_seed(&rng, e->p->seed, 0);
  uint32_t nx = (uint32_t)(e->sw - 2 * e->r), ny = (uint32_t)(e->sh - 2 * e->r);
  for (size_t i = 0; i < (size_t)e->tw * (size_t)e->th; i++) {
    e->nnf[2 * i] = (uint32_t)e->r + ts_rng_below(&rng, nx);
    e->nnf[2 * i + 1] = (uint32_t)e->r + ts_rng_below(&rng, ny);
  }
}

/* The level above's, doubled: each pixel keeps its offset in its 2 x 2
 * cell, clamped to the source patches' centres. */
static void nnf_upsample(run *e, const uint32_t *prev, int pw, int ph) {
  for (int y = 0; y < e->th; y++)
    for (int x = 0; x < e->tw; x++) {
      int cx = x / 2 < pw ? x / 2 : pw - 1, cy = y / 2 < ph ? y / 2 : ph - 1;
      const uint32_t *c = &prev[2 * ((size_t)cy * (size_t)pw + (size_t)cx)];
      uint32_t *o = &e->nnf[2 * ((size_t)y * (size_t)e->tw + (size_t)x)];
      o[0] = clampu(2L * c[0] + (x - 2 * cx), e->r, e->sw - 1 - e->r);
      o[1] = clampu(2L * c[1] + (y - 2 * cy), e->r, e->sh - 1 - e->r);
    }
}

static int build_omega(run *e) {
  size_t n = (size_t)e->sw * (size_t)e->sh;
  uint32_t *counts = malloc(n * sizeof(*counts));
  if (counts == NULL) return TS_ENOMEM;
  ts_stylit_occurrences(e->nnf, (size_t)e->tw * (size_t)e->th, e->r, e->sw, counts, n);
  ts_usage_load(&e->omega, counts);
  free(counts);
  return 0;
}

/* ---- the vote ---------------------------------------------------------- */

/* The style estimate of this level from its NNF. */
static void vote_estimate(run *e) {
  uint8_t *out[TS_WIN_MAX_PLANES];
  ts_plane planes[TS_WIN_MAX_PLANES]; /* the style's planes at this level, side by side */
  for (int k = 0; k < e->pl.nstyle; k++) {
    planes[k] = e->src[k][e->level];
    out[k] = e->est[k].px;
  }
  ts_stylit_vote(e->nnf, e->tw, e->th, e->r, planes, e->pl.nstyle, out);
}

/* ---- the search step --------------------------------------------------- */

/* The query image of this estimate (the style estimate, then the
 * guides). */
static int padded_planes(const run *e, ts_plane *pad) {
  const ts_plane *t[TS_WIN_MAX_PLANES];
  for (int k = 0; k < e->pl.nplanes; k++) t[k] = k < e->pl.nstyle ? &e->est[k] : &e->tgt[k][e->level];
  return ts_stylit_pad(t, e->pl.nplanes, e->r, pad);
}

static void report_progress(run *e, uint64_t n) {
  e->prog.done += n;
  e->prog.work_done += (double)n * ldexp(1.0, -2 * e->level);
  if (e->h != NULL && e->h->progress != NULL) e->h->progress(e->h->progress_ctx, &e->prog);
}

/* The n queries at pos against the set, BATCHES_PER_CALL batches a call,
 * all with the penalty of Ω as it is. */
static int query_set(run *e, int set, const uint32_t *pos, size_t n, ts_l1_best *best, char *err) {
  uint64_t k = e->lambda > 0 ? ts_usage_factor(&e->omega, e->lambda, e->d1) : 0;
  ts_l1_best_reset(best, n);
  for (size_t i0 = 0; i0 < n;) {
    ts_search_req req[BATCHES_PER_CALL];
    uint32_t nr = 0;
    size_t start = i0;
    for (; nr < BATCHES_PER_CALL && i0 < n; nr++, i0 += BATCH) {
      uint32_t nq = (uint32_t)(n - i0 < BATCH ? n - i0 : BATCH);
      req[nr] = (ts_search_req){set, {nq, pos + i0, 0, NULL, k}, best + i0};
    }
    int rc = ts_search_query_many(e->search, req, nr, err);
    if (rc != 0) return rc;
    report_progress(e, (i0 < n ? i0 : n) - start);
  }
  return 0;
}

/* The target pixels of sub-step c (row-major; all of them with one
 * sub-step): their NNF indices and query positions (pw: the query
 * image's width). */
static size_t substep_pixels(const run *e, int c, int substeps, int pw, uint32_t *idx, uint32_t *pos) {
  size_t n = 0;
  for (int y = 0; y < e->th; y++)
    for (int x = 0; x < e->tw; x++) {
      if (substeps > 1 && (y % SUBSTEP_SIDE) * SUBSTEP_SIDE + x % SUBSTEP_SIDE != c) continue;
      idx[n] = (uint32_t)((size_t)y * (size_t)e->tw + (size_t)x);
      pos[n++] = (uint32_t)((size_t)y * (size_t)pw + (size_t)x);
    }
  return n;
}

/* The answers into the NNF; Ω follows each patch from its old source
 * patch to its new one. */
static void take_answers(run *e, const uint32_t *idx, const ts_l1_best *best, size_t n) {
  int p = e->patch;
  for (size_t i = 0; i < n; i++) {
    uint32_t *o = &e->nnf[2 * (size_t)idx[i]];
    int x, y;
    ts_anchors_pos(&e->grid, best[i].index, &x, &y);
    ts_usage_commit(&e->omega, (int)o[0] - e->r, (int)o[1] - e->r, p, p, -1);
    ts_usage_commit(&e->omega, x, y, p, p, 1);
    o[0] = (uint32_t)(x + e->r);
    o[1] = (uint32_t)(y + e->r);
  }
}

/* The sub-steps of a search step on one query image: a set per sub-step,
 * carrying Ω as it is then. */
static int search_substeps(run *e, int image, int pw, char *err) {
  size_t n = (size_t)e->tw * (size_t)e->th;
  ts_l1_best *best = malloc(n * sizeof(*best));
  uint32_t *pos = malloc(n * sizeof(*pos)), *idx = malloc(n * sizeof(*idx));
  int rc = best != NULL && pos != NULL && idx != NULL ? 0 : ts_error(err, TS_ENOMEM, "out of memory");
  ts_levelplanes lp = {{NULL}, {NULL}};
  for (int k = 0; k < e->pl.nplanes; k++) lp.fine[k] = &e->src[k][e->level];
  int substeps = e->lambda > 0 ? SUBSTEP_SIDE * SUBSTEP_SIDE : 1;
  for (int c = 0; rc == 0 && c < substeps; c++) {
    size_t nc = substep_pixels(e, c, substeps, pw, idx, pos);
    ts_refset rs = {image, &e->win, &e->grid, &lp, NULL, NULL, e->lambda > 0, &e->omega};
    int set = -1;
    rc = ts_search_prepare(e->search, &rs, &set, err);
    if (rc == 0) rc = query_set(e, set, pos, nc, best, err);
    if (set >= 0) ts_search_release(e->search, set);
    if (rc == 0) take_answers(e, idx, best, nc);
  }
  free(best);
  free(pos);
  free(idx);
  return rc;
}

/* One search step: the query image of this estimate, every target patch
 * searched, the NNF and Ω renewed. */
static int search_step(run *e, char *err) {
  ts_plane pad[TS_WIN_MAX_PLANES] = {0};
  int pw = e->tw + 2 * e->r, image = -1;
  int rc = padded_planes(e, pad);
  if (rc != 0) rc = ts_error(err, TS_ENOMEM, "out of memory for a %dx%d target", e->tw, e->th);
  ts_replica_desc d = {.w = pw, .h = e->th + 2 * e->r, .nplanes = e->pl.nplanes};
  for (int k = 0; k < e->pl.nplanes; k++) d.fine[k] = pad[k].px;
  if (rc == 0) rc = ts_search_image_open(e->search, &d, &image, err);
  if (rc == 0) rc = search_substeps(e, image, pw, err);
  if (image >= 0) ts_search_image_close(e->search, image);
  for (int k = 0; k < e->pl.nplanes; k++) ts_plane_free(&pad[k]);
  return rc;
}

/* ---- the patchmatch search step ------------------------------------------ */

/* The pass seed of a level: the job's seed with the level mixed in (each
 * pass and tile then draw from their own stream of it, patchmatch.h). */
static uint64_t level_seed(const run *e) { return e->p->seed ^ (0x9E3779B97F4A7C15ull * (uint64_t)(e->level + 1)); }

/* One search step in patchmatch passes against the level's field set: the
 * query image of this estimate, pm_iters passes, the NNF renewed. Passes
 * are numbered through the level, so their directions alternate across
 * steps too. */
static int search_step_pm(run *e, int set, int it, uint32_t *spare, char *err) {
  ts_plane pad[TS_WIN_MAX_PLANES] = {0};
  int image = -1, rc = padded_planes(e, pad);
  if (rc != 0) rc = ts_error(err, TS_ENOMEM, "out of memory for a %dx%d target", e->tw, e->th);
  ts_replica_desc d = {.w = e->tw + 2 * e->r, .h = e->th + 2 * e->r, .nplanes = e->pl.nplanes};
  for (int k = 0; k < e->pl.nplanes; k++) d.fine[k] = pad[k].px;
  if (rc == 0) rc = ts_search_image_open(e->search, &d, &image, err);
  for (int q = 0; rc == 0 && q < e->p->pm_iters; q++) {
    ts_field_pass fp = {set, image, e->tw, e->th, e->nnf, spare, e->usage_k, level_seed(e),
                        (uint32_t)(it * e->p->pm_iters + q)};
    rc = ts_search_field_pass(e->search, &fp, err);
    if (rc == 0) {
      memcpy(e->nnf, spare, 2 * sizeof(uint32_t) * (size_t)e->tw * (size_t)e->th);
      report_progress(e, (uint64_t)e->tw * (uint64_t)e->th / (uint64_t)e->p->pm_iters);
    }
  }
  if (image >= 0) ts_search_image_close(e->search, image);
  for (int k = 0; k < e->pl.nplanes; k++) ts_plane_free(&pad[k]);
  return rc;
}

/* A level's EM iterations with patchmatch: the source is prepared once as
 * a field set (held whole by every holder) and searched pass by pass. */
static int iterate_pm(run *e, char *err) {
  ts_levelplanes lp = {{NULL}, {NULL}};
  for (int k = 0; k < e->pl.nplanes; k++) lp.fine[k] = &e->src[k][e->level];
  ts_refset rs = {.image = -1, .window = &e->win, .anchors = &e->grid, .ref = &lp, .field = 1};
  int set = -1, rc = ts_search_prepare(e->search, &rs, &set, err);
  uint32_t *spare = malloc(2 * sizeof(uint32_t) * (size_t)e->tw * (size_t)e->th);
  if (rc == 0 && spare == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory");
  e->usage_k = e->lambda > 0 ? ts_usage_factor(&e->omega, e->lambda, e->d1) : 0;
  for (int it = 0; rc == 0 && it < e->p->iters; it++) {
    vote_estimate(e);
    rc = search_step_pm(e, set, it, spare, err);
  }
  if (set >= 0) ts_search_release(e->search, set);
  free(spare);
  return rc;
}

static int iterate_exact(run *e, char *err) {
  int rc = 0;
  for (int it = 0; rc == 0 && it < e->p->iters; it++) {
    vote_estimate(e);
    rc = search_step(e, err);
  }
  return rc;
}

/* ---- levels ------------------------------------------------------------ */

static void level_free(run *e) {
  ts_usage_free(&e->omega);
  ts_anchors_free(&e->grid);
  for (int k = 0; k < e->pl.nstyle; k++) ts_plane_free(&e->est[k]);
}

/* The level's sizes, source patches, estimate planes, NNF and Ω. */
static int level_start(run *e, int l, char *err) {
  uint32_t *prev = e->nnf;
  int pw = e->tw, ph = e->th;
  e->level = l;
  e->sw = e->src[0][l].w;
  e->sh = e->src[0][l].h;
  e->tw = e->tgt[e->pl.nstyle][l].w;
  e->th = e->tgt[e->pl.nstyle][l].h;
  size_t n = (size_t)e->tw * (size_t)e->th;
  e->nnf = malloc(2 * n * sizeof(uint32_t));
  int rc = e->nnf != NULL ? 0 : TS_ENOMEM;
  for (int k = 0; rc == 0 && k < e->pl.nstyle; k++) rc = ts_plane_alloc(&e->est[k], e->tw, e->th);
  if (rc != 0) {
    free(prev);
    return ts_error(err, TS_ENOMEM, "out of memory for level %d (%dx%d)", l, e->tw, e->th);
  }
  if (prev == NULL) nnf_random(e);
  else nnf_upsample(e, prev, pw, ph);
  free(prev);
  rc = ts_anchors_init(&e->grid, &e->win, e->sw, e->sh, 0, 0, NULL, 1, NULL, err);
  if (rc == 0 && (ts_usage_init(&e->omega, &e->grid, e->patch, 0) != 0 || build_omega(e) != 0))
    rc = ts_error(err, TS_ENOMEM, "out of memory for the occurrence map");
  e->prog.level = l;
  e->prog.done = 0;
  e->prog.total = (uint64_t)n * (uint64_t)e->p->iters;
  return rc;
}

/* The comparisons an exact level makes: every target patch against every
 * source patch, per iteration. */
static double exact_pairs(const run *e, int l) {
  const ts_plane *s = &e->src[0][l], *t = &e->tgt[e->pl.nstyle][l];
  return (double)t->w * t->h * (double)(s->w - e->patch + 1) * (s->h - e->patch + 1) * e->p->iters;
}

/* Auto's rate when the backend knows none: slower than any machine. */
#define AUTO_UNKNOWN_RATE 1e8

/* Every level's mode, before any runs: size's and auto's are exact where
 * the level's comparisons at the rate (comparisons a second: size's fixed
 * one, or auto's from the backend's calibrated rate in bytes of vectors a
 * second, over this window's bytes) fit the budget. Returns the rate. */
static double plan_levels(run *e) {
  const ts_stylit_params *p = e->p;
  double rate = 0;
  if (p->search == TS_STYLIT_SIZE) rate = TS_STYLIT_SIZE_RATE;
  if (p->search == TS_STYLIT_AUTO) {
    rate = ts_search_rate(e->search) / ts_window_bytes(&e->win);
    if (!(rate > 0)) rate = AUTO_UNKNOWN_RATE;
  }
  for (int l = 0; l < e->levels; l++) {
    e->estimate[l] = rate > 0 ? exact_pairs(e, l) / rate : 0;
    if (p->search == TS_STYLIT_LIST) e->mode[l] = p->level_mode[e->levels - 1 - l];
    else if (rate > 0) e->mode[l] = e->estimate[l] <= p->budget ? TS_STYLIT_EXACT : TS_STYLIT_PATCHMATCH;
    else e->mode[l] = p->search;
  }
  return rate;
}

static int run_level(run *e, int l, ts_stylit_level_stats *st, char *err) {
  double t0 = ts_now();
  ts_search_stats s0 = e->search->stats;
  int mode = e->mode[l];
  int rc = level_start(e, l, err);
  if (rc == 0) rc = mode == TS_STYLIT_EXACT ? iterate_exact(e, err) : iterate_pm(e, err);
  level_free(e);
  *st = (ts_stylit_level_stats){ts_now() - t0, e->search->stats.pairs - s0.pairs,
                                e->search->stats.queries - s0.queries, e->tw, e->th, mode, e->estimate[l]};
  return rc;
}

/* The work of all levels in level-0 query units (a query at level l scans
 * about 4^-l of level 0's source patches). */
static double total_work(const run *e) {
  double w = 0;
  for (int l = 0; l < e->levels; l++)
    w += (double)e->tgt[e->pl.nstyle][l].w * e->tgt[e->pl.nstyle][l].h * e->p->iters * ldexp(1.0, -2 * l);
  return w;
}

/* ---- the result -------------------------------------------------------- */

/* The output: every style channel voted by the finest NNF. */
static int make_result(run *e, ts_stylit_result *res, char *err) {
  int rc = ts_image_alloc(&res->image, e->tw, e->th, e->pl.nvote, TS_PIX_U8, err);
  size_t n = (size_t)e->tw * (size_t)e->th;
  uint8_t *planes = rc == 0 ? malloc(n * (size_t)e->pl.nvote) : NULL;
  uint32_t *counts = rc == 0 ? malloc((size_t)e->sw * (size_t)e->sh * sizeof(uint32_t)) : NULL;
  if (rc == 0 && (planes == NULL || counts == NULL)) rc = ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0) {
    uint8_t *out[TS_STYLIT_MAX_STYLE_CHANNELS];
    for (int c = 0; c < e->pl.nvote; c++) out[c] = planes + (size_t)c * n;
    ts_stylit_vote(e->nnf, e->tw, e->th, e->r, e->pl.vote, e->pl.nvote, out);
    uint8_t *px = res->image.pixels;
    for (size_t i = 0; i < n; i++)
      for (int c = 0; c < e->pl.nvote; c++) px[i * (size_t)e->pl.nvote + (size_t)c] = out[c][i];
    ts_stylit_occurrences(e->nnf, n, e->r, e->sw, counts, (size_t)e->sw * (size_t)e->sh);
    size_t used = 0;
    for (size_t i = 0; i < (size_t)e->sw * (size_t)e->sh; i++) used += counts[i] > 0;
    res->coverage = (double)used / ((double)e->sw * e->sh);
    res->nnf = e->nnf;
    e->nnf = NULL;
    res->src_w = e->sw;
    res->src_h = e->sh;
  }
  free(planes);
  free(counts);
  return rc;
}

static void run_free(run *e) {
  for (int k = 0; k < TS_WIN_MAX_PLANES; k++) {
    ts_pyramid_free(e->src[k], e->levels);
    ts_pyramid_free(e->tgt[k], e->levels);
  }
  ts_window_free(&e->win);
  ts_stylit_planes_free(&e->pl);
  free(e->nnf);
}

int ts_stylit_run(const ts_stylit_params *p, const ts_image *const *in, ts_search *search, const ts_progress_hooks *h,
                  ts_stylit_result *res, char *err) {
  memset(res, 0, sizeof(*res));
  double t0 = ts_now();
  run *e = calloc(1, sizeof(*e));
  if (e == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  *e = (run){.p = p, .search = search, .h = h, .levels = ts_stylit_levels(p, in), .patch = p->patch,
             .r = p->patch / 2, .lambda = p->uniformity};
  int rc = ts_stylit_planes_init(&e->pl, p, in);
  if (rc == 0) rc = build_pyramids(e);
  if (rc != 0) rc = ts_error(err, TS_ENOMEM, "out of memory for the inputs' pyramids");
  if (rc == 0) rc = build_window(e, err);
  e->prog = (ts_progress){.levels = e->levels, .work_total = rc == 0 ? total_work(e) : 0};
  if (rc == 0) res->rate = plan_levels(e);
  for (int l = e->levels - 1; rc == 0 && l >= 0; l--) rc = run_level(e, l, &res->level[l], err);
  res->levels = e->levels;
  if (rc == 0) rc = make_result(e, res, err);
  res->seconds = ts_now() - t0;
  run_free(e);
  free(e);
  if (rc != 0) ts_stylit_result_free(res);
  return rc;
}

void ts_stylit_result_free(ts_stylit_result *res) {
  ts_image_free(&res->image);
  free(res->nnf);
  res->nnf = NULL;
}
