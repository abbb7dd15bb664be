/* fill.c - see fill.h.
 *
 * Per level, coarsest first: the image's level (given pixels from the
 * masked pyramid, work pixels filled class by class), and per class with
 * work at that level a reference set (the class's atlas level, below) and a
 * query image with the class's pixel states, searched in steps taken from
 * the bucket queue (fill_queue.c). */
#include "fill.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "anchors.h"
#include "error.h"
#include "fill_queue.h"
#include "plane.h"
#include "rng.h"
#include "usage.h"
#include "util.h"

const char *const ts_fill_order_names[] = {[TS_FILL_PUZZLE] = "puzzle", [TS_FILL_THRESHOLD] = "threshold", NULL};
const ts_param ts_fill_param_table[] = {TS_FILL_PARAMS(0, "4", "9", "0"), {NULL}};

void ts_fill_params_default(ts_fill_params *p) {
  memset(p, 0, sizeof(*p));
  ts_params_default(ts_fill_param_table, p);
}

/* ---- atlases: a class's sources stacked into one reference ---------------
 *
 * The sources of a class are stacked top to bottom into one plane per
 * level, each at a row that halves exactly down the pyramid (a multiple of
 * 2^(L-1)), so a reference block's coarse window (x/2, y/2) is its own
 * source's coarser level. Each source's pyramid is built on its own with
 * the masked Gaussian over its usable area; what lies between the sources
 * is unusable, so no window spans two of them. */

typedef struct {
  int nsrc;
  int y0[TS_FILL_MAX_SOURCES], h0[TS_FILL_MAX_SOURCES]; /* rows at level 0 */
  int w, h;                                              /* level 0 */
  ts_plane planes[TS_MAX_PLANES][TS_FILL_MAX_LEVELS];
  ts_plane usable[TS_FILL_MAX_LEVELS];
} atlas;

static void atlas_free(atlas *a, int levels) {
  for (int l = 0; l < levels; l++) {
    for (int k = 0; k < TS_MAX_PLANES; k++) ts_plane_free(&a->planes[k][l]);
    ts_plane_free(&a->usable[l]);
  }
}

static int round_up(int v, int m) { return (v + m - 1) / m * m; }

/* One source's level l, planes and usable area, into the atlas's level l. */
static void atlas_put(atlas *a, int l, int s, int nplanes, ts_plane *planes, const ts_plane *usable) {
  int y0 = a->y0[s] >> l;
  for (int y = 0; y < usable->h; y++) {
    size_t o = (size_t)(y0 + y) * (size_t)a->usable[l].w;
    memcpy(a->usable[l].px + o, usable->px + (size_t)y * (size_t)usable->w, (size_t)usable->w);
    for (int k = 0; k < nplanes; k++)
      memcpy(a->planes[k][l].px + o, planes[k].px + (size_t)y * (size_t)usable->w, (size_t)usable->w);
  }
}

/* Builds source s's pyramid level by level into the atlas. */
static int atlas_add_source(atlas *a, int s, const ts_fill_source *src, int nplanes, int levels) {
  ts_plane cur[TS_MAX_PLANES], use, next[TS_MAX_PLANES], nuse;
  memset(cur, 0, sizeof(cur));
  memset(next, 0, sizeof(next));
  memset(&use, 0, sizeof(use));
  memset(&nuse, 0, sizeof(nuse));
  int rc = ts_plane_alloc(&use, src->w, src->h);
  for (int k = 0; rc == 0 && k < nplanes; k++) {
    rc = ts_plane_alloc(&cur[k], src->w, src->h);
    if (rc == 0) memcpy(cur[k].px, src->planes[k], (size_t)src->w * (size_t)src->h);
  }
  if (rc == 0) {
    for (size_t i = 0; i < (size_t)src->w * (size_t)src->h; i++) use.px[i] = src->usable == NULL || src->usable[i];
  }
  for (int l = 0; rc == 0 && l < levels; l++) {
    atlas_put(a, l, s, nplanes, cur, &use);
    if (l + 1 == levels || use.w < 2 || use.h < 2) break; /* a too small source has no coarser level */
    for (int k = 0; rc == 0 && k < nplanes; k++) rc = ts_plane_reduce_masked(&cur[k], &use, 0, &next[k]);
    if (rc == 0) rc = ts_plane_reduce_all(&use, 0, &nuse);
    for (int k = 0; k < nplanes; k++) {
      ts_plane_free(&cur[k]);
      cur[k] = next[k];
      memset(&next[k], 0, sizeof(next[k]));
    }
    ts_plane_free(&use);
    use = nuse;
    memset(&nuse, 0, sizeof(nuse));
  }
  for (int k = 0; k < nplanes; k++) {
    ts_plane_free(&cur[k]);
    ts_plane_free(&next[k]);
  }
  ts_plane_free(&use);
  ts_plane_free(&nuse);
  return rc;
}

