/* mrf.c - see mrf.h.
 *
 * Per level, coarsest first (seed 002 §3.3): the canvas starts as noise
 * drawn from the reference histogram (coarsest level, §3.4, seeded) or as
 * the copy-map prediction of the level above; a skewed wavefront of blocks
 * scans it with the causal L-shaped multi-scale neighbourhood (§3.4,
 * schedule.h), where a window wraps onto blocks placed earlier it uses them
 * too (masked full window), and refinement sweeps revisit the blocks with
 * their full windows. Each block copies the reference block whose
 * neighbourhood is nearest in weighted L1 (+ the usage penalty, §3.7.2).
 * Colour is gathered through the final copy map (§3.8).
 *
 * Beyond the plain method, from the seed: passive usage-variance
 * optimisation (§3.7.1: best-of candidate seeds through the coarse levels),
 * texture mixing (§4.3: the finer levels from a second reference) and the
 * copy-map shortcut (§3.6.6, lossy, mrf_accel.h). */
#include "mrf.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "error.h"
#include "param.h"
#include "util.h"
#include "mrf_accel.h"
#include "plane.h"
#include "replica.h"
#include "rng.h"
#include "schedule.h"
#include "usage.h"



static int nplanes_for(const ts_mrf_params *p, int channels) {
  if (!p->rgb_search || channels < 3) return 1;
  return 3;
}

/* Level sizes: the reference halves with floor (eq. 2.3), the canvas with
 * ceil so every output size works on the torus. */
static void level_sizes(int w, int h, int levels, int *lw, int *lh, int ceil_mode) {
  lw[0] = w;
  lh[0] = h;
  for (int l = 1; l < levels; l++) {
    lw[l] = ceil_mode ? (lw[l - 1] + 1) / 2 : lw[l - 1] / 2;
    lh[l] = ceil_mode ? (lh[l - 1] + 1) / 2 : lh[l - 1] / 2;
  }
}

int ts_mrf_levels_that_fit(int w, int h, int wn, int most) {
  int l = 1;
  for (; l < most && l < TS_MRF_MAX_LEVELS; l++) {
    w = (w + 1) / 2;
    h = (h + 1) / 2;
    if (w < wn || h < wn) break;
  }
  return l;
}

/* How a reference too small for its levels is named and what fixes it. */
typedef struct {
  const char *option, *name, *fix;
  int value;
} ref_words;

/* Checks that a ref_w x ref_h reference holds the window (and, but at the
 * coarsest level, its coarse part one level up) at levels lo..hi. */
static void check_reference_levels(const ts_mrf_params *p, int ref_w, int ref_h, int lo, int hi,
                                   const ref_words *words, char *msg, size_t len, int *count) {
  int rw[TS_MRF_MAX_LEVELS], rh[TS_MRF_MAX_LEVELS];
  level_sizes(ref_w, ref_h, p->levels, rw, rh, 0);
  for (int l = hi; l >= lo; l--) {
    ts_window s;
    ts_anchors g;
    char err[TS_ERR_LEN];
    int coarse = l < p->levels - 1;
    if (ts_neigh_window(&s, TS_SHAPE_SQUARE, p->wn, p->wb, coarse, 1, p->coarse_weight, err) != 0) return;
    /* With parity, every class needs an anchor: two columns and rows. */
    int bad = rw[l] < 1 || rh[l] < 1 ||
              ts_anchors_init(&g, &s, rw[l], rh[l], coarse ? rw[l + 1] : 0, coarse ? rh[l + 1] : 0, NULL, 1, NULL,
                              err) != 0 ||
              (p->parity && (g.nx < 2 || g.ny < 2));
    ts_window_free(&s);
    if (bad) {
      ts_problem(msg, len, count,
              "%s %d: %s (%dx%d) is %dx%d at level %d, too small for a %dx%d neighbourhood%s; use %s",
              words->option, words->value, words->name, ref_w, ref_h, rw[l], rh[l], l, p->wn, p->wn,
              p->parity ? " in every parity class" : "", words->fix);
      return;
    }
  }
}

/* The options of best-of, mixing and the copy-map shortcut. */
static void check_extras(const ts_mrf_params *p, char *msg, size_t len, int *n) {
  int levels_ok = p->levels >= 1 && p->levels <= TS_MRF_MAX_LEVELS;
  if (levels_ok && p->best_of_levels > p->levels)
    ts_problem(msg, len, n, "--best-of-levels %d: need 1..%d (--levels), or 0 for all but the finest two",
            p->best_of_levels, p->levels);
  if (p->best_of_levels != 0 && p->best_of == 1)
    ts_problem(msg, len, n, "--best-of-levels needs --best-of K with K > 1");
  if (levels_ok && p->mix_level >= p->levels)
    ts_problem(msg, len, n, "--mix-level %d: need 1..%d (below --levels; 0 = no mixing)", p->mix_level,
            p->levels - 1);
  if (!p->copy_accel && (p->accel_kernel != 0 || p->accel_min != 0.95))
    ts_problem(msg, len, n, "--copy-accel-kernel and --copy-accel-min need --copy-accel");
}

/* The partitioning options: a count of partitions, a probe of at most as
 * many, levels the job has; none of them without --lbg. */
static void check_lbg(const ts_mrf_params *p, char *msg, size_t len, int *count) {
  if (p->lbg == 0 && (p->lbg_probe != 1 || p->lbg_exact || p->lbg_levels != 1))
    ts_problem(msg, len, count, "--lbg-probe, --lbg-levels and --lbg-exact need --lbg P (the partitions)");
  else if (p->lbg > 0 && p->lbg_probe > p->lbg)
    ts_problem(msg, len, count, "--lbg-probe %d: need 1..%d (at most the --lbg partitions)", p->lbg_probe, p->lbg);
  if (p->lbg > 0 && p->lbg_levels != TS_MRF_LBG_ALL && p->levels >= 1 && p->levels <= TS_MRF_MAX_LEVELS &&
      (p->lbg_levels >> p->levels) != 0)
    ts_problem(msg, len, count, "--lbg-levels names level %d, but --levels %d has levels 0..%d",
            31 - __builtin_clz(p->lbg_levels), p->levels, p->levels - 1);
}

int ts_mrf_check(const ts_mrf_params *p, int ref_w, int ref_h, int channels,
                 char *msg, size_t len) {
  int n = 0;
  msg[0] = '\0';
  if (p->width < 1 || p->height < 1)
    ts_problem(msg, len, &n, "--size %dx%d: width and height must be at least 1", p->width, p->height);
  else if ((uint64_t)p->width * (uint64_t)p->height > p->max_pixels)
    ts_problem(msg, len, &n, "--size %dx%d: %llu pixels exceed the limit of %llu (raise --max-pixels)",
            p->width, p->height, (unsigned long long)p->width * p->height,
            (unsigned long long)p->max_pixels);
  ts_params_check(ts_mrf_param_table, p, msg, len, &n);
  if (n == 0 && p->wn < p->wb + 2)
    ts_problem(msg, len, &n, "--wn %d: the neighbourhood must be wider than the block (--wb %d), at least %d",
            p->wn, p->wb, p->wb + 2);
  if (p->levels >= 1 && p->levels <= TS_MRF_MAX_LEVELS && p->stop_level >= p->levels)
    ts_problem(msg, len, &n, "--stop-level %d: need 0..%d (below --levels)", p->stop_level, p->levels - 1);
  if (channels < 1 || channels > 16)
    ts_problem(msg, len, &n, "reference has %d channels: need 1..16", channels);
  check_extras(p, msg, len, &n);
  check_lbg(p, msg, len, &n);
  if (n > 0) return TS_EINVAL; /* the checks below need sane parameters */
  int cw[TS_MRF_MAX_LEVELS], ch[TS_MRF_MAX_LEVELS];
  level_sizes(p->width, p->height, p->levels, cw, ch, 1);
  int top = p->levels - 1;
  if (cw[top] < p->wn || ch[top] < p->wn)
    ts_problem(msg, len, &n,
            "--levels %d: the output is only %dx%d at the coarsest level, smaller than the "
            "%dx%d neighbourhood; use fewer levels or a larger --size",
            p->levels, cw[top], ch[top], p->wn, p->wn);
  if (ref_w < p->wn || ref_h < p->wn)
    ts_problem(msg, len, &n, "the reference (%dx%d) is smaller than the %dx%d neighbourhood", ref_w,
            ref_h, p->wn, p->wn);
  else {
    /* With mixing the reference makes only the levels from mix_level up. */
    ref_words words = {"--levels", "the reference", "fewer levels, a smaller --wn or a larger reference",
                       p->levels};
    check_reference_levels(p, ref_w, ref_h, p->mix_level, p->levels - 1, &words, msg, len, &n);
  }
  return n > 0 ? TS_EINVAL : 0;
}

