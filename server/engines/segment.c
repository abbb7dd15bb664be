/* segment.c - the segmentation's levels through the search service
 * (segment.h): the pyramids, each query image (the input, or a half of a
 * training image) segmented against its reference images, the
 * self-segmentation counts, then fusion, noise reduction and accuracy. */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "segment.h"
#include "stylit.h"
#include "util.h"

/* Queries per batch and requests per query_many call (a cluster takes 64
 * at most): only the traffic's shape, never the result. 4096 queries of
 * 88 bytes (a 9x9 window) against each reference set make a batch a
 * worker streams its slice once for. */
#define BATCH 4096
#define REQS_PER_CALL 64

/* An image the search compares: its planes and its class map, one size. */
typedef struct {
  ts_plane planes[TS_SEG_MAX_PLANES];
  ts_plane cls; /* class indices; unused (empty) for the input */
} layer;

typedef struct {
  const ts_seg_params *p;
  ts_search *search;
  const ts_progress_hooks *h;
  int levels, r, nplanes, nclass;
  ts_window win;
  /* [level]: the input, and per pair the training image. */
  layer in[TS_SEG_MAX_LEVELS];
  layer train[TS_SEG_MAX_PAIRS][TS_SEG_MAX_LEVELS];
  uint8_t *seg[TS_SEG_MAX_LEVELS]; /* the input's class map per level */
  ts_progress prog;
  ts_seg_result *res;
} run;

static void layer_free(layer *a) {
  for (int k = 0; k < TS_SEG_MAX_PLANES; k++) ts_plane_free(&a->planes[k]);
  ts_plane_free(&a->cls);
}

/* ---- set-up -------------------------------------------------------------- */

/* N x N window offsets from the top-left corner; one part of weight 1. */
static int build_window(run *e, char *err) {
  int n = e->p->window;
  int16_t dx[TS_SEG_MAX_WINDOW * TS_SEG_MAX_WINDOW], dy[TS_SEG_MAX_WINDOW * TS_SEG_MAX_WINDOW];
  int no = 0;
  for (int y = 0; y < n; y++)
    for (int x = 0; x < n; x++) {
      dx[no] = (int16_t)x;
      dy[no++] = (int16_t)y;
    }
  ts_window_spec s = {.nplanes = {e->nplanes, 0}, .noff = {no, 0}, .dx = {dx, NULL}, .dy = {dy, NULL},
                      .extent = {{0, 0, (int16_t)n, (int16_t)n}}, .block = 1, .nparts = 1};
  s.part[0] = (ts_part){TS_SRC_FINE, 0, (uint8_t)e->nplanes, 1};
  return ts_window_init(&e->win, &s, err);
}

/* A class map's level l: its pixel (x << l, y << l), the centre of the
 * level-l pixel's Gaussian. */
static int reduce_classes(const ts_plane *base, int l, int w, int h, ts_plane *out) {
  if (ts_plane_alloc(out, w, h) != 0) return TS_ENOMEM;
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) out->px[(size_t)y * (size_t)w + (size_t)x] = ts_plane_at(base, x << l, y << l);
  return 0;
}

/* The pyramid of an image's planes (and of its class map when given). */
static int build_layers(run *e, const ts_image *img, const ts_image *labels, const ts_seg_classes *c, layer *out) {
  ts_plane base[TS_SEG_MAX_PLANES] = {{0}}, cls = {0};
  ts_plane pyr[TS_SEG_MAX_LEVELS];
  int rc = ts_seg_planes(img, e->p->rgb, base);
  for (int k = 0; rc == 0 && k < e->nplanes; k++) {
    rc = ts_pyramid_build(&base[k], e->levels, pyr);
    for (int l = 0; rc == 0 && l < e->levels; l++) out[l].planes[k] = pyr[l];
  }
  if (rc == 0 && labels != NULL) {
    rc = ts_plane_alloc(&cls, img->width, img->height);
    if (rc == 0) ts_seg_class_map(c, labels, cls.px);
    for (int l = 0; rc == 0 && l < e->levels; l++)
      rc = reduce_classes(&cls, l, out[l].planes[0].w, out[l].planes[0].h, &out[l].cls);
  }
  for (int k = 0; k < TS_SEG_MAX_PLANES; k++) ts_plane_free(&base[k]);
  ts_plane_free(&cls);
  return rc;
}