static int atlas_build(atlas *a, const ts_fill_class *c, int nplanes, int levels) {
  memset(a, 0, sizeof(*a));
  int unit = 1 << (levels - 1), y = 0, w = 0;
  a->nsrc = c->nsources;
  for (int s = 0; s < c->nsources; s++) {
    a->y0[s] = y;
    a->h0[s] = c->src[s].h;
    y += round_up(c->src[s].h, unit);
    w = c->src[s].w > w ? c->src[s].w : w;
  }
  a->w = round_up(w, unit);
  a->h = y;
  int rc = 0;
  for (int l = 0; rc == 0 && l < levels; l++) {
    rc = ts_plane_alloc(&a->usable[l], a->w >> l, a->h >> l);
    for (int k = 0; rc == 0 && k < nplanes; k++) rc = ts_plane_alloc(&a->planes[k][l], a->w >> l, a->h >> l);
  }
  for (int s = 0; rc == 0 && s < c->nsources; s++) rc = atlas_add_source(a, s, &c->src[s], nplanes, levels);
  if (rc != 0) atlas_free(a, levels);
  return rc;
}

/* Which source an atlas row of level 0 belongs to. */
static int atlas_source_of(const atlas *a, int y) {
  int s = 0;
  while (s + 1 < a->nsrc && y >= a->y0[s + 1]) s++;
  return s;
}

/* ---- reference blocks that qualify ---------------------------------------
 *
 * A block qualifies when its whole window lies in its source's usable area
 * at its level and its coarse window in the usable area one level up
 * (§3.2.3): the validity plane of the level's anchors. */

/* Summed-area table of the unusable pixels of a plane ((w+1) x (h+1)). */
static uint32_t *unusable_table(const ts_plane *u) {
  size_t w1 = (size_t)u->w + 1;
  uint32_t *t = calloc(w1 * ((size_t)u->h + 1), sizeof(uint32_t));
  if (t == NULL) return NULL;
  for (int y = 0; y < u->h; y++) {
    uint32_t row = 0;
    for (int x = 0; x < u->w; x++) {
      row += u->px[(size_t)y * (size_t)u->w + (size_t)x] == 0;
      t[(size_t)(y + 1) * w1 + (size_t)x + 1] = t[(size_t)y * w1 + (size_t)x + 1] + row;
    }
  }
  return t;
}

/* Whether box [x0, x1) x [y0, y1) lies in the plane and is all usable. */
static int box_usable(const uint32_t *t, int w, int h, int x0, int y0, int x1, int y1) {
  if (x0 < 0 || y0 < 0 || x1 > w || y1 > h) return 0;
  size_t w1 = (size_t)w + 1;
  uint32_t n = t[(size_t)y1 * w1 + (size_t)x1] - t[(size_t)y0 * w1 + (size_t)x1] - t[(size_t)y1 * w1 + (size_t)x0] +
               t[(size_t)y0 * w1 + (size_t)x0];
  return n == 0;
}

/* The validity plane of the anchors of atlas level l for window win. */
static int qualifying_blocks(const atlas *a, int l, int levels, const ts_window *win, ts_plane *valid) {
  const ts_plane *u = &a->usable[l];
  int coarse = ts_window_has_coarse(win) && l + 1 < levels;
  const ts_plane *uc = coarse ? &a->usable[l + 1] : NULL;
  uint32_t *t = unusable_table(u), *tc = coarse ? unusable_table(uc) : NULL;
  int rc = t != NULL && (!coarse || tc != NULL) ? ts_plane_alloc(valid, u->w, u->h) : TS_ENOMEM;
  const ts_box *f = &win->spec.extent[TS_SRC_FINE], *c = &win->spec.extent[TS_SRC_COARSE];
  for (int y = 0; rc == 0 && y < u->h; y++)
    for (int x = 0; x < u->w; x++) {
      int ok = box_usable(t, u->w, u->h, x + f->dx0, y + f->dy0, x + f->dx1, y + f->dy1);
      int cx = (x + win->spec.centre) / 2, cy = (y + win->spec.centre) / 2;
      if (ok && coarse) ok = box_usable(tc, uc->w, uc->h, cx + c->dx0, cy + c->dy0, cx + c->dx1, cy + c->dy1);
      valid->px[(size_t)y * (size_t)u->w + (size_t)x] = (uint8_t)ok;
    }
  free(t);
  free(tc);
  return rc;
}

/* ---- the image's pyramid --------------------------------------------------
 *
 * Sizes halve rounding up, so every pixel has a coarse parent. A coarse
 * pixel is given when its whole 2 x 2 cell is, with the masked Gaussian of
 * the given pixels as its value; else it belongs to the class most of its
 * cell's work pixels have (ties to the earlier class), so a hole or an area
 * to fill never shrinks on the way up. */