/* Whether the parameters the reference checks rest on are sane (ts_mrf_check
 * names those that are not). */
static int geometry_sane(const ts_mrf_params *p) {
  return p->wb >= 1 && p->wb % 2 == 1 && p->wb <= 15 && p->wn % 2 == 1 && p->wn >= p->wb + 2 &&
         p->wn <= TS_MAX_WN && p->levels >= 1 && p->levels <= TS_MRF_MAX_LEVELS && p->mix_level >= 1 &&
         p->mix_level < p->levels;
}

int ts_mrf_check_fine(const ts_mrf_params *p, int fine_w, int fine_h, int fine_channels, int ref_channels,
                      char *msg, size_t len) {
  int n = msg[0] != '\0', before = n;
  if (fine_channels < 1 || fine_channels > 16)
    ts_problem(msg, len, &n, "--ref-fine has %d channels: need 1..16", fine_channels);
  else if (nplanes_for(p, fine_channels) != nplanes_for(p, ref_channels))
    ts_problem(msg, len, &n,
            "--rgb-search: the reference has %d channels and the --ref-fine image %d; both need 3 or more "
            "(or drop --rgb-search to search on luminance)", ref_channels, fine_channels);
  if (geometry_sane(p) && (fine_w < p->wn || fine_h < p->wn))
    ts_problem(msg, len, &n, "the --ref-fine image (%dx%d) is smaller than the %dx%d neighbourhood", fine_w, fine_h,
            p->wn, p->wn);
  else if (geometry_sane(p)) {
    /* Its levels below mix_level, each with its coarse part one level up. */
    ref_words words = {"--mix-level", "the --ref-fine image",
                       "a lower --mix-level, a smaller --wn or a larger --ref-fine image", p->mix_level};
    check_reference_levels(p, fine_w, fine_h, 0, p->mix_level - 1, &words, msg, len, &n);
  }
  return n > before ? TS_EINVAL : 0;
}

/* ---- engine state ------------------------------------------------------ */

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

static void group_free(query_group *g) {
  free(g->pos);
  free(g->klass);
  free(g->block);
  free(g->best);
  memset(g, 0, sizeof(*g));
}

static int ensure_step_scratch(engine *e, uint32_t n) {
  if (n <= e->cap) return 0;
  free(e->places);
  free(e->direct);
  e->places = malloc(sizeof(ts_place) * n);
  e->direct = malloc(sizeof(uint32_t) * n);
  int ok = e->places != NULL && e->direct != NULL;
  for (int k = 0; k < 2; k++) {
    query_group *g = &e->group[k];
    group_free(g);
    g->pos = malloc(sizeof(uint32_t) * n);
    g->klass = malloc(n);
    g->block = malloc(sizeof(uint32_t) * n);
    g->best = malloc(sizeof(ts_l1_best) * n);
    ok = ok && g->pos && g->klass && g->block && g->best;
  }
  e->cap = ok ? n : 0;
  return ok ? 0 : TS_ENOMEM;
}

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
static uint64_t level_blocks(const ts_mrf_params *p, int l, int w, int h) {
  uint64_t rows = (uint64_t)(h + p->wb - 1) / p->wb, cols = (uint64_t)(w + p->wb - 1) / p->wb;
  uint64_t n = rows * cols;
  sweep_pass pass[2];
  for (int i = 0, k = level_sweeps(p, l, pass); i < k; i++)
    n += band_blocks(rows, cols, (uint64_t)pass[i].band) * (uint64_t)pass[i].count;
  return n;
}

static void plan_free(level_plan *pl) {
  for (int i = 0; i < pl->n; i++) ts_schedule_free(&pl->phase[i].sched);
  memset(pl, 0, sizeof(*pl));
}

static int plan_level(level_plan *pl, const ts_mrf_params *p, int l, int w, int h) {
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
  if (rc != 0) plan_free(pl);
  return rc;
}

/* Calls fn on every block of the plan's first `steps` steps, in order. */
static void plan_walk(const level_plan *pl, uint64_t steps, void (*fn)(void *ctx, const ts_block *b), void *ctx) {
  for (int i = 0; i < pl->n && steps > 0; i++) {
    const ts_schedule *s = &pl->phase[i].sched;
    for (int r = 0; r < pl->phase[i].reps && steps > 0; r++) {
      uint32_t t = steps < s->nsteps ? (uint32_t)steps : s->nsteps;
      for (uint32_t b = 0; b < s->step_start[t]; b++) fn(ctx, &s->blocks[b]);
      steps -= t;
    }
  }
}

/* Fills the coarsest level's canvas with reference pixels from uniformly
 * random positions (noise with the reference histogram, §3.4, seeded). */
static void init_noise(engine *e) {
  ts_rng rng;
  ts_rng_seed(&rng, e->seed, (uint64_t)e->level);
  const ts_plane *r0 = e->ref_lp.fine[0];
  int w = e->cw[e->level], h = e->ch[e->level];
  for (long i = 0; i < (long)w * h; i++) {
    int x = (int)ts_rng_below(&rng, (uint32_t)r0->w);
    int y = (int)ts_rng_below(&rng, (uint32_t)r0->h);
    for (int p = 0; p < e->nplanes; p++) e->canvas[p][e->level].px[i] = ts_plane_at(e->ref_lp.fine[p], x, y);
    e->copy[2 * i] = (uint32_t)x;
    e->copy[2 * i + 1] = (uint32_t)y;
  }
}

/* Fills a finer level's canvas with the prediction of the coarser level's
 * copy map: every pixel from where its coarse pixel's source points, doubled
 * (the copy-map extrapolation of §3.6.6). Blocks are still all searched;
 * the prediction only stands in for what is not placed yet, so the first
 * row and column see around the torus what the last ones will likely
 * become (a better start for closing the torus than noise). */
static void init_prediction(engine *e) {
  int l = e->level, w = e->cw[l], h = e->ch[l];
  const ts_plane *r0 = e->ref_lp.fine[0];
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      int sx, sy;
      ts_copy_predict(e->prev_copy, e->cw[l + 1], e->ch[l + 1], w, h, r0->w, r0->h, x, y, &sx, &sy);
      long o = (long)y * w + x;
      for (int p = 0; p < e->nplanes; p++) e->canvas[p][l].px[o] = ts_plane_at(e->ref_lp.fine[p], sx, sy);
      e->copy[2 * o] = (uint32_t)sx;
      e->copy[2 * o + 1] = (uint32_t)sy;
    }
}

/* Whether level l is the first made from the fine reference (§4.3). */
static int mix_switch(const engine *e, int l) { return e->mix > 0 && l == e->mix - 1; }

