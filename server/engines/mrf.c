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
 * copy-map shortcut (§3.6.6, lossy, mrf_accel.h). mrf_state.h lists the
 * files these live in; this one holds the checks and the levels. */
#include "mrf_levels.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "error.h"
#include "param.h"
#include "util.h"
#include "mrf_accel.h"
#include "mrf_plan.h"
#include "plane.h"
#include "replica.h"
#include "rng.h"
#include "schedule.h"
#include "usage.h"

int mrf_nplanes_for(const ts_mrf_params *p, int channels) {
  if (!p->rgb_search || channels < 3) return 1;
  return 3;
}

/* Level sizes: the reference halves with floor (eq. 2.3), the canvas with
 * ceil so every output size works on the torus. */
void mrf_level_sizes(int w, int h, int levels, int *lw, int *lh, int ceil_mode) {
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
  mrf_level_sizes(ref_w, ref_h, p->levels, rw, rh, 0);
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
  mrf_level_sizes(p->width, p->height, p->levels, cw, ch, 1);
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
  else if (mrf_nplanes_for(p, fine_channels) != mrf_nplanes_for(p, ref_channels))
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
    g->klass[g->n] = e->p->parity ? (uint8_t)ts_parity_class(b->x, b->y) : 0;
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

/* The current level's statistics: those carried over from a checkpoint
 * inside it, plus what this run has done since it started the level. */
static void level_stats(const engine *e, ts_mrf_level_stats *ls) {
  const ts_search_stats *s = &e->search->stats, *b = &e->base;
  int l = e->level;
  *ls = e->carried;
  ls->ref_w = mrf_level_refs(e, 0, l)[l].w;
  ls->ref_h = mrf_level_refs(e, 0, l)[l].h;
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
  ts_mrf_checkpoint ck = {.level = l, .step = e->step, .steps = e->plan.steps, .saved_at = mrf_wall_now(),
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
    e->prog.work_done += n * mrf_level_cost(e->level);
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
int mrf_build_reference(engine *e, const ts_image *ref, int levels, ts_plane pyr[][TS_MRF_MAX_LEVELS]) {
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
  e->prog.work_done += (double)e->prog.done * mrf_level_cost(l);
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
int mrf_lbg_decide(engine *e) {
  const ts_mrf_params *p = e->p;
  uint64_t parts = (uint64_t)p->lbg * (p->parity ? 4 : 1);
  for (int l = p->stop_level; l < p->levels && p->lbg > 0; l++) {
    if (!(p->lbg_levels >> l & 1)) continue;
    level_plan pl;
    if (mrf_plan_level(&pl, p, l, e->cw[l], e->ch[l]) != 0) return TS_ENOMEM;
    ts_mrf_lbg_stats *ls = &e->res->lbg[l];
    plan_queries(&pl, p, e->cw[l], e->ch[l], ls->queries);
    mrf_plan_free(&pl);
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
  const ts_plane *refs = mrf_level_refs(e, 0, l);
  for (int k = 0; k < e->nplanes; k++) {
    e->ref_lp.fine[k] = &mrf_level_refs(e, k, l)[l];
    e->ref_lp.coarse[k] = coarse ? &mrf_level_refs(e, k, l)[l + 1] : NULL;
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
  if (rc == 0 && p->parity && (rc = ts_plane_parity(&e->parity, r0->w, r0->h)) != 0) ts_error(err, rc, "out of memory");
  if (rc == 0)
    rc = ts_anchors_init(&e->grid, &e->shape[SHAPE_PLAIN], r0->w, r0->h, coarse ? refs[l + 1].w : 0,
                         coarse ? refs[l + 1].h : 0, p->parity ? &e->parity : NULL, p->parity ? 4 : 1, NULL, err);
  if (rc == 0 && (rc = ts_usage_init(&e->usage, &e->grid, p->wb, p->usage_weight > 0)) != 0) ts_error(err, rc, "out of memory");
  size_t npx = (size_t)e->cw[l] * e->ch[l];
  e->copy = rc == 0 ? malloc(sizeof(uint32_t) * 2 * npx) : NULL;
  e->done = rc == 0 ? calloc(npx, 1) : NULL;
  if (rc == 0 && (e->copy == NULL || e->done == NULL)) rc = ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0 && (rc = mrf_plan_level(&e->plan, p, l, e->cw[l], e->ch[l])) != 0) ts_error(err, rc, "out of memory");
  e->step = 0;
  e->prog.level = l;
  e->prog.done = 0;
  e->prog.total = mrf_level_blocks(p, l, e->cw[l], e->ch[l]);
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

void mrf_engine_free(engine *e) {
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
  mrf_plan_free(&e->plan);
}

/* Full result: reference pixels of any type gathered through the copy map
 * (§3.8). Preview (stop_level > 0): the level's luminance plane. */
int mrf_gather_output(engine *e, const ts_image *ref, ts_mrf_result *res, char *err) {
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
  res->ref_w = mrf_level_refs(e, 0, l)[l].w;
  res->ref_h = mrf_level_refs(e, 0, l)[l].h;
  return 0;
}

/* Frees the state of the level above before level l starts. */
void mrf_drop_previous_level(engine *e) {
  ts_usage_free(&e->usage);
  ts_anchors_free(&e->grid);
  ts_plane_free(&e->parity);
  free(e->prev_copy);
  e->prev_copy = e->copy;
  free(e->done);
  e->copy = NULL;
  e->done = NULL;
  for (int k = 0; k < 2; k++) ts_window_free(&e->shape[k]);
  mrf_plan_free(&e->plan);
  ts_accel_map_free(&e->accel);
}

/* After a level but the output's: its checkpoint (best-of candidates take
 * none), and a stop if one was asked for. */
int mrf_level_end(engine *e, int l, char *err) {
  int rc = e->hooks->checkpoint && !e->candidate_phase ? save_checkpoint(e, err) : 0;
  if (rc == 0 && stop_requested(e)) rc = ts_error(err, TS_ESTOPPED, "stopped after level %d", l);
  return rc;
}

/* Runs levels `from` down to `to`, the first from `inside` when that is a
 * checkpoint taken inside it. */
int mrf_run_levels(engine *e, int from, int to, const ts_mrf_checkpoint *inside, char *err) {
  const ts_mrf_params *p = e->p;
  int rc = 0;
  for (int l = from; l >= to && rc == 0; l--) {
    if (l < p->levels - 1) mrf_drop_previous_level(e);
    rc = synthesize_level(e, l, l == from ? inside : NULL, err);
    level_stats(e, &e->res->level[l]);
    /* Level l+2 is no longer needed as anyone's coarse part. */
    for (int k = 0; k < e->nplanes && l + 2 < p->levels; k++) ts_plane_free(&e->canvas[k][l + 2]);
    if (rc == 0 && l > p->stop_level) rc = mrf_level_end(e, l, err);
  }
  return rc;
}