static void state_reduce(const ts_plane *s, ts_plane *d, int nclass) {
  for (int y = 0; y < d->h; y++)
    for (int x = 0; x < d->w; x++) {
      int votes[TS_FILL_MAX_CLASSES + 1] = {0}, any = 0;
      for (int j = 0; j < 2 && 2 * y + j < s->h; j++)
        for (int i = 0; i < 2 && 2 * x + i < s->w; i++) {
          int c = ts_plane_at(s, 2 * x + i, 2 * y + j);
          if (c > 0) votes[c]++, any = 1;
        }
      int best = 0;
      for (int c = 1; any && c <= nclass; c++)
        if (best == 0 || votes[c] > votes[best]) best = c;
      d->px[(size_t)y * (size_t)d->w + (size_t)x] = (uint8_t)best;
    }
}

typedef struct {
  int levels, nplanes, nclass;
  ts_plane planes[TS_MAX_PLANES][TS_FILL_MAX_LEVELS]; /* given values; filled ones as levels finish */
  ts_plane state[TS_FILL_MAX_LEVELS];
} image_pyramid;

static void image_pyramid_free(image_pyramid *ip) {
  for (int l = 0; l < TS_FILL_MAX_LEVELS; l++) {
    for (int k = 0; k < TS_MAX_PLANES; k++) ts_plane_free(&ip->planes[k][l]);
    ts_plane_free(&ip->state[l]);
  }
}

static int image_pyramid_build(image_pyramid *ip, const ts_fill_input *in, int levels) {
  memset(ip, 0, sizeof(*ip));
  ip->levels = levels;
  ip->nplanes = in->nplanes;
  ip->nclass = in->nclass;
  size_t npx = (size_t)in->w * (size_t)in->h;
  int rc = ts_plane_alloc(&ip->state[0], in->w, in->h);
  if (rc == 0) memcpy(ip->state[0].px, in->state, npx);
  for (int k = 0; rc == 0 && k < in->nplanes; k++) {
    rc = ts_plane_alloc(&ip->planes[k][0], in->w, in->h);
    for (size_t i = 0; rc == 0 && i < npx; i++) ip->planes[k][0].px[i] = in->state[i] == 0 ? in->planes[k][i] : 0;
  }
  for (int l = 1; rc == 0 && l < levels; l++) {
    const ts_plane *s = &ip->state[l - 1];
    ts_plane given;
    rc = ts_plane_alloc(&given, s->w, s->h);
    for (size_t i = 0; rc == 0 && i < (size_t)s->w * (size_t)s->h; i++) given.px[i] = s->px[i] == 0;
    for (int k = 0; rc == 0 && k < in->nplanes; k++)
      rc = ts_plane_reduce_masked(&ip->planes[k][l - 1], &given, 1, &ip->planes[k][l]);
    if (rc == 0) rc = ts_plane_alloc(&ip->state[l], (s->w + 1) / 2, (s->h + 1) / 2);
    if (rc == 0) state_reduce(s, &ip->state[l], in->nclass);
    ts_plane_free(&given);
  }
  if (rc != 0) image_pyramid_free(ip);
  return rc;
}

/* ---- checks -------------------------------------------------------------- */

static int level_anchors(const atlas *a, int l, int levels, const ts_fill_params *p, int nplanes, ts_anchors *g,
                         ts_plane *valid, ts_plane *labels, char *err) {
  ts_window win;
  int coarse = l + 1 < levels;
  int rc = ts_neigh_window(&win, TS_SHAPE_FREE, p->wn, p->wb, coarse, nplanes, p->coarse_weight, err);
  if (rc != 0) return rc;
  const ts_plane *u = &a->usable[l];
  rc = qualifying_blocks(a, l, levels, &win, valid);
  if (rc == 0 && p->parity) rc = ts_plane_parity(labels, u->w, u->h);
  if (rc != 0) rc = ts_error(err, rc, "out of memory");
  if (rc == 0)
    rc = ts_anchors_init(g, &win, u->w, u->h, coarse ? a->usable[l + 1].w : 0, coarse ? a->usable[l + 1].h : 0,
                         p->parity ? labels : NULL, p->parity ? 4 : 1, valid, err);
  ts_window_free(&win);
  return rc;
}

/* Whether class c's atlas has blocks to copy at every level (in every
 * parity class with parity). */