/* The pyramid level l is made from: the fine reference's below the mix
 * level, the reference's from it up. Its level l is the fine part of the
 * vectors, its level l + 1 the coarse part; the coarse part of the queries
 * is the canvas above, so at the switch the coarse layout made from the
 * reference is matched against the fine reference's coarse level. */
static const ts_plane *level_refs(const engine *e, int k, int l) { return l < e->mix ? e->fine_ref[k] : e->ref[k]; }

/* Fills the first level made from the fine reference with that reference
 * laid out as tiles. The copy map above points into the other reference,
 * so there is nothing to predict from; as everywhere, the initial canvas
 * only stands in for what is not placed yet (what windows read across the
 * torus seam), where real texture serves better than noise. It needs no
 * seed: a best-of run's seed is spent at the coarsest level, so a run
 * resumed after the best-of choice, which does not know the chosen seed,
 * goes on as the uninterrupted run does. */
static void init_tiles(engine *e) {
  int l = e->level, w = e->cw[l], h = e->ch[l];
  const ts_plane *r0 = e->ref_lp.fine[0];
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      int sx = x % r0->w, sy = y % r0->h;
      long o = (long)y * w + x;
      for (int p = 0; p < e->nplanes; p++) e->canvas[p][l].px[o] = ts_plane_at(e->ref_lp.fine[p], sx, sy);
      e->copy[2 * o] = (uint32_t)sx;
      e->copy[2 * o + 1] = (uint32_t)sy;
    }
}

static double level_cost(int l) { return 1.0 / (double)(1ull << (2 * l)); }

/* Copies reference block (sx, sy) onto canvas block b; records the copy. */
static void place_block(engine *e, const ts_block *b, int sx, int sy) {
  int w = e->cw[e->level];
  for (int dy = 0; dy < b->h; dy++)
    for (int dx = 0; dx < b->w; dx++) {
      long o = (long)(b->y + dy) * w + (b->x + dx);
      for (int p = 0; p < e->nplanes; p++)
        e->canvas[p][e->level].px[o] = ts_plane_at(e->ref_lp.fine[p], sx + dx, sy + dy);
      e->copy[2 * o] = (uint32_t)(sx + dx);
      e->copy[2 * o + 1] = (uint32_t)(sy + dy);
      e->done[o] = 1;
    }
}

/* Whether block b is searched with the masked square window: when its
 * window holds pixels placed at this level outside the causal L, which
 * happens only where the window wraps around the torus onto placed blocks
 * (the last rows and columns) or meets a clipped block. The mask
 * (ts_vec_mask, read by the backend out of its replica of the canvas)
 * keeps the L (placed pixels, or still the initial noise or prediction)
 * and every placed pixel, never the pixels b writes. So the last row and
 * column also match the first ones across the seam. A block clipped at the
 * last row or column writes only part of its W_B square; the rest of the
 * square is ordinary neighbourhood. In a refinement sweep (refine = 1)
 * every block is searched this way, seeing all of its window but itself. */
static int masked_query(engine *e, const ts_block *b, int refine) {
  int w = e->cw[e->level], h = e->ch[e->level];
  int wb = e->p->wb, hn = (e->p->wn - wb) / 2;
  if (refine) return 1;
  /* During the scan, a whole block whose window does not wrap sees exactly
   * its L placed (schedule.h): the plain query, without looking. */
  if (b->w == wb && b->h == wb && b->x >= hn && b->y >= hn && b->x + wb + hn <= w && b->y + wb + hn <= h) return 0;
  return ts_vec_mask(&e->shape[SHAPE_MASKED], e->done, w, h, 1, b->x, b->y, e->mask);
}

/* Parity control (seed 002 §3.3.3): a block at (x, y) copies only from
 * reference blocks of the same (x & 1, y & 1): its class. */
static int parity_class(int x, int y) { return (x & 1) | (y & 1) << 1; }

/* The reference level's parity classes as the anchors' label plane. */
static int parity_plane(ts_plane *p, int w, int h) {
  if (ts_plane_alloc(p, w, h) != 0) return TS_ENOMEM;
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) p->px[(size_t)y * (size_t)w + (size_t)x] = (uint8_t)parity_class(x, y);
  return 0;
}

/* Sorts the blocks of a step into the two query groups, and the blocks
 * the copy-map shortcut copies: placed from their prediction in the scan,
 * left as they are by the sweeps. */
static void build_queries(engine *e, const ts_block *blocks, uint32_t n, int refine) {
  e->group[SHAPE_PLAIN].n = e->group[SHAPE_MASKED].n = 0;
  e->ndirect = 0;
  for (uint32_t i = 0; i < n; i++) {
    const ts_block *b = &blocks[i];
    int sx, sy;
    if (ts_accel_block(&e->accel, b->x, b->y, TS_ACCEL_COPY, &sx, &sy)) {
      e->res->accel[e->level].searches_saved++;
      if (!refine) e->direct[e->ndirect++] = i;
      continue;
    }
    query_group *g = &e->group[masked_query(e, b, refine) ? SHAPE_MASKED : SHAPE_PLAIN];
    g->pos[g->n] = (uint32_t)b->y * (uint32_t)e->cw[e->level] + (uint32_t)b->x;
    g->klass[g->n] = e->p->parity ? (uint8_t)parity_class(b->x, b->y) : 0;
    g->block[g->n++] = i;
  }
}

/* Searches both groups of a step, each split into batches of at most
 * max_batch, as one set of independent requests (one round trip on a
 * remote backend). One penalty snapshot per step, however it is split. */
#define STEP_MAX_REQS 32
static int search_step(engine *e, const uint64_t d1[2], char *err) {
  ts_search_req req[STEP_MAX_REQS];
  uint32_t nr = 0;
  for (int k = 0; k < 2; k++) {
    query_group *g = &e->group[k];
    uint64_t usage_k = e->p->usage_weight > 0 ? ts_usage_factor(&e->usage, e->p->usage_weight, d1[k]) : 0;
    uint32_t chunk = e->p->max_batch ? e->p->max_batch : (g->n ? g->n : 1);
    for (uint32_t i0 = 0; i0 < g->n; i0 += chunk) {
      uint32_t m = g->n - i0 < chunk ? g->n - i0 : chunk;
      ts_search_req r = {e->set_ids[k], {m, g->pos + i0, k == SHAPE_MASKED, g->klass + i0, usage_k}, g->best + i0};
      req[nr++] = r;
      if (nr == STEP_MAX_REQS) {
        int rc = ts_search_query_many(e->search, req, nr, err);
        if (rc != 0) return rc;
        nr = 0;
      }
    }
  }
  return nr ? ts_search_query_many(e->search, req, nr, err) : 0;
}

/* Places every block of the step, here and on the backend's replica of
 * the canvas, which counts the copies in its sets' usage replicas as this
 * does: in a refinement sweep the copy a block replaces leaves the usage
 * counts. */
static void place_counted(engine *e, const ts_block *b, int sx, int sy, int refine, uint32_t *np) {
  long o = (long)b->y * e->cw[e->level] + b->x;
  if (refine) ts_usage_commit(&e->usage, (int)e->copy[2 * o], (int)e->copy[2 * o + 1], b->w, b->h, -1);
  place_block(e, b, sx, sy);
  ts_usage_commit(&e->usage, sx, sy, b->w, b->h, 1);
  e->places[(*np)++] = (ts_place){(uint32_t)o, (uint32_t)sy * (uint32_t)e->grid.w + (uint32_t)sx};
}