static void report_progress(run *e, uint64_t queries, double pairs) {
  e->prog.done += queries;
  e->prog.work_done += pairs;
  if (e->h != NULL && e->h->progress != NULL) e->h->progress(e->h->progress_ctx, &e->prog);
}

/* ---- one query image ----------------------------------------------------- */

static uint64_t anchors_of(const run *e, const layer *a) {
  int n = e->p->window;
  return (uint64_t)(a->planes[0].w - n + 1) * (uint64_t)(a->planes[0].h - n + 1);
}

/* The reference sets of one query image, prepared for it (set -1: not
 * prepared). */
typedef struct {
  int n;
  const layer *ref[TS_SEG_MAX_PAIRS];
  ts_anchors grid[TS_SEG_MAX_PAIRS];
  int set[TS_SEG_MAX_PAIRS];
  ts_levelplanes lp[TS_SEG_MAX_PAIRS];
} refsets;

static int refsets_open(run *e, refsets *rs, int image, char *err) {
  for (int j = 0; j < rs->n; j++) {
    const ts_plane *pl = &rs->ref[j]->planes[0];
    int rc = ts_anchors_init(&rs->grid[j], &e->win, pl->w, pl->h, 0, 0, NULL, 1, NULL, err);
    for (int k = 0; rc == 0 && k < e->nplanes; k++) rs->lp[j].fine[k] = &rs->ref[j]->planes[k];
    ts_refset s = {image, &e->win, &rs->grid[j], &rs->lp[j], NULL, NULL, 0, NULL, 0};
    if (rc == 0) rc = ts_search_prepare(e->search, &s, &rs->set[j], err);
    if (rc != 0) return rc;
  }
  return 0;
}

static void refsets_close(run *e, refsets *rs) {
  for (int j = 0; j < rs->n; j++) {
    if (rs->set[j] >= 0) ts_search_release(e->search, rs->set[j]);
    ts_anchors_free(&rs->grid[j]);
  }
}

/* The classes of queries [i0, i0 + n) from their answers in every set
 * (best[j][i - i0]): the smallest distance, ties to the earlier set (the
 * search already took the lower index within one). */
static void take_classes(const run *e, const refsets *rs, ts_l1_best *const *best, uint32_t n, uint8_t *out) {
  for (uint32_t i = 0; i < n; i++) {
    int j = 0;
    for (int t = 1; t < rs->n; t++)
      if (best[t][i].dist < best[j][i].dist) j = t;
    int x, y;
    ts_anchors_pos(&rs->grid[j], best[j][i].index, &x, &y);
    out[i] = ts_plane_at(&rs->ref[j]->cls, x + e->r, y + e->r);
  }
}

/* Every pixel of q (w x h, padded by the window's radius as the query
 * image) against the sets: class into out. As many batches per call as
 * REQS_PER_CALL holds, each in every set. */
static int query_all(run *e, const refsets *rs, int w, int h, ts_l1_best *scratch, uint8_t *out, char *err) {
  uint32_t n = (uint32_t)w * (uint32_t)h, pw = (uint32_t)(w + 2 * e->r);
  uint32_t chunks = (uint32_t)(REQS_PER_CALL / rs->n);
  uint32_t *pos = malloc(sizeof(*pos) * n);
  if (pos == NULL) return ts_error(err, TS_ENOMEM, "out of memory for %u queries", n);
  for (uint32_t i = 0; i < n; i++) pos[i] = (i / (uint32_t)w) * pw + i % (uint32_t)w;
  uint64_t per_query = 0;
  for (int j = 0; j < rs->n; j++) per_query += anchors_of(e, rs->ref[j]);
  int rc = 0;
  for (uint32_t i0 = 0; rc == 0 && i0 < n; i0 += chunks * BATCH) {
    ts_search_req req[REQS_PER_CALL];
    uint32_t nr = 0, c0 = i0;
    for (uint32_t c = 0; c < chunks && c0 < n; c++, c0 += BATCH) {
      uint32_t nq = n - c0 < BATCH ? n - c0 : BATCH;
      for (int j = 0; j < rs->n; j++, nr++) {
        req[nr] = (ts_search_req){rs->set[j], {nq, pos + c0, 0, NULL, 0}, scratch + (size_t)nr * BATCH};
        ts_l1_best_reset(req[nr].out, nq);
      }
    }
    rc = ts_search_query_many(e->search, req, nr, err);
    for (uint32_t r = 0; rc == 0 && r < nr; r += (uint32_t)rs->n) {
      ts_l1_best *best[TS_SEG_MAX_PAIRS];
      for (int j = 0; j < rs->n; j++) best[j] = req[r + (uint32_t)j].out;
      uint32_t q0 = (uint32_t)(req[r].b.pos - pos);
      take_classes(e, rs, best, req[r].b.nq, out + q0);
    }
    if (rc == 0) report_progress(e, c0 - i0, (double)(c0 - i0) * (double)per_query);
  }
  free(pos);
  return rc;
}