static void check_class_levels(const ts_fill_params *p, const ts_fill_input *in, int c, const char *name, char *msg,
                               size_t len, int *n) {
  atlas a;
  if (atlas_build(&a, &in->cls[c - 1], in->nplanes, p->levels) != 0) {
    ts_problem(msg, len, n, "out of memory for class %s's reference", name);
    return;
  }
  for (int l = p->levels - 1; l >= 0; l--) {
    ts_anchors g;
    ts_plane valid = {0}, labels = {0};
    char err[TS_ERR_LEN];
    int rc = level_anchors(&a, l, p->levels, p, in->nplanes, &g, &valid, &labels, err);
    int short_class = 0;
    for (int k = 0; rc == 0 && p->parity && k < 4; k++) short_class |= g.count[k] == 0;
    if (rc == 0) ts_anchors_free(&g);
    ts_plane_free(&valid);
    ts_plane_free(&labels);
    if (rc == TS_ENOMEM) {
      ts_problem(msg, len, n, "out of memory for class %s's reference", name);
      break;
    }
    if (rc != 0 || short_class) {
      ts_problem(msg, len, n,
              "class %s: its reference has no usable %dx%d window%s at pyramid level %d (it is %dx%d there); "
              "give a larger reference, or use fewer --levels or a smaller --wn",
              name, p->wn, p->wn, short_class ? " of every parity" : "", l, a.usable[l].w, a.usable[l].h);
      break;
    }
  }
  atlas_free(&a, p->levels);
}

void ts_fill_check_params(const ts_fill_params *p, char *msg, size_t len, int *count) {
  int n = 0;
  ts_params_check(ts_fill_param_table, p, msg, len, &n);
  if (n == 0 && p->wn < p->wb + 2)
    ts_problem(msg, len, &n, "--wn %d: the neighbourhood must be wider than the block (--wb %d), at least %d", p->wn,
            p->wb, p->wb + 2);
  *count += n;
}

int ts_fill_check(const ts_fill_params *p, const ts_fill_input *in, const char *const *names, char *msg,
                  size_t len) {
  int n = 0;
  msg[0] = '\0';
  ts_fill_check_params(p, msg, len, &n);
  if (in->nplanes < 1 || in->nplanes > TS_MAX_PLANES) ts_problem(msg, len, &n, "%d feature planes: need 1..%d", in->nplanes, TS_MAX_PLANES);
  if (in->nclass < 1 || in->nclass > TS_FILL_MAX_CLASSES)
    ts_problem(msg, len, &n, "%d classes: need 1..%d", in->nclass, TS_FILL_MAX_CLASSES);
  if (in->w < 1 || in->h < 1) ts_problem(msg, len, &n, "an image of %dx%d", in->w, in->h);
  if (n > 0) return TS_EINVAL;
  for (size_t i = 0; i < (size_t)in->w * (size_t)in->h; i++)
    if (in->state[i] > in->nclass) {
      ts_problem(msg, len, &n, "pixel (%zu, %zu) is of class %d, beyond the %d classes", i % (size_t)in->w,
              i / (size_t)in->w, in->state[i], in->nclass);
      return TS_EINVAL;
    }
  if (((in->w - 1) >> (p->levels - 1)) + 1 < p->wb)
    ts_problem(msg, len, &n, "--levels %d: the image is smaller than a %dx%d block at the coarsest level; use fewer levels",
            p->levels, p->wb, p->wb);
  for (int c = 1; c <= in->nclass; c++) {
    char num[16];
    snprintf(num, sizeof(num), "%d", c);
    const char *name = names != NULL ? names[c - 1] : num;
    const ts_fill_class *k = &in->cls[c - 1];
    if (k->nsources < 1 || k->nsources > TS_FILL_MAX_SOURCES) {
      ts_problem(msg, len, &n, "class %s: %d reference images, need 1..%d", name, k->nsources, TS_FILL_MAX_SOURCES);
      continue;
    }
    if (!(k->usage_weight >= 0.0 && k->usage_weight <= 100.0))
      ts_problem(msg, len, &n, "class %s: usage weight %g, need 0..100", name, k->usage_weight);
    check_class_levels(p, in, c, name, msg, len, &n);
  }
  return n > 0 ? TS_EINVAL : 0;
}

/* ---- filling one class at one level --------------------------------------- */

typedef struct {
  const ts_fill_params *p;
  const ts_fill_input *in;
  ts_search *search;
  const ts_progress_hooks *hooks;
  ts_fill_result *res;
  image_pyramid ip;
  atlas at[TS_FILL_MAX_CLASSES];
  ts_progress prog;
  /* the level under way */
  int level, klass;
  int w, h;
  uint8_t *done;  /* pixel states for the class being filled (window.h) */
  uint32_t *copy; /* atlas (x, y) of every filled pixel */
  uint8_t *from;  /* class of every filled pixel, 0 given */
  /* the class under way */
  ts_window win;
  ts_anchors grid;
  ts_plane valid, labels;
  ts_usage usage;
  int image, set;
  ts_fill_queue q;
  ts_rng rng;
  /* step scratch */
  uint32_t *pos;
  uint8_t *cls;
  ts_l1_best *best;
  ts_place *places;
  uint32_t cap;
} engine;

static double level_cost(int l) { return 1.0 / (double)(1ull << (2 * l)); }