static int place_step(engine *e, const ts_block *blocks, int refine, char *err) {
  uint32_t np = 0;
  for (int k = 0; k < 2; k++) {
    const query_group *g = &e->group[k];
    for (uint32_t i = 0; i < g->n; i++) {
      if (g->best[i].index >= e->grid.total)
        return ts_error(err, TS_EPROTO, "search returned no match for a block");
      int sx, sy;
      ts_anchors_pos(&e->grid, g->best[i].index, &sx, &sy);
      place_counted(e, &blocks[g->block[i]], sx, sy, refine, &np);
    }
  }
  /* Copied blocks reach the replica like searched ones. */
  for (uint32_t i = 0; i < e->ndirect; i++) {
    const ts_block *b = &blocks[e->direct[i]];
    int sx, sy;
    ts_accel_block(&e->accel, b->x, b->y, TS_ACCEL_COPY, &sx, &sy);
    place_counted(e, b, sx, sy, 0, &np);
  }
  return ts_search_place(e->search, e->image, e->places, np, err);
}

/* Seconds since the epoch: a checkpoint's moment has to mean something to
 * the process that resumes from it, which the monotonic clock does not. */
static double wall_now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_REALTIME, &ts);
  return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* The current level's statistics: those carried over from a checkpoint
 * inside it, plus what this run has done since it started the level. */
static void level_stats(const engine *e, ts_mrf_level_stats *ls) {
  const ts_search_stats *s = &e->search->stats, *b = &e->base;
  int l = e->level;
  *ls = e->carried;
  ls->ref_w = level_refs(e, 0, l)[l].w;
  ls->ref_h = level_refs(e, 0, l)[l].h;
  ls->out_w = e->cw[l];
  ls->out_h = e->ch[l];
  ls->vectors = e->grid.total;
  ls->blocks = e->prog.done;
  ls->steps = e->step;
  ls->pairs += s->pairs - b->pairs;
  ls->round_trips += s->round_trips - b->round_trips;
  ls->wire_bytes += s->bytes_out + s->bytes_in - (b->bytes_out + b->bytes_in);
  ls->seconds += ts_now() - e->t0;
}

/* Hands the state after the level's step e->step to the checkpoint hook:
 * the level's end, or (fewer steps done) a place inside it, which also
 * needs what the steps left read. */
static int save_checkpoint(engine *e, char *err) {
  const ts_mrf_hooks *h = e->hooks;
  int l = e->level;
  ts_mrf_checkpoint ck = {.level = l, .step = e->step, .steps = e->plan.steps, .saved_at = wall_now(),
                          .interval = h->checkpoint_interval, .width = e->cw[l], .height = e->ch[l],
                          .nplanes = e->nplanes, .copy = e->copy};
  for (int k = 0; k < e->nplanes; k++) ck.planes[k] = e->canvas[k][l].px;
  memcpy(ck.stats, e->res->level, sizeof(ck.stats));
  if (e->step < e->plan.steps) {
    ck.done = e->done;
    ck.ref_width = e->grid.w;
    ck.ref_height = e->grid.h;
    ck.usage = e->usage.count;
    if (l + 1 < e->levels) {
      ck.coarse_width = e->cw[l + 1];
      ck.coarse_height = e->ch[l + 1];
      for (int k = 0; k < e->nplanes; k++) ck.coarse[k] = e->canvas[k][l + 1].px;
    }
    level_stats(e, &ck.stats[l]);
  }
  int rc = h->checkpoint(h->checkpoint_ctx, &ck, err);
  e->last_checkpoint = ts_now(); /* the interval counts work, not writing */
  return rc;
}

/* A checkpoint inside the level is due: the interval has passed since the
 * last one, and steps are left (the level's end has its own). Best-of
 * candidates take none: their state is not yet the job's. */
static int checkpoint_due(const engine *e) {
  const ts_mrf_hooks *h = e->hooks;
  return h->checkpoint != NULL && !e->candidate_phase && h->checkpoint_interval > 0 && e->step < e->plan.steps &&
         ts_now() - e->last_checkpoint >= h->checkpoint_interval;
}

/* The run was asked to stop: it saves a checkpoint after this step and
 * returns (ts_mrf_hooks.stop). Only a run that can save one stops early
 * (best-of candidates stop once the choice is made). */
static int stop_requested(const engine *e) {
  const ts_mrf_hooks *h = e->hooks;
  return h->checkpoint != NULL && !e->candidate_phase && h->stop != NULL && atomic_load(h->stop);
}

/* Runs steps t0.. of a schedule, every block of a step searched against
 * the canvas as the previous step left it (schedule.h); a checkpoint, when
 * due, goes between two steps. */