/* Segments a query image (its planes, w x h) against refs: classes into
 * out (w x h). */
static int segment_image(run *e, const layer *q, const layer *const *refs, int nref, uint8_t *out, char *err) {
  int w = q->planes[0].w, h = q->planes[0].h;
  ts_plane pad[TS_SEG_MAX_PLANES] = {{0}};
  const ts_plane *t[TS_SEG_MAX_PLANES];
  for (int k = 0; k < e->nplanes; k++) t[k] = &q->planes[k];
  int image = -1, rc = ts_stylit_pad(t, e->nplanes, e->r, pad);
  if (rc != 0) rc = ts_error(err, TS_ENOMEM, "out of memory for a %dx%d query image", w, h);
  ts_replica_desc d = {.w = w + 2 * e->r, .h = h + 2 * e->r, .nplanes = e->nplanes};
  for (int k = 0; k < e->nplanes; k++) d.fine[k] = pad[k].px;
  if (rc == 0) rc = ts_search_image_open(e->search, &d, &image, err);
  refsets rs = {.n = nref};
  for (int j = 0; j < nref; j++) {
    rs.ref[j] = refs[j];
    rs.set[j] = -1;
  }
  ts_l1_best *scratch = rc == 0 ? malloc(sizeof(*scratch) * REQS_PER_CALL * BATCH) : NULL;
  if (rc == 0 && scratch == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory for the answers");
  if (rc == 0) rc = refsets_open(e, &rs, image, err);
  if (rc == 0) rc = query_all(e, &rs, w, h, scratch, out, err);
  refsets_close(e, &rs);
  free(scratch);
  if (image >= 0) ts_search_image_close(e->search, image);
  for (int k = 0; k < TS_SEG_MAX_PLANES; k++) ts_plane_free(&pad[k]);
  return rc;
}

/* ---- self-segmentation --------------------------------------------------- */

/* A w x h crop of a plane at (x0, y0). */
static int crop(const ts_plane *src, int x0, int y0, int w, int h, ts_plane *dst) {
  if (ts_plane_alloc(dst, w, h) != 0) return TS_ENOMEM;
  for (int y = 0; y < h; y++)
    memcpy(dst->px + (size_t)y * (size_t)w, src->px + (size_t)(y0 + y) * (size_t)src->w + (size_t)x0, (size_t)w);
  return 0;
}

/* The two halves of a layer, cut across the longer side of the training
 * image (wide: at level 0; the same cut at every level). */
static int halves(const run *e, const layer *a, int wide, layer *half) {
  int w = a->planes[0].w, h = a->planes[0].h;
  int hw = wide ? w / 2 : w, hh = wide ? h : h / 2;
  int rc = 0;
  for (int s = 0; s < 2 && rc == 0; s++) {
    int x0 = wide && s ? hw : 0, y0 = !wide && s ? hh : 0, cw = wide && s ? w - hw : hw, ch = !wide && s ? h - hh : hh;
    for (int k = 0; rc == 0 && k < e->nplanes; k++) rc = crop(&a->planes[k], x0, y0, cw, ch, &half[s].planes[k]);
    if (rc == 0) rc = crop(&a->cls, x0, y0, cw, ch, &half[s].cls);
  }
  return rc;
}

/* Both halves of training image t at level l, each against the other half
 * and every other training image: their counts into the result. */
static int self_segment(run *e, int t, int l, char *err) {
  layer half[2] = {{{{0}}}};
  const ts_plane *base = &e->train[t][0].planes[0];
  int rc = halves(e, &e->train[t][l], base->w >= base->h, half);
  if (rc != 0) rc = ts_error(err, TS_ENOMEM, "out of memory for the halves of training image %d", t + 1);
  for (int s = 0; rc == 0 && s < 2; s++) {
    const layer *refs[TS_SEG_MAX_PAIRS];
    int n = 0;
    refs[n++] = &half[1 - s];
    for (int u = 0; u < e->p->pairs; u++)
      if (u != t) refs[n++] = &e->train[u][l];
    size_t np = (size_t)half[s].cls.w * (size_t)half[s].cls.h;
    uint8_t *got = malloc(np);
    if (got == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory");
    if (rc == 0) rc = segment_image(e, &half[s], refs, n, got, err);
    size_t row = (size_t)l * (size_t)e->nclass;
    if (rc == 0) ts_seg_count(got, half[s].cls.px, np, e->res->self_total + row, e->res->self_correct + row);
    free(got);
  }
  layer_free(&half[0]);
  layer_free(&half[1]);
  return rc;
}

/* ---- levels -------------------------------------------------------------- */

/* The comparisons of a level: every input pixel against every training
 * window, and (several levels) every training pixel against the windows
 * of the other half and the other training images. */
static double level_work(const run *e, int l) {
  double train = 0, self = 0;
  for (int t = 0; t < e->p->pairs; t++) train += (double)anchors_of(e, &e->train[t][l]);
  if (e->levels > 1)
    for (int t = 0; t < e->p->pairs; t++) {
      const ts_plane *pl = &e->train[t][l].planes[0];
      double others = train - (double)anchors_of(e, &e->train[t][l]);
      /* Each half against the other (about half the windows) and the rest. */
      self += (double)pl->w * pl->h * (others + (double)anchors_of(e, &e->train[t][l]) / 2);
    }
  const ts_plane *in = &e->in[l].planes[0];
  return (double)in->w * in->h * train + self;
}

static uint64_t level_queries(const run *e, int l) {
  uint64_t n = (uint64_t)e->in[l].planes[0].w * (uint64_t)e->in[l].planes[0].h;
  for (int t = 0; e->levels > 1 && t < e->p->pairs; t++)
    n += (uint64_t)e->train[t][l].planes[0].w * (uint64_t)e->train[t][l].planes[0].h;
  return n;
}

static int run_level(run *e, int l, char *err) {
  ts_seg_level_stats *st = &e->res->level[l];
  double t0 = ts_now();
  ts_search_stats s0 = e->search->stats;
  st->w = e->in[l].planes[0].w;
  st->h = e->in[l].planes[0].h;
  e->prog.level = l;
  e->prog.done = 0;
  e->prog.total = level_queries(e, l);
  int rc = 0;
  for (int t = 0; rc == 0 && e->levels > 1 && t < e->p->pairs; t++) rc = self_segment(e, t, l, err);
  st->self_seconds = ts_now() - t0;
  st->self_queries = level_queries(e, l) - (uint64_t)st->w * (uint64_t)st->h;
  const layer *refs[TS_SEG_MAX_PAIRS];
  for (int t = 0; t < e->p->pairs; t++) refs[t] = &e->train[t][l];
  e->seg[l] = rc == 0 ? malloc((size_t)st->w * (size_t)st->h) : NULL;
  if (rc == 0 && e->seg[l] == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory for level %d's labels", l);
  if (rc == 0) rc = segment_image(e, &e->in[l], refs, e->p->pairs, e->seg[l], err);
  st->seconds = ts_now() - t0;
  st->pairs = e->search->stats.pairs - s0.pairs;
  st->queries = (uint64_t)st->w * (uint64_t)st->h;
  return rc;
}

/* ---- the result ---------------------------------------------------------- */

/* The levels' maps fused at level 0 (one level: its map). */
static void fuse(run *e, uint8_t *out) {
  double t0 = ts_now();
  ts_seg_result *res = e->res;
  int w = e->in[0].planes[0].w, h = e->in[0].planes[0].h;
  if (e->levels == 1) {
    memcpy(out, e->seg[0], (size_t)w * (size_t)h);
  } else {
    ts_seg_weights(e->levels, e->nclass, res->self_correct, res->self_total, res->rate, res->weight);
    const uint8_t *lab[TS_SEG_MAX_LEVELS];
    int lw[TS_SEG_MAX_LEVELS], lh[TS_SEG_MAX_LEVELS];
    for (int l = 0; l < e->levels; l++) {
      lab[l] = e->seg[l];
      lw[l] = e->in[l].planes[0].w;
      lh[l] = e->in[l].planes[0].h;
    }
    ts_seg_fuse(e->levels, e->nclass, lab, lw, lh, res->weight, w, h, out);
  }
  res->fuse_seconds = ts_now() - t0;
}

/* With a truth: what each level alone gets right, and per class what the
 * fused map gets right (before noise reduction). */
static int count_truth(run *e, const ts_image *truth, const uint8_t *fused, uint8_t *tmap, char *err) {
  ts_seg_result *res = e->res;
  int w = e->in[0].planes[0].w, h = e->in[0].planes[0].h;
  size_t n = (size_t)w * (size_t)h;
  ts_seg_class_map(&res->classes, truth, tmap);
  ts_seg_count(fused, tmap, n, res->truth_pixels, res->correct_before);
  uint8_t *up = malloc(n);
  if (up == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  for (int l = 0; l < e->levels; l++) {
    ts_seg_upsample(e->seg[l], e->in[l].planes[0].w, e->in[l].planes[0].h, l, w, h, up);
    uint64_t pixels[TS_SEG_MAX_CLASSES] = {0}, correct[TS_SEG_MAX_CLASSES] = {0};
    ts_seg_count(up, tmap, n, pixels, correct);
    for (int k = 0; k < e->nclass; k++) res->level[l].correct += correct[k];
  }
  free(up);
  res->has_truth = 1;
  return 0;
}

/* The output raster: the classes' label values. */
static int make_labels(run *e, const uint8_t *map, char *err) {
  ts_seg_result *res = e->res;
  int w = e->in[0].planes[0].w, h = e->in[0].planes[0].h;
  int rc = ts_image_alloc(&res->labels, w, h, 1, res->classes.wide ? TS_PIX_U16 : TS_PIX_U8, err);
  for (size_t i = 0; rc == 0 && i < (size_t)w * (size_t)h; i++) {
    uint16_t v = res->classes.value[map[i]];
    if (res->classes.wide) ((uint16_t *)res->labels.pixels)[i] = v;
    else ((uint8_t *)res->labels.pixels)[i] = (uint8_t)v;
  }
  return rc;
}

/* Fusion, the truth's counts, noise reduction, the output. */
static int finish(run *e, const ts_image *truth, char *err) {
  ts_seg_result *res = e->res;
  size_t n = (size_t)e->in[0].planes[0].w * (size_t)e->in[0].planes[0].h;
  uint8_t *map = malloc(n), *tmap = truth != NULL ? malloc(n) : NULL;
  int rc = map != NULL && (truth == NULL || tmap != NULL) ? 0 : ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0) fuse(e, map);
  if (rc == 0 && truth != NULL) rc = count_truth(e, truth, map, tmap, err);
  double t0 = ts_now();
  if (rc == 0 && ts_seg_denoise(map, e->in[0].planes[0].w, e->in[0].planes[0].h, (uint32_t)e->p->denoise,
                                &res->denoise) != 0)
    rc = ts_error(err, TS_ENOMEM, "out of memory for the noise reduction");
  res->denoise_seconds = ts_now() - t0;
  if (rc == 0 && truth != NULL) {
    uint64_t pixels[TS_SEG_MAX_CLASSES] = {0};
    ts_seg_count(map, tmap, n, pixels, res->correct_after);
  }
  if (rc == 0) rc = make_labels(e, map, err);
  free(map);
  free(tmap);
  return rc;
}

/* ---- the run ------------------------------------------------------------- */

static int setup(run *e, const ts_image *const *in, char *err) {
  ts_seg_classes_find(e->p, in, &e->res->classes);
  e->nclass = e->res->classes.n;
  int rc = build_layers(e, in[TS_SEG_IN_INPUT], NULL, NULL, e->in);
  for (int t = 0; rc == 0 && t < e->p->pairs; t++)
    rc = build_layers(e, in[ts_seg_in_train(t)], in[ts_seg_in_labels(t)], &e->res->classes, e->train[t]);
  if (rc != 0) return ts_error(err, TS_ENOMEM, "out of memory for the images' pyramids");
  rc = build_window(e, err);
  e->prog = (ts_progress){.levels = e->levels};
  for (int l = 0; rc == 0 && l < e->levels; l++) e->prog.work_total += level_work(e, l);
  return rc;
}

static void run_free(run *e) {
  for (int l = 0; l < TS_SEG_MAX_LEVELS; l++) {
    layer_free(&e->in[l]);
    for (int t = 0; t < TS_SEG_MAX_PAIRS; t++) layer_free(&e->train[t][l]);
    free(e->seg[l]);
  }
  ts_window_free(&e->win);
}

int ts_seg_run(const ts_seg_params *p, const ts_image *const *in, ts_search *search, const ts_progress_hooks *h,
               ts_seg_result *res, char *err) {
  memset(res, 0, sizeof(*res));
  double t0 = ts_now();
  run *e = calloc(1, sizeof(*e));
  if (e == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  *e = (run){.p = p, .search = search, .h = h, .levels = p->levels, .r = p->window / 2,
             .nplanes = p->rgb ? 3 : 1, .res = res};
  res->levels = p->levels;
  int rc = setup(e, in, err);
  for (int l = e->levels - 1; rc == 0 && l >= 0; l--) rc = run_level(e, l, err);
  if (rc == 0) rc = finish(e, p->truth ? in[ts_seg_in_truth(p)] : NULL, err);
  res->seconds = ts_now() - t0;
  run_free(e);
  free(e);
  if (rc != 0) ts_seg_result_free(res);
  return rc;
}

void ts_seg_result_free(ts_seg_result *res) { ts_image_free(&res->labels); }

/* ---- the accuracy table -------------------------------------------------- */

static double share(uint64_t part, uint64_t whole) { return whole > 0 ? (double)part / (double)whole : 0.0; }

typedef struct {
  char *buf;
  size_t cap, used;
  int over; /* the text outgrew cap */
} text;

static void put(text *t, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void put(text *t, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  size_t room = t->used < t->cap ? t->cap - t->used : 0;
  int n = vsnprintf(t->buf + (room ? t->used : 0), room, fmt, ap);
  va_end(ap);
  if (n < 0 || (size_t)n >= room) t->over = 1;
  else t->used += (size_t)n;
}

int ts_seg_accuracy_text(const ts_seg_result *res, int denoise, char *buf, size_t cap) {
  text t = {buf, cap, 0, cap == 0};
  uint64_t all = 0, before = 0, after = 0;
  put(&t, "accuracy: the share of each class's truth pixels labelled right, before and after noise reduction "
          "(--denoise %d)\n", denoise);
  put(&t, "%-8s %10s %8s %8s\n", "class", "pixels", "before", "after");
  for (int k = 0; k < res->classes.n; k++) {
    uint64_t n = res->truth_pixels[k];
    all += n;
    before += res->correct_before[k];
    after += res->correct_after[k];
    if (n == 0) put(&t, "%-8u %10s %8s %8s\n", res->classes.value[k], "0", "-", "-");
    else
      put(&t, "%-8u %10llu %8.4f %8.4f\n", res->classes.value[k], (unsigned long long)n,
          share(res->correct_before[k], n), share(res->correct_after[k], n));
  }
  put(&t, "%-8s %10llu %8.4f %8.4f\n", "overall", (unsigned long long)all, share(before, all), share(after, all));
  return t.over ? TS_ETOOBIG : (int)t.used;
}