static int ensure_scratch(engine *e, uint32_t n) {
  if (n <= e->cap) return 0;
  free(e->pos);
  free(e->cls);
  free(e->best);
  free(e->places);
  e->pos = malloc(sizeof(uint32_t) * n);
  e->cls = malloc(n);
  e->best = malloc(sizeof(ts_l1_best) * n);
  e->places = malloc(sizeof(ts_place) * n);
  e->cap = e->pos && e->cls && e->best && e->places ? n : 0;
  return e->cap ? 0 : TS_ENOMEM;
}

/* The pixel states while class c is filled: given pixels and earlier
 * classes' are fixed, c's free, later classes' closed. */
static void class_states(engine *e, int c) {
  const uint8_t *s = e->ip.state[e->level].px;
  for (size_t i = 0; i < (size_t)e->w * (size_t)e->h; i++)
    e->done[i] = s[i] == 0 || s[i] < c ? TS_DONE_FIXED : s[i] == c ? TS_DONE_FREE : TS_DONE_CLOSED;
}

/* Copies atlas block (sx, sy) onto the free pixels of the block at (x, y);
 * returns the pixels written. */
static uint32_t copy_block(engine *e, const atlas *a, int x, int y, int sx, int sy) {
  int l = e->level, bw = e->p->wb < e->w - x ? e->p->wb : e->w - x, bh = e->p->wb < e->h - y ? e->p->wb : e->h - y;
  uint32_t n = 0;
  for (int dy = 0; dy < bh; dy++)
    for (int dx = 0; dx < bw; dx++) {
      size_t o = (size_t)(y + dy) * (size_t)e->w + (size_t)(x + dx);
      if (e->done[o] != TS_DONE_FREE) continue;
      for (int k = 0; k < e->in->nplanes; k++) e->ip.planes[k][l].px[o] = ts_plane_at(&a->planes[k][l], sx + dx, sy + dy);
      e->copy[2 * o] = (uint32_t)(sx + dx);
      e->copy[2 * o + 1] = (uint32_t)(sy + dy);
      e->from[o] = (uint8_t)e->klass;
      e->done[o] = TS_DONE_PLACED;
      n++;
    }
  ts_usage_commit(&e->usage, sx, sy, bw, bh, 1);
  return n;
}

/* Places block b from anchor `index`, here and (as one of np) on the
 * backend's replica; the queue re-sorts its neighbours. */
static void place(engine *e, uint32_t b, uint32_t index, uint32_t *np) {
  int x, y, sx, sy;
  ts_fill_queue_block_xy(&e->q, b, &x, &y);
  ts_anchors_pos(&e->grid, index, &sx, &sy);
  copy_block(e, &e->at[e->klass - 1], x, y, sx, sy);
  ts_fill_queue_placed(&e->q, b, e->done);
  e->places[(*np)++] = (ts_place){(uint32_t)y * (uint32_t)e->w + (uint32_t)x, (uint32_t)sy * (uint32_t)e->grid.w + (uint32_t)sx};
}

static int block_class(const engine *e, uint32_t b) {
  int x, y;
  ts_fill_queue_block_xy(&e->q, b, &x, &y);
  return e->p->parity ? ts_parity_class(x, y) : 0;
}

/* An area with nothing known around it, at the coarsest level: its first
 * block copies a reference block drawn with the seed (of its parity). */