static int run_steps(engine *e, const ts_schedule *sch, int refine, uint32_t t0, char *err) {
  uint64_t d1[2] = {ts_window_unit_distance(&e->shape[0]), ts_window_unit_distance(&e->shape[1])};
  for (uint32_t t = t0; t < sch->nsteps; t++) {
    const ts_block *blocks = sch->blocks + sch->step_start[t];
    uint32_t n = sch->step_start[t + 1] - sch->step_start[t];
    if (ensure_step_scratch(e, n) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
    build_queries(e, blocks, n, refine);
    int rc = search_step(e, d1, err);
    if (rc == 0) rc = place_step(e, blocks, refine, err);
    if (rc != 0) return rc;
    e->step++;
    e->prog.done += n;
    e->prog.work_done += n * level_cost(e->level);
    if (e->hooks->progress) e->hooks->progress(e->hooks->progress_ctx, &e->prog);
    if (e->step < e->plan.steps && stop_requested(e)) { /* a level's end stops in the caller */
      rc = save_checkpoint(e, err);
      return rc != 0 ? rc : ts_error(err, TS_ESTOPPED, "stopped at level %d, step %llu of %llu", e->level,
                                     (unsigned long long)e->step, (unsigned long long)e->plan.steps);
    }
    if (checkpoint_due(e) && (rc = save_checkpoint(e, err)) != 0) return rc;
  }
  return 0;
}

/* Runs the level's plan from step e->step on: 0, or where a checkpoint
 * inside the level left it. The sweeps (ICM-like) search every block again
 * with its full window, all of it placed now, so joins made early against
 * little context - and the torus seam, where the scan closes - are
 * revisited with both sides known. */
static int run_level(engine *e, char *err) {
  uint64_t first = 0; /* plan step of the schedule's first step */
  for (int i = 0; i < e->plan.n; i++) {
    const level_phase *ph = &e->plan.phase[i];
    for (int r = 0; r < ph->reps; r++, first += ph->sched.nsteps) {
      if (e->step >= first + ph->sched.nsteps) continue; /* done before the checkpoint */
      int rc = run_steps(e, &ph->sched, ph->refine, (uint32_t)(e->step - first), err);
      if (rc != 0) return rc;
    }
  }
  return 0;
}

/* The first `levels` levels of a reference's pyramid, per feature plane. */
static int build_reference(engine *e, const ts_image *ref, int levels, ts_plane pyr[][TS_MRF_MAX_LEVELS]) {
  int rw = ref->width, rh = ref->height;
  uint8_t *buf = malloc((size_t)rw * rh);
  if (buf == NULL) return TS_ENOMEM;
  int rc = 0;
  for (int p = 0; p < e->nplanes && rc == 0; p++) {
    if (e->nplanes == 1) ts_image_luma8(ref, buf);
    else ts_image_channel8(ref, p, buf);
    ts_plane base = {rw, rh, buf};
    rc = ts_pyramid_build(&base, levels, pyr[p]);
  }
  free(buf);
  return rc;
}

/* Takes over a checkpoint inside level l (check_resume passed it): the
 * canvas, copy map, placed blocks and usage counters as its step left
 * them, and the level above's canvas, the coarse part of the queries. */
static int restore_inside(engine *e, const ts_mrf_checkpoint *ck, char *err) {
  int l = e->level;
  size_t npx = (size_t)ck->width * ck->height;
  for (int k = 0; k < e->nplanes; k++) {
    memcpy(e->canvas[k][l].px, ck->planes[k], npx);
    if (l + 1 == e->levels) continue;
    if (ts_plane_alloc(&e->canvas[k][l + 1], ck->coarse_width, ck->coarse_height) != 0)
      return ts_error(err, TS_ENOMEM, "out of memory");
    memcpy(e->canvas[k][l + 1].px, ck->coarse[k], (size_t)ck->coarse_width * ck->coarse_height);
  }
  memcpy(e->copy, ck->copy, sizeof(uint32_t) * 2 * npx);
  memcpy(e->done, ck->done, npx);
  ts_usage_load(&e->usage, ck->usage);
  e->step = ck->step;
  e->carried = ck->stats[l];
  e->prog.done = ck->stats[l].blocks;
  e->prog.work_done += (double)e->prog.done * level_cost(l);
  return 0;
}

/* The backend's replica of the canvas as this level starts: predicted by
 * the backend itself from the level above when it holds that one (nothing
 * but the new reference level travels), else the canvas as it is here
 * (the first level of a run: the coarsest, or a resumed one; and the
 * first made from the fine reference, where a prediction across the two
 * references would be meaningless: the replica is loaded afresh). */
static int open_image(engine *e, char *err) {
  int l = e->level;
  const uint8_t *ref[TS_WIN_MAX_PLANES];
  for (int k = 0; k < e->nplanes; k++) ref[k] = e->ref_lp.fine[k]->px;
  const ts_plane *r0 = e->ref_lp.fine[0];
  if (e->image >= 0 && mix_switch(e, l)) {
    ts_search_image_close(e->search, e->image);
    e->image = -1;
  }
  if (e->image >= 0) return ts_search_image_next(e->search, e->image, e->cw[l], e->ch[l], r0->w, r0->h, ref, err);
  ts_replica_desc d = {.w = e->cw[l], .h = e->ch[l], .nplanes = e->nplanes, .done = e->done, .block = e->p->wb,
                       .rw = r0->w, .rh = r0->h, .copy = e->copy};
  memcpy(d.ref, ref, sizeof(ref));
  for (int k = 0; k < e->nplanes; k++) {
    d.fine[k] = e->canvas[k][l].px;
    d.coarse[k] = l + 1 < e->levels ? e->canvas[k][l + 1].px : NULL;
  }
  if (l + 1 < e->levels) {
    d.cw = e->cw[l + 1];
    d.ch = e->ch[l + 1];
  }
  return ts_search_image_open(e->search, &d, &e->image, err);
}

/* ---- the copy-map shortcut (§3.6.6) ------------------------------------ */

/* The levels it may copy at: the two finest, which hold all but a few per
 * cent of a job's work (16x per level) and where the seed's Table 3.3 uses
 * it; the levels above only measure, so at least one measurement comes
 * before the first copy whenever there are levels enough. */
#define ACCEL_TOP_LEVEL 1
/* Where it copies, every ACCEL_SAMPLE-th candidate is searched anyway and
 * keeps the constancy measured (1/8 of the saving given back). */
#define ACCEL_SAMPLE 8
/* Candidates measured before any copy: with 64 all kept, the true rate is
 * above 0.95 at 95 % confidence (the rule of three, 1 - 3/n); fewer (a
 * small job's coarse levels) prove nothing. */
#define ACCEL_MIN_MEASURED 64

/* The level's candidates, from the level above's copy map, and whether it
 * copies them: at levels 0 and 1 only, once the candidates measured so far
 * (ACCEL_MIN_MEASURED at least) kept their predicted sources at a rate of
 * at least accel_min - the seed's check of region constancy over
 * successive coarse levels. The rate is pooled over the levels (kept /
 * measured of all of them): the coarsest have few candidates each, too
 * few to judge alone. A level without a prediction (the coarsest, the
 * first made from the fine reference) has none. */
static int accel_begin(engine *e, char *err) {
  const ts_mrf_params *p = e->p;
  int l = e->level;
  ts_mrf_accel_stats *st = &e->res->accel[l];
  memset(st, 0, sizeof(*st));
  if (!p->copy_accel || l + 1 >= e->levels || mix_switch(e, l)) return 0;
  int n = p->accel_kernel ? p->accel_kernel : ts_coarse_width(p->wn);
  const ts_plane *r0 = e->ref_lp.fine[0];
  int rc = ts_accel_map_build(&e->accel, e->prev_copy, e->cw[l + 1], e->ch[l + 1], e->cw[l], e->ch[l], p->wb, n,
                              r0->w, r0->h, &e->grid, p->parity);
  if (rc != 0) return ts_error(err, rc, "out of memory");
  int on = l <= ACCEL_TOP_LEVEL && e->accel_measured >= ACCEL_MIN_MEASURED &&
           (double)e->accel_kept >= p->accel_min * (double)e->accel_measured;
  if (on) ts_accel_map_enable(&e->accel, ACCEL_SAMPLE);
  st->role = on ? TS_ACCEL_ON : TS_ACCEL_VALIDATE;
  st->pool_measured = e->accel_measured;
  st->pool_kept = e->accel_kept;
  st->blocks = (uint64_t)e->accel.rows * (uint64_t)e->accel.cols;
  st->candidates = e->accel.candidates;
  e->res->lossy |= on;
  return 0;
}

/* After the level: how many measured candidates kept their predicted
 * source, which decides the levels below. */
static void accel_end(engine *e) {
  ts_mrf_accel_stats *st = &e->res->accel[e->level];
  if (st->role == TS_ACCEL_NONE) return;
  ts_accel_constancy(&e->accel, e->copy, e->cw[e->level], &st->measured, &st->kept);
  st->copied = st->role == TS_ACCEL_ON ? st->candidates - st->measured : 0;
  e->accel_measured += st->measured;
  e->accel_kept += st->kept;
  ts_accel_map_free(&e->accel);
}

/* The queries plan pl of a w x h level makes of each set: a sweep's
 * blocks all search the full window; a scan block the causal L unless it
 * is clipped or its window wraps past the last row or column
 * (masked_query: where it may meet the first ones, placed). */
static void plan_queries(const level_plan *pl, const ts_mrf_params *p, int w, int h, uint64_t q[2]) {
  int wb = p->wb, hn = (p->wn - wb) / 2;
  q[SHAPE_PLAIN] = q[SHAPE_MASKED] = 0;
  for (int i = 0; i < pl->n; i++) {
    const level_phase *ph = &pl->phase[i];
    for (uint32_t j = 0; j < ph->sched.nblocks; j++) {
      const ts_block *b = &ph->sched.blocks[j];
      int plain = !ph->refine && b->w == wb && b->h == wb && b->x + wb + hn <= w && b->y + wb + hn <= h;
      q[plain ? SHAPE_PLAIN : SHAPE_MASKED] += (uint64_t)ph->reps;
    }
  }
}

/* A codebook pays when its set is queried more than this many times per
 * partition and iteration: building it compares every vector with every
 * centroid once an iteration and takes the medians, which cost about as
 * much as this many exhaustive queries (measured on the Table 3.3 job:
 * 64 partitions of each parity class, 12 iterations, 0.40 s for the full
 * window's codebook against 61 us a query of it). */
#define LBG_QUERIES_PER_PARTITION_ITERATION 2

/* Which sets of the chosen levels are partitioned (lossy search, §3.6.5):
 * those queried often enough for their codebook to pay (the seed: "it is
 * worthwhile only when the codebook is used often") - on the Table 3.3
 * job the scan's causal L always, the full window's (windows wrapping
 * onto placed blocks, the sweeps) with 64 partitions and the default
 * sweeps, not with 256 or with the scan alone. Decided from the levels'
 * plans before synthesis starts, a function of the parameters alone, so
 * that a run resumed past a level knows it too: the report and the
 * image's metadata say what ran whatever the run's history. (P partitions
 * of every class: fewer when a class has fewer vectors, which only errs
 * towards exhaustive search.) */
static int lbg_decide(engine *e) {
  const ts_mrf_params *p = e->p;
  uint64_t parts = (uint64_t)p->lbg * (p->parity ? 4 : 1);
  for (int l = p->stop_level; l < p->levels && p->lbg > 0; l++) {
    if (!(p->lbg_levels >> l & 1)) continue;
    level_plan pl;
    if (plan_level(&pl, p, l, e->cw[l], e->ch[l]) != 0) return TS_ENOMEM;
    ts_mrf_lbg_stats *ls = &e->res->lbg[l];
    plan_queries(&pl, p, e->cw[l], e->ch[l], ls->queries);
    plan_free(&pl);
    for (int k = 0; k < 2; k++) {
      ls->partitioned[k] = ls->queries[k] > LBG_QUERIES_PER_PARTITION_ITERATION * TS_LBG_MAX_ITER * parts;
      ls->on |= ls->partitioned[k];
    }
  }
  return 0;
}

/* Level l's set k's partitioning into *out, or NULL: exhaustive search.
 * Each codebook is drawn with a seed of its own, a function of the job's. */
static const ts_lbg_params *lbg_params(const engine *e, int l, int k, ts_lbg_params *out) {
  const ts_mrf_params *p = e->p;
  if (!e->res->lbg[l].partitioned[k]) return NULL;
  *out = (ts_lbg_params){(uint32_t)p->lbg, (uint32_t)p->lbg_probe, p->lbg_exact,
                         p->seed + 0x9E3779B97F4A7C15ull * (uint64_t)(2 * l + k + 1), 0};
  return out;
}

/* Synthesises level l from its start, or from `inside`, a checkpoint
 * taken inside it. */
static int synthesize_level(engine *e, int l, const ts_mrf_checkpoint *inside, char *err) {
  const ts_mrf_params *p = e->p;
  int coarse = l < e->levels - 1;
  e->level = l;
  e->t0 = ts_now();
  e->base = e->search->stats;
  memset(&e->carried, 0, sizeof(e->carried));
  const ts_plane *refs = level_refs(e, 0, l);
  for (int k = 0; k < e->nplanes; k++) {
    e->ref_lp.fine[k] = &level_refs(e, k, l)[l];
    e->ref_lp.coarse[k] = coarse ? &level_refs(e, k, l)[l + 1] : NULL;
    e->canvas_lp.fine[k] = &e->canvas[k][l];
    e->canvas_lp.coarse[k] = coarse ? &e->canvas[k][l + 1] : NULL;
    if (ts_plane_alloc(&e->canvas[k][l], e->cw[l], e->ch[l]) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
  }
  int rc = ts_neigh_window(&e->shape[SHAPE_PLAIN], TS_SHAPE_CAUSAL, p->wn, p->wb, coarse, e->nplanes,
                           p->coarse_weight, err);
  if (rc == 0)
    rc = ts_neigh_window(&e->shape[SHAPE_MASKED], TS_SHAPE_SQUARE, p->wn, p->wb, coarse, e->nplanes,
                         p->coarse_weight, err);
  if (rc == 0) /* masked queries weigh each pixel as plain ones do */
    for (int k = 0; k < e->shape[SHAPE_MASKED].spec.nparts; k++)
      e->shape[SHAPE_MASKED].spec.part[k].weight = e->shape[SHAPE_PLAIN].spec.part[k].weight;
  const ts_plane *r0 = e->ref_lp.fine[0];
  e->set_ids[0] = e->set_ids[1] = -1;
  e->cap = 0; /* the shapes' sizes changed */
  if (rc == 0 && p->parity && (rc = parity_plane(&e->parity, r0->w, r0->h)) != 0) ts_error(err, rc, "out of memory");
  if (rc == 0)
    rc = ts_anchors_init(&e->grid, &e->shape[SHAPE_PLAIN], r0->w, r0->h, coarse ? refs[l + 1].w : 0,
                         coarse ? refs[l + 1].h : 0, p->parity ? &e->parity : NULL, p->parity ? 4 : 1, NULL, err);
  if (rc == 0 && (rc = ts_usage_init(&e->usage, &e->grid, p->wb, p->usage_weight > 0)) != 0) ts_error(err, rc, "out of memory");
  size_t npx = (size_t)e->cw[l] * e->ch[l];
  e->copy = rc == 0 ? malloc(sizeof(uint32_t) * 2 * npx) : NULL;
  e->done = rc == 0 ? calloc(npx, 1) : NULL;
  if (rc == 0 && (e->copy == NULL || e->done == NULL)) rc = ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0 && (rc = plan_level(&e->plan, p, l, e->cw[l], e->ch[l])) != 0) ts_error(err, rc, "out of memory");
  e->step = 0;
  e->prog.level = l;
  e->prog.done = 0;
  e->prog.total = level_blocks(p, l, e->cw[l], e->ch[l]);
  if (rc == 0 && inside) rc = restore_inside(e, inside, err);
  else if (rc == 0 && mix_switch(e, l)) init_tiles(e);
  else if (rc == 0 && coarse) init_prediction(e);
  else if (rc == 0) init_noise(e);
  if (rc == 0) rc = open_image(e, err);
  if (rc == 0) rc = accel_begin(e, err);
  /* The backend's usage replicas start from the counters as they are now:
   * zero, or a resumed level's. */
  ts_lbg_params lbg;
  ts_mrf_lbg_stats *ls = &e->res->lbg[l];
  for (int k = 0; rc == 0 && k < 2; k++) {
    ts_refset rs = {e->image, &e->shape[k], &e->grid, &e->ref_lp, p->parity ? &e->parity : NULL, NULL,
                    p->usage_weight > 0, &e->usage, 0, lbg_params(e, l, k, &lbg), &ls->set[k]};
    rc = ts_search_prepare(e->search, &rs, &e->set_ids[k], err);
  }
  if (rc == 0) rc = run_level(e, err);
  if (rc == 0) accel_end(e);
  if (rc == 0 && ls->on) {
    ls->ran = 1;
    ls->pairs = e->search->stats.pairs - e->base.pairs;
    ls->full_pairs = e->search->stats.full_pairs - e->base.full_pairs;
  }
  for (int k = 0; k < 2; k++)
    if (e->set_ids[k] >= 0) ts_search_release(e->search, e->set_ids[k]);
  return rc;
}

static void engine_free(engine *e) {
  for (int p = 0; p < TS_MAX_PLANES; p++) {
    ts_pyramid_free(e->ref[p], e->levels);
    ts_pyramid_free(e->fine_ref[p], e->levels);
    ts_pyramid_free(e->canvas[p], e->levels);
  }
  ts_accel_map_free(&e->accel);
  free(e->direct);
  ts_usage_free(&e->usage);
  ts_anchors_free(&e->grid);
  ts_plane_free(&e->parity);
  free(e->copy);
  free(e->prev_copy);
  free(e->done);
  for (int k = 0; k < 2; k++) {
    group_free(&e->group[k]);
    ts_window_free(&e->shape[k]);
  }
  free(e->places);
  if (e->image >= 0) ts_search_image_close(e->search, e->image);
  plan_free(&e->plan);
}


/* Full result: reference pixels of any type gathered through the copy map
 * (§3.8). Preview (stop_level > 0): the level's luminance plane. */
static int gather_output(engine *e, const ts_image *ref, ts_mrf_result *res, char *err) {
  int l = e->level, w = e->cw[l], h = e->ch[l];
  int rc = l == 0 ? ts_image_alloc(&res->image, w, h, ref->channels, ref->type, err)
                  : ts_image_alloc(&res->image, w, h, 1, TS_PIX_U8, err);
  if (rc != 0) return rc;
  if (l > 0) memcpy(res->image.pixels, e->canvas[0][l].px, (size_t)w * h);
  for (int y = 0; l == 0 && y < h; y++)
    for (int x = 0; x < w; x++) {
      long o = (long)y * w + x;
      ts_image_copy_pixel(&res->image, x, y, ref, (int)e->copy[2 * o], (int)e->copy[2 * o + 1]);
    }
  res->copy_map = e->copy;
  e->copy = NULL;
  res->usage = e->usage.count;
  e->usage.count = NULL;
  res->ref_w = level_refs(e, 0, l)[l].w;
  res->ref_h = level_refs(e, 0, l)[l].h;
  return 0;
}

/* The last level the best-of candidates run: the best_of_levels coarsest
 * (by default all but the finest two), but not below the output's. */
static int candidate_last_level(const ts_mrf_params *p) {
  int n = p->best_of_levels > 0 ? p->best_of_levels : p->levels - 2;
  int last = p->levels - (n > 0 ? n : 1);
  return last > p->stop_level ? last : p->stop_level;
}

/* ---- resuming ----------------------------------------------------------- */

/* What the first steps of a plan leave: the blocks placed, and how many
 * were searched. */
typedef struct {
  int w;
  uint8_t *done;
  uint64_t blocks;
} walk_state;

static void mark_block(void *ctx, const ts_block *b) {
  walk_state *ws = ctx;
  ws->blocks++;
  for (int dy = 0; dy < b->h; dy++) memset(ws->done + (size_t)(b->y + dy) * ws->w + b->x, 1, b->w);
}

/* A checkpoint inside a level must hold what its first `step` steps of the
 * plan leave: exactly those blocks placed, as many blocks searched, and
 * usage counters that count the placed pixels' copies (every copy adds
 * its pixels, every sweep's replacement takes the old ones away). */
static int check_inside(const engine *e, const ts_mrf_checkpoint *ck, const level_plan *pl, char *err) {
  int l = ck->level, top = l + 1 == e->levels;
  int rw = level_refs(e, 0, l)[l].w, rh = level_refs(e, 0, l)[l].h;
  if (ck->coarse_width != (top ? 0 : e->cw[l + 1]) || ck->coarse_height != (top ? 0 : e->ch[l + 1]) ||
      ck->ref_width != rw || ck->ref_height != rh)
    return ts_error(err, TS_EINVAL,
                    "the checkpoint inside level %d (coarse canvas %dx%d, reference %dx%d) does not belong to "
                    "this job", l, ck->coarse_width, ck->coarse_height, ck->ref_width, ck->ref_height);
  size_t npx = (size_t)ck->width * ck->height;
  walk_state ws = {ck->width, calloc(npx, 1), 0};
  uint32_t *count = calloc((size_t)rw * rh, sizeof(uint32_t));
  int rc = ws.done && count ? 0 : ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0) plan_walk(pl, ck->step, mark_block, &ws);
  if (rc == 0 && memcmp(ws.done, ck->done, npx) != 0)
    rc = ts_error(err, TS_EINVAL, "the checkpoint's placed blocks are not those of its %llu steps",
                  (unsigned long long)ck->step);
  if (rc == 0 && ws.blocks != ck->stats[l].blocks)
    rc = ts_error(err, TS_EINVAL, "the checkpoint counts %llu blocks searched, its %llu steps search %llu",
                  (unsigned long long)ck->stats[l].blocks, (unsigned long long)ck->step,
                  (unsigned long long)ws.blocks);
  for (size_t i = 0; rc == 0 && i < npx; i++)
    if (ck->done[i]) count[(size_t)ck->copy[2 * i + 1] * rw + ck->copy[2 * i]]++;
  if (rc == 0 && memcmp(count, ck->usage, (size_t)rw * rh * sizeof(uint32_t)) != 0)
    rc = ts_error(err, TS_EINVAL, "the checkpoint's usage counters do not count its placed copies");
  free(ws.done);
  free(count);
  return rc;
}

/* Checks that a checkpoint is a state this job's synthesis passes through.
 * It came through a checksum, but from a file: one left by another build,
 * or a lie, must be refused rather than trusted. */
static int check_resume(const engine *e, const ts_mrf_checkpoint *ck, char *err) {
  const ts_mrf_params *p = e->p;
  int l = ck->level, inside = ck->step < ck->steps;
  if (l < p->stop_level + !inside || l >= p->levels || ck->nplanes != e->nplanes || ck->width != e->cw[l] ||
      ck->height != e->ch[l])
    return ts_error(err, TS_EINVAL, "the checkpoint (level %d, %dx%d, %d planes) does not belong to this job", l,
                    ck->width, ck->height, ck->nplanes);
  if (p->copy_accel)
    return ts_error(err, TS_EINVAL, "a job with --copy-accel takes no checkpoints: its choices rest on the copy "
                    "maps and constancy of the levels above, which a checkpoint does not hold");
  int last = candidate_last_level(p);
  if (p->best_of > 1 && (l > last || (l == last && inside)))
    return ts_error(err, TS_EINVAL, "the checkpoint (level %d) lies among the best-of candidates' levels (%d and "
                    "up), which take none", l, last);
  size_t npx = (size_t)ck->width * ck->height;
  const ts_plane *r = &level_refs(e, 0, l)[l];
  for (size_t i = 0; i < npx; i++)
    if (ck->copy[2 * i] >= (uint32_t)r->w || ck->copy[2 * i + 1] >= (uint32_t)r->h)
      return ts_error(err, TS_EINVAL, "the checkpoint's copy map points outside the level-%d reference", l);
  level_plan pl;
  if (plan_level(&pl, p, l, ck->width, ck->height) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
  int rc = 0;
  if (ck->steps != pl.steps || ck->stats[l].steps != ck->step || ck->step > ck->steps)
    rc = ts_error(err, TS_EINVAL, "the checkpoint is at step %llu of %llu of level %d, which has %llu steps here",
                  (unsigned long long)ck->step, (unsigned long long)ck->steps, l, (unsigned long long)pl.steps);
  else if (inside)
    rc = check_inside(e, ck, &pl, err);
  plan_free(&pl);
  return rc;
}

/* Takes over a finished level's state: its canvas becomes the coarse part
 * of the next level and its copy map the prediction. */
static int restore_level_end(engine *e, const ts_mrf_checkpoint *ck, char *err) {
  int l = ck->level;
  size_t npx = (size_t)ck->width * ck->height;
  for (int k = 0; k < e->nplanes; k++) {
    if (ts_plane_alloc(&e->canvas[k][l], ck->width, ck->height) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
    memcpy(e->canvas[k][l].px, ck->planes[k], npx);
  }
  e->copy = malloc(sizeof(uint32_t) * 2 * npx);
  if (e->copy == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  memcpy(e->copy, ck->copy, sizeof(uint32_t) * 2 * npx);
  e->level = l;
  return 0;
}

static void describe_resume(const engine *e, const ts_mrf_checkpoint *ck, ts_mrf_resume *r) {
  int l = ck->level;
  r->level = l;
  r->step = ck->step;
  r->steps = ck->steps;
  r->level_done = (double)ck->stats[l].blocks / (double)level_blocks(e->p, l, e->cw[l], e->ch[l]);
  r->saved_at = ck->saved_at;
  r->age = wall_now() - ck->saved_at;
  if (!(r->age > 0)) r->age = 0; /* a clock set back */
  r->redone = ck->interval > 0 && ck->interval < r->age ? ck->interval : r->age;
}

/* Goes on from hooks->resume when it fits the job: *first is the level to
 * run first, and *inside the checkpoint to start it from when it was taken
 * inside that level. One that does not fit fails the synthesis, or, with a
 * `refused` hook, is reported and synthesis starts from noise. */
static int take_resume(engine *e, int *first, const ts_mrf_checkpoint **inside, char *err) {
  const ts_mrf_hooks *h = e->hooks;
  const ts_mrf_checkpoint *ck = h->resume;
  char why[TS_ERR_LEN];
  int rc = check_resume(e, ck, why);
  if (rc == TS_EINVAL && h->refused != NULL) {
    h->refused(h->resume_ctx, why);
    return 0;
  }
  if (rc != 0) return ts_error(err, rc, "%s", why);
  int l = ck->level, finished = ck->step == ck->steps;
  if (finished) rc = restore_level_end(e, ck, err);
  *first = finished ? l - 1 : l;
  *inside = finished ? NULL : ck;
  for (int k = finished ? l : l + 1; k < e->levels; k++) { /* the levels done */
    e->res->level[k] = ck->stats[k];
    e->prog.work_done += (double)level_blocks(e->p, k, e->cw[k], e->ch[k]) * level_cost(k);
  }
  e->res->resumed = 1;
  describe_resume(e, ck, &e->res->resume);
  if (h->resumed) h->resumed(h->resume_ctx, &e->res->resume);
  return rc;
}

/* Frees the state of the level above before level l starts. */
static void drop_previous_level(engine *e) {
  ts_usage_free(&e->usage);
  ts_anchors_free(&e->grid);
  ts_plane_free(&e->parity);
  free(e->prev_copy);
  e->prev_copy = e->copy;
  free(e->done);
  e->copy = NULL;
  e->done = NULL;
  for (int k = 0; k < 2; k++) ts_window_free(&e->shape[k]);
  plan_free(&e->plan);
  ts_accel_map_free(&e->accel);
}

/* After a level but the output's: its checkpoint (best-of candidates take
 * none), and a stop if one was asked for. */
static int level_end(engine *e, int l, char *err) {
  int rc = e->hooks->checkpoint && !e->candidate_phase ? save_checkpoint(e, err) : 0;
  if (rc == 0 && stop_requested(e)) rc = ts_error(err, TS_ESTOPPED, "stopped after level %d", l);
  return rc;
}

/* Runs levels `from` down to `to`, the first from `inside` when that is a
 * checkpoint taken inside it. */
static int run_levels(engine *e, int from, int to, const ts_mrf_checkpoint *inside, char *err) {
  const ts_mrf_params *p = e->p;
  int rc = 0;
  for (int l = from; l >= to && rc == 0; l--) {
    if (l < p->levels - 1) drop_previous_level(e);
    rc = synthesize_level(e, l, l == from ? inside : NULL, err);
    level_stats(e, &e->res->level[l]);
    /* Level l+2 is no longer needed as anyone's coarse part. */
    for (int k = 0; k < e->nplanes && l + 2 < p->levels; k++) ts_plane_free(&e->canvas[k][l + 2]);
    if (rc == 0 && l > p->stop_level) rc = level_end(e, l, err);
  }
  return rc;
}

/* ---- passive usage-variance optimisation (§3.7.1) ----------------------- */

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
  drop_previous_level(e);
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
  int rc = run_levels(e, e->levels - 1, last, NULL, err);
  if (rc == 0) ts_usage_stats(&e->usage, &mean, &c->variance);
  if (!rerun) c->seconds = ts_now() - t0;
  return rc;
}

/* The work of one candidate, for the progress bar. */
static double candidate_work(const engine *e, int last) {
  double w = 0;
  for (int l = last; l < e->levels; l++) w += (double)level_blocks(e->p, l, e->cw[l], e->ch[l]) * level_cost(l);
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
static int choose_candidate(engine *e, int *next, char *err) {
  const ts_mrf_params *p = e->p;
  ts_mrf_result *res = e->res;
  int last = candidate_last_level(p), rc = 0;
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
    e->prog.work_total += candidate_work(e, last);
    rc = run_candidate(e, res->chosen, last, 1, err);
  }
  e->candidate_phase = 0;
  if (rc == 0 && last > p->stop_level) rc = level_end(e, last, err);
  *next = last - 1;
  return rc;
}

/* The inputs' checks, every problem listed. */
static int check_inputs(const ts_mrf_params *p, const ts_image *ref, const ts_image *fine, char *err) {
  char msg[2048];
  if (p->mix_level > 0 && fine == NULL) return ts_error(err, TS_EINVAL, "--mix-level needs a --ref-fine image");
  if (p->mix_level == 0 && fine != NULL) return ts_error(err, TS_EINVAL, "--ref-fine needs --mix-level");
  int rc = ts_mrf_check(p, ref->width, ref->height, ref->channels, msg, sizeof(msg));
  if (fine != NULL && ts_mrf_check_fine(p, fine->width, fine->height, fine->channels, ref->channels, msg,
                                        sizeof(msg)) != 0)
    rc = TS_EINVAL;
  return rc != 0 ? ts_error(err, TS_EINVAL, "%s", msg) : 0;
}

int ts_mrf_synthesize(const ts_mrf_params *p, const ts_image *ref, ts_search *search,
                      const ts_mrf_hooks *hooks, ts_mrf_result *res, char *err) {
  return ts_mrf_synthesize_mixed(p, ref, NULL, search, hooks, res, err);
}

int ts_mrf_synthesize_mixed(const ts_mrf_params *p, const ts_image *ref, const ts_image *ref_fine,
                            ts_search *search, const ts_mrf_hooks *hooks, ts_mrf_result *res, char *err) {
  memset(res, 0, sizeof(*res));
  if (check_inputs(p, ref, ref_fine, err) != 0) return TS_EINVAL;
  static const ts_mrf_hooks none = {0};
  double t_start = ts_now();
  engine e;
  memset(&e, 0, sizeof(e));
  e.p = p;
  e.search = search;
  e.hooks = hooks ? hooks : &none;
  e.res = res;
  e.last_checkpoint = t_start;
  e.image = -1;
  e.levels = p->levels;
  e.mix = p->mix_level;
  e.seed = p->seed;
  e.nplanes = nplanes_for(p, ref->channels);
  e.prog.levels = p->levels;
  level_sizes(p->width, p->height, p->levels, e.cw, e.ch, 1);
  for (int l = 0; l < p->levels; l++)
    e.prog.work_total += (double)level_blocks(p, l, e.cw[l], e.ch[l]) * level_cost(l);
  if (p->best_of > 1) e.prog.work_total += (p->best_of - 1) * candidate_work(&e, candidate_last_level(p));
  int rc = build_reference(&e, ref, p->levels, e.ref);
  if (rc == 0 && e.mix > 0) rc = build_reference(&e, ref_fine, e.mix + 1, e.fine_ref);
  if (rc != 0) rc = ts_error(err, rc, "cannot build the reference pyramids: %s", ts_strerror(rc));
  if (rc == 0 && (rc = lbg_decide(&e)) != 0) ts_error(err, rc, "out of memory");
  int first = p->levels - 1;
  const ts_mrf_checkpoint *inside = NULL;
  if (rc == 0 && e.hooks->resume) rc = take_resume(&e, &first, &inside, err);
  if (rc == 0 && p->best_of > 1 && !res->resumed) rc = choose_candidate(&e, &first, err);
  if (rc == 0) rc = run_levels(&e, first, p->stop_level, inside, err);
  if (rc == 0) {
    ts_usage_stats(&e.usage, &res->usage_mean, &res->usage_variance);
    /* Colour from the reference the finest level was made from. */
    rc = gather_output(&e, e.mix > p->stop_level ? ref_fine : ref, res, err);
  }
  engine_free(&e);
  res->seconds = ts_now() - t_start;
  if (rc != 0) ts_mrf_result_free(res);
  return rc;
}

void ts_mrf_result_free(ts_mrf_result *res) {
  ts_image_free(&res->image);
  free(res->copy_map);
  free(res->usage);
  res->copy_map = NULL;
  res->usage = NULL;
}