static int seed_block(engine *e, uint32_t b, char *err) {
  if (ensure_scratch(e, 1) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
  int k = block_class(e, b);
  uint32_t index = e->grid.base[k] + ts_rng_below(&e->rng, e->grid.count[k]);
  uint32_t np = 0;
  place(e, b, index, &np);
  e->res->level[e->level].seeds++;
  return ts_search_place(e->search, e->image, e->places, np, err);
}

/* Searches the step's blocks (split into batches of at most max_batch, one
 * set of independent requests) and places them. */
#define STEP_MAX_REQS 32
static int search_step(engine *e, const uint32_t *blocks, uint32_t n, char *err) {
  if (ensure_scratch(e, n) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
  for (uint32_t i = 0; i < n; i++) {
    int x, y;
    ts_fill_queue_block_xy(&e->q, blocks[i], &x, &y);
    e->pos[i] = (uint32_t)y * (uint32_t)e->w + (uint32_t)x;
    e->cls[i] = (uint8_t)block_class(e, blocks[i]);
  }
  double alpha = e->in->cls[e->klass - 1].usage_weight;
  uint64_t usage_k = alpha > 0 ? ts_usage_factor(&e->usage, alpha, ts_window_unit_distance(&e->win)) : 0;
  uint32_t chunk = e->p->max_batch ? e->p->max_batch : n;
  ts_search_req req[STEP_MAX_REQS];
  uint32_t nr = 0;
  for (uint32_t i0 = 0; i0 < n; i0 += chunk) {
    uint32_t m = n - i0 < chunk ? n - i0 : chunk;
    req[nr++] = (ts_search_req){e->set, {m, e->pos + i0, 1, e->cls + i0, usage_k}, e->best + i0};
    if (nr == STEP_MAX_REQS || i0 + m >= n) {
      int rc = ts_search_query_many(e->search, req, nr, err);
      if (rc != 0) return rc;
      nr = 0;
    }
  }
  uint32_t np = 0;
  for (uint32_t i = 0; i < n; i++) {
    if (e->best[i].index >= e->grid.total) return ts_error(err, TS_EPROTO, "search returned no match for a block");
    place(e, blocks[i], e->best[i].index, &np);
  }
  return ts_search_place(e->search, e->image, e->places, np, err);
}

/* Steps until every block of the class is placed. */
static int run_queue(engine *e, char *err) {
  int coarsest = e->level == e->p->levels - 1;
  ts_fill_level_stats *ls = &e->res->level[e->level];
  while (!ts_fill_queue_empty(&e->q)) {
    const uint32_t *blocks;
    uint32_t n;
    int context = ts_fill_queue_step(&e->q, !coarsest, &blocks, &n);
    int rc = context ? search_step(e, blocks, n, err) : seed_block(e, blocks[0], err);
    if (rc != 0) return rc;
    ls->steps++;
    ls->blocks += n;
    e->prog.done += n;
    e->prog.work_done += n * level_cost(e->level);
    if (e->hooks->progress) e->hooks->progress(e->hooks->progress_ctx, &e->prog);
  }
  return 0;
}

static void class_free(engine *e) {
  if (e->set >= 0) ts_search_release(e->search, e->set);
  if (e->image >= 0) ts_search_image_close(e->search, e->image);
  e->set = e->image = -1;
  ts_fill_queue_free(&e->q);
  ts_usage_free(&e->usage);
  ts_anchors_free(&e->grid);
  ts_window_free(&e->win);
  ts_plane_free(&e->valid);
  ts_plane_free(&e->labels);
}

/* The backend's query image for class c: the level's planes and states,
 * bounded, with the class's atlas level to copy from and no copy map. */
static int open_class_image(engine *e, const atlas *a, char *err) {
  int l = e->level;
  ts_replica_desc d = {.w = e->w, .h = e->h, .nplanes = e->in->nplanes, .bounded = 1, .done = e->done,
                       .block = e->p->wb, .rw = a->planes[0][l].w, .rh = a->planes[0][l].h};
  for (int k = 0; k < e->in->nplanes; k++) {
    d.fine[k] = e->ip.planes[k][l].px;
    d.ref[k] = a->planes[k][l].px;
    if (l + 1 < e->p->levels) d.coarse[k] = e->ip.planes[k][l + 1].px;
  }
  if (l + 1 < e->p->levels) {
    d.cw = e->ip.planes[0][l + 1].w;
    d.ch = e->ip.planes[0][l + 1].h;
  }
  return ts_search_image_open(e->search, &d, &e->image, err);
}

static int fill_class(engine *e, int c, char *err) {
  const ts_fill_params *p = e->p;
  int l = e->level, coarse = l + 1 < p->levels;
  const atlas *a = &e->at[c - 1];
  e->klass = c;
  class_states(e, c);
  if (e->in->nclass > 1)
    snprintf(e->prog.stage, sizeof(e->prog.stage), "%.24s, class %d of %d", e->in->names ? e->in->names[c - 1] : "class",
             c, e->in->nclass);
  ts_rng_seed(&e->rng, p->seed, (uint64_t)l << 8 | (uint64_t)c);
  int rc = level_anchors(a, l, p->levels, p, e->in->nplanes, &e->grid, &e->valid, &e->labels, err);
  if (rc == 0) rc = ts_neigh_window(&e->win, TS_SHAPE_FREE, p->wn, p->wb, coarse, e->in->nplanes, p->coarse_weight, err);
  double alpha = e->in->cls[c - 1].usage_weight;
  if (rc == 0 && (rc = ts_usage_init(&e->usage, &e->grid, p->wb, alpha > 0)) != 0) ts_error(err, rc, "out of memory");
  if (rc == 0 && (rc = ts_fill_queue_init(&e->q, e->done, e->ip.state[l].px, c, e->w, e->h, p)) != 0)
    ts_error(err, rc, "out of memory for the block queue");
  if (rc == 0) rc = open_class_image(e, a, err);
  ts_levelplanes ref;
  for (int k = 0; k < e->in->nplanes; k++) {
    ref.fine[k] = &a->planes[k][l];
    ref.coarse[k] = coarse ? &a->planes[k][l + 1] : NULL;
  }
  if (rc == 0) {
    ts_refset rs = {e->image, &e->win, &e->grid, &ref, p->parity ? &e->labels : NULL, &e->valid, alpha > 0, NULL, 0};
    rc = ts_search_prepare(e->search, &rs, &e->set, err);
  }
  if (rc == 0) rc = run_queue(e, err);
  if (rc == 0 && l == 0) {
    ts_fill_class_stats *cs = &e->res->cls[c - 1];
    ts_usage_stats(&e->usage, &cs->usage_mean, &cs->usage_variance);
    cs->blocks = e->q.placed;
  }
  class_free(e);
  return rc;
}

/* ---- the seam cut (fill_seams.h) ------------------------------------------ */

/* Cuts the seams of the finished level 0: the work pixels' copies as
 * filled, and the given pixels' where the input names them. */
static int cut_seams(engine *e, char *err) {
  const ts_fill_input *in = e->in;
  size_t npx = (size_t)e->w * (size_t)e->h;
  uint8_t *cls = malloc(npx), *movable = malloc(npx);
  ts_seam_ref ref[TS_FILL_MAX_CLASSES];
  int rc = cls != NULL && movable != NULL ? 0 : ts_error(err, TS_ENOMEM, "out of memory for the seam cut");
  for (size_t i = 0; rc == 0 && i < npx; i++) {
    movable[i] = e->from[i] != 0;
    cls[i] = e->from[i];
    int g = movable[i] || in->given_from == NULL ? 0 : in->given_from[i];
    if (g < 1 || g > in->nclass) continue;
    const atlas *a = &e->at[g - 1];
    if (in->given_copy[2 * i] >= (uint32_t)in->cls[g - 1].src[0].w || in->given_copy[2 * i + 1] >= (uint32_t)a->h0[0])
      continue; /* not a copy of this fill's references: it stays as it is */
    cls[i] = (uint8_t)g;
    movable[i] = in->given_cut != NULL && in->given_cut[i];
    e->copy[2 * i] = in->given_copy[2 * i];
    e->copy[2 * i + 1] = in->given_copy[2 * i + 1]; /* the first source's rows start the atlas */
  }
  for (int c = 0; rc == 0 && c < in->nclass; c++) {
    const atlas *a = &e->at[c];
    ref[c] = (ts_seam_ref){a->w, a->h, {NULL}, a->usable[0].px, a->nsrc, a->y0, a->h0};
    for (int k = 0; k < in->nplanes; k++) ref[c].planes[k] = a->planes[k][0].px;
  }
  ts_seam_image im = {e->w, e->h, in->nplanes, {NULL}, e->copy, cls, movable, ref, e->p->seam_cut};
  for (int k = 0; k < in->nplanes; k++) im.planes[k] = e->ip.planes[k][0].px;
  uint64_t moved;
  if (rc == 0 && ts_fill_cut_seams(&im, &moved) != 0)
    rc = ts_error(err, TS_ENOMEM, "out of memory for the seam cut");
  /* Given pixels have no copy in the result but those the cut changed
   * (given_cut), which take the class they were given with. */
  for (size_t i = 0; rc == 0 && i < npx; i++) {
    if (e->from[i] != 0) continue;
    if (movable[i] && (e->copy[2 * i] != in->given_copy[2 * i] || e->copy[2 * i + 1] != in->given_copy[2 * i + 1]))
      e->from[i] = cls[i];
    else
      e->copy[2 * i] = e->copy[2 * i + 1] = 0;
  }
  free(cls);
  free(movable);
  return rc;
}

/* ---- levels -------------------------------------------------------------- */

static void level_stats_from(engine *e, const ts_search_stats *base, double t0) {
  ts_fill_level_stats *ls = &e->res->level[e->level];
  const ts_search_stats *s = &e->search->stats;
  ls->w = e->w;
  ls->h = e->h;
  ls->pairs = s->pairs - base->pairs;
  ls->round_trips = s->round_trips - base->round_trips;
  ls->wire_bytes = s->bytes_out + s->bytes_in - (base->bytes_out + base->bytes_in);
  ls->seconds = ts_now() - t0;
}

static int fill_level(engine *e, int l, char *err) {
  double t0 = ts_now();
  ts_search_stats base = e->search->stats;
  e->level = l;
  e->w = e->ip.state[l].w;
  e->h = e->ip.state[l].h;
  size_t npx = (size_t)e->w * (size_t)e->h;
  free(e->done);
  free(e->copy);
  free(e->from);
  e->done = malloc(npx);
  e->copy = calloc(2 * npx, sizeof(uint32_t));
  e->from = calloc(npx, 1);
  if (e->done == NULL || e->copy == NULL || e->from == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  e->prog.level = l;
  e->prog.done = 0;
  e->prog.total = ts_fill_level_blocks(e->ip.state[l].px, e->w, e->h, e->in->nclass, e->p->wb);
  int rc = 0;
  for (int c = 1; rc == 0 && c <= e->in->nclass; c++)
    if (ts_fill_class_blocks(e->ip.state[l].px, e->w, e->h, c, e->p->wb) > 0) rc = fill_class(e, c, err);
  level_stats_from(e, &base, t0);
  return rc;
}

/* The finished level 0: the filled planes, and every pixel's source. */
static int take_result(engine *e, char *err) {
  ts_fill_result *r = e->res;
  size_t npx = (size_t)e->w * (size_t)e->h;
  r->w = e->w;
  r->h = e->h;
  r->nplanes = e->in->nplanes;
  r->source = malloc(npx);
  if (r->source == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  for (int k = 0; k < e->in->nplanes; k++) {
    r->planes[k] = e->ip.planes[k][0].px;
    e->ip.planes[k][0].px = NULL;
  }
  for (size_t i = 0; i < npx; i++) {
    if (e->from[i] == 0) {
      r->source[i] = TS_FILL_NO_SOURCE;
      continue;
    }
    const atlas *a = &e->at[e->from[i] - 1];
    int s = atlas_source_of(a, (int)e->copy[2 * i + 1]);
    r->source[i] = (uint8_t)s;
    e->copy[2 * i + 1] -= (uint32_t)a->y0[s];
  }
  r->copy = e->copy;
  e->copy = NULL;
  return 0;
}

static void engine_free(engine *e) {
  class_free(e);
  image_pyramid_free(&e->ip);
  for (int c = 0; c < e->in->nclass; c++) atlas_free(&e->at[c], e->p->levels);
  free(e->done);
  free(e->copy);
  free(e->from);
  free(e->pos);
  free(e->cls);
  free(e->best);
  free(e->places);
}

int ts_fill_synthesize(const ts_fill_params *p, const ts_fill_input *in, ts_search *search,
                       const ts_progress_hooks *hooks, ts_fill_result *res, char *err) {
  memset(res, 0, sizeof(*res));
  char msg[2048];
  if (ts_fill_check(p, in, NULL, msg, sizeof(msg)) != 0) return ts_error(err, TS_EINVAL, "%s", msg);
  static const ts_progress_hooks none = {0};
  double t0 = ts_now();
  engine e;
  memset(&e, 0, sizeof(e));
  e.p = p;
  e.in = in;
  e.search = search;
  e.hooks = hooks ? hooks : &none;
  e.res = res;
  e.image = e.set = -1;
  e.prog.levels = p->levels;
  int rc = image_pyramid_build(&e.ip, in, p->levels);
  for (int c = 0; rc == 0 && c < in->nclass; c++) rc = atlas_build(&e.at[c], &in->cls[c], in->nplanes, p->levels);
  if (rc != 0) rc = ts_error(err, rc, "out of memory for the pyramids");
  for (int l = 0; rc == 0 && l < p->levels; l++)
    e.prog.work_total += (double)ts_fill_level_blocks(e.ip.state[l].px, e.ip.state[l].w, e.ip.state[l].h,
                                                      in->nclass, p->wb) * level_cost(l);
  for (int l = p->levels - 1; rc == 0 && l >= 0; l--) rc = fill_level(&e, l, err);
  if (rc == 0 && p->seam_cut > 0) rc = cut_seams(&e, err);
  if (rc == 0) rc = take_result(&e, err);
  engine_free(&e);
  res->seconds = ts_now() - t0;
  if (rc != 0) ts_fill_result_free(res);
  return rc;
}

void ts_fill_result_free(ts_fill_result *res) {
  for (int k = 0; k < TS_MAX_PLANES; k++) {
    free(res->planes[k]);
    res->planes[k] = NULL;
  }
  free(res->copy);
  free(res->source);
  res->copy = NULL;
  res->source = NULL;
}

void ts_fill_report_params(FILE *f, const ts_fill_params *p) {
  fprintf(f, "\"levels\": %d, \"wn\": %d, \"wb\": %d, \"parity\": %s, \"coarse_weight\": %g, \"order\": \"%s\", "
             "\"threshold\": %g, \"seed\": %llu, \"seam_cut\": %d",
          p->levels, p->wn, p->wb, p->parity ? "true" : "false", p->coarse_weight,
          p->order == TS_FILL_THRESHOLD ? "threshold" : "puzzle", p->threshold, (unsigned long long)p->seed, p->seam_cut);
}

void ts_fill_report_levels(FILE *f, const ts_fill_params *p, const ts_fill_result *r) {
  fprintf(f, "  \"levels\": [\n");
  for (int l = p->levels - 1; l >= 0; l--) {
    const ts_fill_level_stats *s = &r->level[l];
    fprintf(f, "    {\"level\": %d, \"out\": [%d, %d], \"blocks\": %llu, \"steps\": %llu, \"seeds\": %llu, "
               "\"comparisons\": %llu, \"wire_bytes\": %llu, \"round_trips\": %llu, \"seconds\": %.4f}%s\n",
            l, s->w, s->h, (unsigned long long)s->blocks, (unsigned long long)s->steps, (unsigned long long)s->seeds,
            (unsigned long long)s->pairs, (unsigned long long)s->wire_bytes, (unsigned long long)s->round_trips,
            s->seconds, l > 0 ? "," : "");
  }
  fprintf(f, "  ]\n");
}
