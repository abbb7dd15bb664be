/* test_mrf.c - the synthesis engine: exactness against an independent
 * brute-force backend, independence from batching and threads, colour
 * gathering, resuming from checkpoints after and inside levels, parameter
 * errors; best-of candidates, texture mixing and the copy-map shortcut. */
#include <stdlib.h>

#include "checkpoint.h"
#include "error.h"
#include "image.h"
#include "mrf.h"
#include "replica.h"
#include "rng.h"
#include "search.h"
#include "ts_test.h"
#include "usage.h"

/* ---- a brute-force search backend: one query at a time, plain loops ---- */

typedef struct {
  int used, image;
  ts_window shape;
  ts_anchors grid;
  ts_levelplanes ref;
  ts_usage usage;
} brute_set;

/* Query vectors come out of the query image's replica (replica.h), as
 * on every backend; the distances and minima are plain loops. */
typedef struct {
  ts_search base;
  brute_set sets[4];
  ts_replica image;
  int image_used;
  ts_query_scratch scratch;
} brute_search;

static int brute_image_open(ts_search *s, const ts_replica_desc *d, int *id, char *err) {
  brute_search *b = (brute_search *)s;
  assert_false(b->image_used);
  assert_int_equal(ts_replica_init(&b->image, d, err), 0);
  b->image_used = 1;
  *id = 0;
  return 0;
}

static int brute_image_next(ts_search *s, int id, int w, int h, int rw, int rh, const uint8_t *const *ref,
                            char *err) {
  assert_int_equal(id, 0);
  return ts_replica_next_level(&((brute_search *)s)->image, w, h, rw, rh, ref, err);
}

static int brute_place(ts_search *s, int id, const ts_place *p, uint32_t n, char *err) {
  brute_search *b = (brute_search *)s;
  assert_int_equal(id, 0);
  ts_commit *c = malloc(sizeof(ts_commit) * 2 * (n + 1));
  uint32_t nc;
  assert_int_equal(ts_replica_place(&b->image, p, n, c, &nc, err), 0);
  for (int k = 0; k < 4; k++)
    for (uint32_t i = 0; b->sets[k].used && i < nc; i++)
      ts_usage_commit(&b->sets[k].usage, c[i].x, c[i].y, c[i].w, c[i].h, c[i].delta);
  free(c);
  return 0;
}

static void brute_image_close(ts_search *s, int id) {
  brute_search *b = (brute_search *)s;
  assert_int_equal(id, 0);
  ts_replica_free(&b->image);
  ts_query_scratch_free(&b->scratch);
  b->image_used = 0;
}

static int brute_prepare(ts_search *s, const ts_refset *rs, int *id, char *err) {
  brute_search *b = (brute_search *)s;
  int k = 0;
  while (b->sets[k].used) k++;
  brute_set *st = &b->sets[k];
  st->used = 1;
  /* copy the window: the engine frees its own at the end of the level
   * (the anchors live until the set is released) */
  assert_int_equal(ts_window_init(&st->shape, &rs->window->spec, err), 0);
  st->grid = *rs->anchors;
  st->ref = *rs->ref;
  assert_int_equal(ts_usage_init(&st->usage, rs->anchors, rs->window->spec.block, 1), 0);
  if (rs->counts != NULL) ts_usage_load(&st->usage, rs->counts->count);
  *id = k;
  return 0;
}

static int brute_query(ts_search *s, int id, const ts_query_batch *pb, ts_l1_best *out, char *err) {
  brute_search *bs = (brute_search *)s;
  brute_set *st = &bs->sets[id];
  ts_vec_batch vecs, *qb = &vecs;
  assert_int_equal(ts_query_vectors(&bs->scratch, &bs->image, &st->shape, pb, qb, err), 0);
  uint32_t vb = ts_window_bytes(&st->shape);
  uint8_t vec[TS_L1_MAX_CHUNKS * 8];
  for (uint32_t q = 0; q < qb->nq; q++) {
    const uint8_t *qv = qb->queries + (size_t)q * vb;
    const uint8_t *mv = qb->masks ? qb->masks + (size_t)q * vb : NULL;
    out[q].dist = UINT64_MAX;
    out[q].index = UINT32_MAX;
    for (uint32_t j = 0; j < st->grid.total; j++) {
      int x, y;
      if (ts_anchors_class(&st->grid, j) != (qb->klass ? qb->klass[q] : 0)) continue;
      ts_anchors_pos(&st->grid, j, &x, &y);
      ts_vec_ref(&st->shape, &st->ref, x, y, vec);
      uint64_t d = ts_usage_penalty(st->usage.u[j], qb->usage_k);
      int part = 0;
      for (uint32_t k = 0; k < vb; k++) {
        while (k >= st->shape.part_end[part] * 8) part++;
        uint64_t a = qv[k] > vec[k] ? qv[k] - vec[k] : vec[k] - qv[k];
        if (mv == NULL || mv[k] != 0) d += a * st->shape.spec.part[part].weight;
      }
      if (d < out[q].dist) {
        out[q].dist = d;
        out[q].index = j;
      }
    }
  }
  s->stats.queries += qb->nq;
  return 0;
}

static void brute_release(ts_search *s, int id) {
  brute_set *st = &((brute_search *)s)->sets[id];
  ts_window_free(&st->shape);
  ts_usage_free(&st->usage);
  st->used = 0;
}

static void brute_destroy(ts_search *s) { free(s); }

static const ts_search_ops brute_ops = {.name = "brute",
                                        .prepare = brute_prepare,
                                        .image_open = brute_image_open,
                                        .image_next = brute_image_next,
                                        .place = brute_place,
                                        .image_close = brute_image_close,
                                        .query = brute_query,
                                        .release = brute_release,
                                        .destroy = brute_destroy};

static ts_search *brute_create(void) {
  brute_search *b = calloc(1, sizeof(*b));
  b->base.ops = &brute_ops;
  return &b->base;
}

/* ---- fixtures ------------------------------------------------------------ */

/* A structured 8-bit RGB reference: stripes + blobs + noise. */
static void make_reference(ts_image *img, int w, int h, ts_pixtype type) {
  char err[TS_ERR_LEN];
  assert_int_equal(ts_image_alloc(img, w, h, 3, type, err), 0);
  ts_rng rng;
  ts_rng_seed(&rng, 7, 0);
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      int v[3] = {(x * 9 + y * 3) % 200 + (int)ts_rng_below(&rng, 40), ((x / 5 + y / 7) % 3) * 90,
                  (int)ts_rng_below(&rng, 255)};
      for (int c = 0; c < 3; c++) {
        long o = ((long)y * w + x) * 3 + c;
        if (type == TS_PIX_U8) ((uint8_t *)img->pixels)[o] = (uint8_t)v[c];
        else ((uint16_t *)img->pixels)[o] = (uint16_t)(v[c] * 257 + c);
      }
    }
}

static ts_mrf_params small_params(void) {
  ts_mrf_params p;
  ts_mrf_params_default(&p);
  p.width = 40;
  p.height = 34;
  p.levels = 3;
  p.wn = 7;
  p.wb = 3;
  p.seed = 11;
  return p;
}

static void run(const ts_mrf_params *p, const ts_image *ref, ts_search *s, ts_mrf_result *res) {
  char err[TS_ERR_LEN] = "";
  int rc = ts_mrf_synthesize(p, ref, s, NULL, res, err);
  if (rc != 0) fail_msg("synthesis failed: %s", err);
}

static void assert_same_result(const ts_mrf_result *a, const ts_mrf_result *b) {
  size_t n = (size_t)a->image.width * a->image.height;
  assert_memory_equal(a->copy_map, b->copy_map, n * 2 * sizeof(uint32_t));
  assert_memory_equal(a->image.pixels, b->image.pixels, n * 3 * ts_pixtype_size(a->image.type));
  assert_int_equal(a->ref_w, b->ref_w);
  assert_memory_equal(a->usage, b->usage, (size_t)a->ref_w * a->ref_h * sizeof(uint32_t));
}

/* The engine with the SIMD local backend on whole steps equals the
 * brute-force backend fed one query per batch: the search is exact and the
 * batching changes nothing - with and without parity and usage penalty. */
static void engine_matches_brute_force(void **state) {
  (void)state;
  ts_image ref;
  make_reference(&ref, 36, 32, TS_PIX_U8);
  for (int variant = 0; variant < 3; variant++) {
    ts_mrf_params p = small_params();
    p.parity = variant == 1;
    p.usage_weight = variant == 2 ? 1.5 : 0.0;
    ts_search *local, *brute = brute_create();
    char err[TS_ERR_LEN];
    assert_int_equal(ts_search_local_create(&local, 2, NULL, err), 0);
    ts_search_local_set_inline(local, 0);
    ts_mrf_result a, b;
    run(&p, &ref, local, &a);
    p.max_batch = 1;
    run(&p, &ref, brute, &b);
    assert_same_result(&a, &b);
    ts_mrf_result_free(&a);
    ts_mrf_result_free(&b);
    ts_search_destroy(local);
    ts_search_destroy(brute);
  }
  ts_image_free(&ref);
}

static void threads_and_variants_give_same_bytes(void **state) {
  (void)state;
  ts_image ref;
  make_reference(&ref, 48, 40, TS_PIX_U8);
  ts_mrf_params p = small_params();
  p.width = 64;
  p.height = 50;
  ts_mrf_result base;
  ts_search *s;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_search_local_create(&s, 1, ts_l1_impl_get(TS_SIMD_SCALAR), err), 0);
  run(&p, &ref, s, &base);
  ts_search_destroy(s);
  for (int v = 0; v < TS_SIMD_COUNT; v++) {
    const ts_l1_impl *impl = ts_l1_impl_get((ts_simd)v);
    if (impl == NULL) continue;
    for (int threads = 1; threads <= 3; threads++) {
      ts_mrf_result r;
      assert_int_equal(ts_search_local_create(&s, threads, impl, err), 0);
      ts_search_local_set_inline(s, 0); /* every batch through the pool */
      run(&p, &ref, s, &r);
      assert_same_result(&base, &r);
      ts_mrf_result_free(&r);
      ts_search_destroy(s);
    }
  }
  ts_mrf_result_free(&base);
  ts_image_free(&ref);
}

static void seed_changes_output(void **state) {
  (void)state;
  ts_image ref;
  make_reference(&ref, 48, 40, TS_PIX_U8);
  ts_mrf_params p = small_params();
  ts_search *s;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_search_local_create(&s, 2, NULL, err), 0);
  ts_mrf_result a, b, c;
  run(&p, &ref, s, &a);
  run(&p, &ref, s, &b);
  p.seed = 12;
  run(&p, &ref, s, &c);
  assert_same_result(&a, &b);
  size_t n = (size_t)p.width * p.height * 3;
  assert_true(memcmp(a.image.pixels, c.image.pixels, n) != 0);
  ts_mrf_result_free(&a);
  ts_mrf_result_free(&b);
  ts_mrf_result_free(&c);
  ts_search_destroy(s);
  ts_image_free(&ref);
}

/* 16-bit RGB in, 16-bit RGB out, every pixel a reference pixel at the copy
 * map's position; usage counts add up to the output area. */
static void colour_is_gathered_through_copy_map(void **state) {
  (void)state;
  ts_image ref;
  make_reference(&ref, 40, 36, TS_PIX_U16);
  ts_mrf_params p = small_params();
  p.rgb_search = 1;
  ts_search *s;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_search_local_create(&s, 2, NULL, err), 0);
  ts_mrf_result r;
  run(&p, &ref, s, &r);
  assert_int_equal(r.image.type, TS_PIX_U16);
  assert_int_equal(r.image.channels, 3);
  const uint16_t *out = r.image.pixels, *in = ref.pixels;
  for (long i = 0; i < (long)p.width * p.height; i++) {
    uint32_t x = r.copy_map[2 * i], y = r.copy_map[2 * i + 1];
    assert_true(x < 40 && y < 36);
    for (int c = 0; c < 3; c++) assert_int_equal(out[3 * i + c], in[((long)y * 40 + x) * 3 + c]);
  }
  uint64_t total = 0;
  for (int i = 0; i < 40 * 36; i++) total += r.usage[i];
  assert_int_equal(total, (uint64_t)p.width * p.height);
  ts_mrf_result_free(&r);
  ts_search_destroy(s);
  ts_image_free(&ref);
}

/* Every level's checkpoint, kept as encoded bytes as the spool keeps them. */
typedef struct {
  int levels;
  uint8_t *bytes[TS_MRF_MAX_LEVELS];
  size_t len[TS_MRF_MAX_LEVELS];
} saved_checkpoints;

static int keep_checkpoint(void *ctx, const ts_mrf_checkpoint *ck, char *err) {
  saved_checkpoints *sc = ctx;
  assert_null(sc->bytes[ck->level]);
  return ts_checkpoint_encode(ck, sc->levels, 42, &sc->bytes[ck->level], &sc->len[ck->level], err);
}

/* Resumed after any level, from decoded checkpoint bytes, synthesis gives
 * the bytes of the uninterrupted run: the checkpoint holds all the state
 * the finer levels depend on. */
static void resuming_after_any_level_gives_same_bytes(void **state) {
  (void)state;
  ts_image ref;
  make_reference(&ref, 96, 80, TS_PIX_U8);
  ts_mrf_params p = small_params();
  p.levels = 4;
  p.width = 72;
  p.height = 56;
  p.usage_weight = 1.0;
  ts_search *s;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_search_local_create(&s, 2, NULL, err), 0);
  saved_checkpoints sc = {.levels = p.levels};
  ts_mrf_hooks save = {.checkpoint = keep_checkpoint, .checkpoint_ctx = &sc};
  ts_mrf_result base;
  if (ts_mrf_synthesize(&p, &ref, s, &save, &base, err) != 0) fail_msg("%s", err);
  assert_null(sc.bytes[0]); /* the last level has a result, not a checkpoint */
  for (int l = 1; l < p.levels; l++) {
    assert_non_null(sc.bytes[l]);
    ts_mrf_checkpoint ck;
    assert_int_equal(ts_checkpoint_decode(sc.bytes[l], sc.len[l], 42, 1u << 20, &ck, err), 0);
    assert_int_equal(ck.level, l);
    ts_mrf_hooks resume = {.resume = &ck};
    ts_mrf_result r;
    assert_int_equal(ts_mrf_synthesize(&p, &ref, s, &resume, &r, err), 0);
    assert_same_result(&base, &r);
    assert_int_equal(r.level[l].blocks, base.level[l].blocks); /* carried statistics */
    ts_mrf_result_free(&r);
    ts_checkpoint_free(&ck);
    free(sc.bytes[l]);
  }
  ts_mrf_result_free(&base);
  ts_search_destroy(s);
  ts_image_free(&ref);
}

/* A checkpoint of another size or level count is refused, not trusted. */
static void foreign_checkpoint_is_refused(void **state) {
  (void)state;
  ts_image ref;
  make_reference(&ref, 48, 40, TS_PIX_U8);
  ts_mrf_params p = small_params();
  ts_search *s;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_search_local_create(&s, 1, NULL, err), 0);
  saved_checkpoints sc = {.levels = p.levels};
  ts_mrf_hooks save = {.checkpoint = keep_checkpoint, .checkpoint_ctx = &sc};
  ts_mrf_result r;
  assert_int_equal(ts_mrf_synthesize(&p, &ref, s, &save, &r, err), 0);
  ts_mrf_result_free(&r);
  ts_mrf_checkpoint ck;
  assert_int_equal(ts_checkpoint_decode(sc.bytes[1], sc.len[1], 42, 1u << 20, &ck, err), 0);
  ts_mrf_hooks resume = {.resume = &ck};
  p.width += 8;
  assert_int_equal(ts_mrf_synthesize(&p, &ref, s, &resume, &r, err), TS_EINVAL);
  assert_non_null(strstr(err, "does not belong to this job"));
  p.width -= 8;
  ck.copy[0] = 1000; /* points outside the reference */
  assert_int_equal(ts_mrf_synthesize(&p, &ref, s, &resume, &r, err), TS_EINVAL);
  assert_non_null(strstr(err, "outside"));
  ts_checkpoint_free(&ck);
  for (int l = 0; l < TS_MRF_MAX_LEVELS; l++) free(sc.bytes[l]);
  ts_search_destroy(s);
  ts_image_free(&ref);
}

/* Checkpoints inside levels, as encoded bytes, kept at a few chosen steps
 * of every level: the first, a quarter, half, three quarters and the last
 * but one (scan and sweeps alike), taken with an interval so short that
 * one falls between every two steps. */
#define MAX_INSIDE 64
typedef struct {
  int levels, n;
  uint8_t *bytes[MAX_INSIDE];
  size_t len[MAX_INSIDE];
} inside_checkpoints;

static int keep_inside(void *ctx, const ts_mrf_checkpoint *ck, char *err) {
  inside_checkpoints *ic = ctx;
  uint64_t s = ck->step, n = ck->steps;
  if (s == n || !(s == 1 || s == n / 4 || s == n / 2 || s == 3 * n / 4 || s == n - 1)) return 0;
  assert_true(ic->n < MAX_INSIDE);
  assert_non_null(ck->done);
  int k = ic->n++;
  return ts_checkpoint_encode(ck, ic->levels, 42, &ic->bytes[k], &ic->len[k], err);
}

static void inside_free(inside_checkpoints *ic) {
  for (int k = 0; k < ic->n; k++) free(ic->bytes[k]);
  ic->n = 0;
}

static ts_mrf_params inside_params(int variant) {
  ts_mrf_params p = small_params();
  p.levels = 4;
  p.width = 72;
  p.height = 56;
  p.parity = variant & 1;
  p.usage_weight = variant & 2 ? 1.0 : 0.0;
  p.rgb_search = variant == 3;
  if (variant >= 4) { /* partitioned (lbg.h): every level, or level 1 alone */
    p.lbg = 2;
    p.lbg_levels = variant == 4 ? TS_MRF_LBG_ALL : 2u;
  }
  return p;
}

/* The uninterrupted run, and every kept checkpoint inside a level of a run
 * that checkpointed between every two steps. */
static void run_with_inside_checkpoints(const ts_mrf_params *p, const ts_image *ref, ts_search *s,
                                        ts_mrf_result *base, inside_checkpoints *ic) {
  char err[TS_ERR_LEN];
  run(p, ref, s, base);
  ic->levels = p->levels;
  ts_mrf_hooks save = {.checkpoint = keep_inside, .checkpoint_ctx = ic, .checkpoint_interval = 1e-12};
  ts_mrf_result r;
  if (ts_mrf_synthesize(p, ref, s, &save, &r, err) != 0) fail_msg("%s", err);
  assert_same_result(base, &r); /* checkpoints never change the result */
  ts_mrf_result_free(&r);
  assert_true(ic->n >= 4 * p->levels);
}

static void note_resumed(void *ctx, const ts_mrf_resume *r) { *(ts_mrf_resume *)ctx = *r; }

/* Resumed from a checkpoint taken inside any level, at any step, synthesis
 * goes on at that step and gives the uninterrupted run's bytes (image,
 * copy map and usage map), its steps and its blocks: with and without
 * parity and the usage penalty (whose counters the backend's replicas
 * must start from), on luminance and on colour, and with partitioned
 * (LBG) sets, whose codebooks are built again. */
static void resuming_inside_a_level_gives_same_bytes(void **state) {
  (void)state;
  ts_image ref;
  make_reference(&ref, 96, 80, TS_PIX_U8);
  char err[TS_ERR_LEN];
  for (int variant = 0; variant < 6; variant++) {
    ts_mrf_params p = inside_params(variant);
    ts_search *s;
    assert_int_equal(ts_search_local_create(&s, 2, NULL, err), 0);
    ts_mrf_result base;
    inside_checkpoints ic = {0};
    run_with_inside_checkpoints(&p, &ref, s, &base, &ic);
    if (variant >= 4) /* some set was partitioned: the finest level's, or level 1's full window */
      assert_true(variant == 4 ? base.lbg[0].partitioned[0] : base.lbg[1].partitioned[1]);
    for (int k = 0; k < ic.n; k++) {
      ts_mrf_checkpoint ck;
      assert_int_equal(ts_checkpoint_decode(ic.bytes[k], ic.len[k], 42, 1u << 20, &ck, err), 0);
      ts_mrf_resume where = {.level = -1};
      ts_mrf_hooks resume = {.resume = &ck, .resumed = note_resumed, .resume_ctx = &where};
      ts_mrf_result r;
      if (ts_mrf_synthesize(&p, &ref, s, &resume, &r, err) != 0) fail_msg("variant %d: %s", variant, err);
      assert_true(r.resumed);
      assert_int_equal(where.level, ck.level);
      assert_int_equal(where.step, ck.step);
      assert_true(where.level_done > 0 && where.level_done < 1);
      assert_same_result(&base, &r);
      for (int l = 0; l < p.levels; l++) {
        assert_int_equal(r.level[l].steps, base.level[l].steps);
        assert_int_equal(r.level[l].blocks, base.level[l].blocks);
        /* what was partitioned is known past the resume too */
        assert_memory_equal(r.lbg[l].partitioned, base.lbg[l].partitioned, sizeof(r.lbg[l].partitioned));
      }
      ts_mrf_result_free(&r);
      ts_checkpoint_free(&ck);
    }
    inside_free(&ic);
    ts_mrf_result_free(&base);
    ts_search_destroy(s);
  }
  ts_image_free(&ref);
}

/* The same through the brute-force backend, which builds its usage
 * replica from the counts it is given: the interface carries them. */
static void resumed_usage_reaches_the_backend(void **state) {
  (void)state;
  ts_image ref;
  make_reference(&ref, 96, 80, TS_PIX_U8);
  ts_mrf_params p = inside_params(2);
  p.max_batch = 7;
  ts_search *s = brute_create();
  char err[TS_ERR_LEN];
  ts_mrf_result base;
  inside_checkpoints ic = {0};
  run_with_inside_checkpoints(&p, &ref, s, &base, &ic);
  ts_mrf_checkpoint ck;
  assert_int_equal(ts_checkpoint_decode(ic.bytes[ic.n - 3], ic.len[ic.n - 3], 42, 1u << 20, &ck, err), 0);
  assert_int_equal(ck.level, 0);
  ts_mrf_hooks resume = {.resume = &ck};
  ts_mrf_result r;
  assert_int_equal(ts_mrf_synthesize(&p, &ref, s, &resume, &r, err), 0);
  assert_same_result(&base, &r);
  ts_mrf_result_free(&r);
  ts_checkpoint_free(&ck);
  inside_free(&ic);
  ts_mrf_result_free(&base);
  ts_search_destroy(s);
  ts_image_free(&ref);
}

static void note_refused(void *ctx, const char *why) { snprintf(ctx, TS_ERR_LEN, "%s", why); }

/* An intact checkpoint (right checksum and tag) whose state is not one
 * this job passes through is refused with the reason: a step that is not
 * its statistics', placed blocks or usage counters that are not those of
 * its steps, sizes of another job. With a `refused` hook the synthesis
 * starts over instead, with the uninterrupted run's bytes. */
static void inconsistent_inside_checkpoint_is_refused(void **state) {
  (void)state;
  ts_image ref;
  make_reference(&ref, 96, 80, TS_PIX_U8);
  ts_mrf_params p = inside_params(2);
  ts_search *s;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_search_local_create(&s, 1, NULL, err), 0);
  ts_mrf_result base, r;
  inside_checkpoints ic = {0};
  run_with_inside_checkpoints(&p, &ref, s, &base, &ic);
  const int pick = ic.n - 4; /* inside level 0 */
  struct {
    const char *reason;
  } lies[] = {{"at step"}, {"which has"}, {"placed blocks"}, {"usage counters"}, {"blocks searched"},
              {"does not belong"}, {"outside"}};
  for (size_t i = 0; i < sizeof(lies) / sizeof(lies[0]); i++) {
    ts_mrf_checkpoint ck;
    assert_int_equal(ts_checkpoint_decode(ic.bytes[pick], ic.len[pick], 42, 1u << 20, &ck, err), 0);
    size_t npx = (size_t)ck.width * ck.height;
    switch (i) {
    case 0: ck.step--; break;
    case 1: ck.steps++; break;
    case 2: ck.done[npx - 1] ^= 1; break;
    case 3: ck.usage[ck.copy[1] * (uint32_t)ck.ref_width + ck.copy[0]]++; break;
    case 4: ck.stats[ck.level].blocks++; break;
    case 5: ck.coarse_width++; break;
    case 6: ck.copy[2 * npx - 1] = 1000; break;
    }
    ts_mrf_hooks resume = {.resume = &ck};
    err[0] = '\0';
    assert_int_equal(ts_mrf_synthesize(&p, &ref, s, &resume, &r, err), TS_EINVAL);
    if (strstr(err, lies[i].reason) == NULL) fail_msg("lie %zu: expected '%s' in '%s'", i, lies[i].reason, err);
    char why[TS_ERR_LEN] = "";
    ts_mrf_hooks start_over = {.resume = &ck, .refused = note_refused, .resume_ctx = why};
    assert_int_equal(ts_mrf_synthesize(&p, &ref, s, &start_over, &r, err), 0);
    assert_string_equal(why, err);
    assert_false(r.resumed);
    assert_same_result(&base, &r);
    ts_mrf_result_free(&r);
    ts_checkpoint_free(&ck);
  }
  inside_free(&ic);
  ts_mrf_result_free(&base);
  ts_search_destroy(s);
  ts_image_free(&ref);
}

static void bad_parameters_are_all_listed(void **state) {
  (void)state;
  ts_mrf_params p = small_params();
  p.wb = 4;
  p.wn = 2;
  p.levels = 0;
  p.usage_weight = -1;
  char msg[2048];
  assert_int_equal(ts_mrf_check(&p, 64, 64, 3, msg, sizeof(msg)), TS_EINVAL);
  assert_non_null(strstr(msg, "--wb 4"));
  assert_non_null(strstr(msg, "--wn 2"));
  assert_non_null(strstr(msg, "--levels 0"));
  assert_non_null(strstr(msg, "--usage-weight"));
  p = small_params();
  p.wn = 3;
  p.wb = 3;
  assert_int_equal(ts_mrf_check(&p, 64, 64, 3, msg, sizeof(msg)), TS_EINVAL);
  assert_non_null(strstr(msg, "wider than the block"));
  p = small_params();
  p.levels = 6; /* 64 -> 2 at level 5 */
  assert_int_equal(ts_mrf_check(&p, 64, 64, 3, msg, sizeof(msg)), TS_EINVAL);
  assert_non_null(strstr(msg, "coarsest level"));
  assert_non_null(strstr(msg, "reference"));
  p = small_params();
  assert_int_equal(ts_mrf_check(&p, 64, 64, 3, msg, sizeof(msg)), 0);
}


/* ---- best-of, mixing, the copy-map shortcut ------------------------------ */

/* Passive variance optimisation: every candidate's variance is listed, the
 * chosen one has the least (ties: the lowest number), the first is the
 * job's own seed, and the result is byte for byte a plain run with the
 * chosen seed - through the SIMD backend and the brute-force one alike
 * (each candidate reopens the backend's replica). */
static void best_of_equals_a_plain_run_of_the_chosen_seed(void **state) {
  (void)state;
  ts_image ref;
  make_reference(&ref, 64, 56, TS_PIX_U8);
  ts_mrf_params p = small_params();
  p.levels = 4;
  p.width = 72;
  p.height = 56;
  p.best_of = 4;
  ts_search *local, *brute = brute_create();
  char err[TS_ERR_LEN];
  assert_int_equal(ts_search_local_create(&local, 2, NULL, err), 0);
  ts_mrf_result best, via_brute, plain;
  run(&p, &ref, local, &best);
  assert_int_equal(best.ncandidates, 4);
  assert_int_equal(best.best_of_level, 2); /* all but the finest two */
  assert_int_equal(best.candidate[0].seed, p.seed);
  for (int k = 0; k < 4; k++) {
    assert_true(best.candidate[best.chosen].variance <= best.candidate[k].variance);
    if (k < best.chosen) assert_true(best.candidate[k].variance > best.candidate[best.chosen].variance);
    for (int j = 0; j < k; j++) assert_true(best.candidate[j].seed != best.candidate[k].seed);
  }
  ts_mrf_params q = p;
  q.max_batch = 1;
  run(&q, &ref, brute, &via_brute);
  assert_same_result(&best, &via_brute);
  q = p;
  q.best_of = 1;
  q.seed = best.candidate[best.chosen].seed;
  run(&q, &ref, local, &plain);
  assert_same_result(&best, &plain);
  assert_int_equal(plain.ncandidates, 0);
  ts_mrf_result_free(&best);
  ts_mrf_result_free(&via_brute);
  ts_mrf_result_free(&plain);
  ts_search_destroy(local);
  ts_search_destroy(brute);
  ts_image_free(&ref);
}

/* Best-of candidates take no checkpoints; the chosen one's last candidate
 * level and every level after it do, inside and at their ends, and a run
 * resumed from any of them gives the uninterrupted run's bytes (without
 * the candidates, which it did not run). */
static void best_of_resumes_after_the_choice(void **state) {
  (void)state;
  ts_image ref;
  make_reference(&ref, 96, 80, TS_PIX_U8);
  ts_mrf_params p = inside_params(2);
  p.best_of = 3;
  ts_search *s;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_search_local_create(&s, 2, NULL, err), 0);
  ts_mrf_result base;
  inside_checkpoints ic = {0};
  run(&p, &ref, s, &base);
  ic.levels = p.levels;
  saved_checkpoints sc = {.levels = p.levels};
  ts_mrf_hooks ends = {.checkpoint = keep_checkpoint, .checkpoint_ctx = &sc};
  ts_mrf_hooks inside = {.checkpoint = keep_inside, .checkpoint_ctx = &ic, .checkpoint_interval = 1e-12};
  ts_mrf_result r;
  assert_int_equal(ts_mrf_synthesize(&p, &ref, s, &ends, &r, err), 0);
  assert_same_result(&base, &r);
  ts_mrf_result_free(&r);
  assert_int_equal(ts_mrf_synthesize(&p, &ref, s, &inside, &r, err), 0);
  assert_same_result(&base, &r);
  ts_mrf_result_free(&r);
  assert_null(sc.bytes[3]); /* a candidate level */
  assert_true(ic.n >= 4);
  int nck = 0;
  ts_mrf_checkpoint cks[MAX_INSIDE + 2];
  for (int l = 1; l <= 2; l++) {
    assert_non_null(sc.bytes[l]);
    assert_int_equal(ts_checkpoint_decode(sc.bytes[l], sc.len[l], 42, 1u << 20, &cks[nck++], err), 0);
  }
  for (int k = 0; k < ic.n; k++) {
    assert_int_equal(ts_checkpoint_decode(ic.bytes[k], ic.len[k], 42, 1u << 20, &cks[nck], err), 0);
    assert_true(cks[nck++].level < 2);
  }
  for (int k = 0; k < nck; k++) {
    ts_mrf_hooks resume = {.resume = &cks[k]};
    if (ts_mrf_synthesize(&p, &ref, s, &resume, &r, err) != 0) fail_msg("checkpoint %d: %s", k, err);
    assert_true(r.resumed);
    assert_int_equal(r.ncandidates, 0);
    assert_same_result(&base, &r);
    ts_mrf_result_free(&r);
    ts_checkpoint_free(&cks[k]);
  }
  inside_free(&ic);
  for (int l = 0; l < TS_MRF_MAX_LEVELS; l++) free(sc.bytes[l]);
  ts_mrf_result_free(&base);
  ts_search_destroy(s);
  ts_image_free(&ref);
}

/* A fine reference unlike make_reference's: vertical bars of 4 grey
 * levels, 16-bit, so its pixels are told apart from the reference's. */
static void make_fine(ts_image *img, int w, int h) {
  char err[TS_ERR_LEN];
  assert_int_equal(ts_image_alloc(img, w, h, 3, TS_PIX_U16, err), 0);
  ts_rng rng;
  ts_rng_seed(&rng, 9, 0);
  uint16_t *px = img->pixels;
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++)
      for (int c = 0; c < 3; c++)
        px[((size_t)y * w + x) * 3 + c] = (uint16_t)(((x / 3) % 4) * 15000 + (int)ts_rng_below(&rng, 3000) + c);
}

/* Texture mixing: the levels from mix_level up are those of a plain run on
 * the reference (the preview there is the same), the finer ones copy from
 * the fine reference, whose pixels the output gathers; the backend's
 * replica is loaded afresh at the switch (the brute-force backend refuses
 * an open without a close, and gives the same bytes). */
static void mixing_takes_the_coarse_levels_from_ref_and_the_rest_from_fine(void **state) {
  (void)state;
  ts_image ref, fine;
  make_reference(&ref, 96, 80, TS_PIX_U8);
  make_fine(&fine, 40, 36);
  ts_mrf_params p = small_params();
  p.levels = 4;
  p.width = 72;
  p.height = 56;
  p.mix_level = 2;
  ts_search *local, *brute = brute_create();
  char err[TS_ERR_LEN];
  assert_int_equal(ts_search_local_create(&local, 2, NULL, err), 0);
  ts_mrf_result mixed, plain, via_brute;
  ts_mrf_params q = p;
  q.stop_level = 2;
  assert_int_equal(ts_mrf_synthesize_mixed(&q, &ref, &fine, local, NULL, &mixed, err), 0);
  q.mix_level = 0;
  run(&q, &ref, local, &plain);
  size_t npx = (size_t)mixed.image.width * mixed.image.height; /* previews: 1 channel, 8 bits */
  assert_int_equal(npx, 18 * 14);
  assert_memory_equal(mixed.copy_map, plain.copy_map, npx * 2 * sizeof(uint32_t));
  assert_memory_equal(mixed.image.pixels, plain.image.pixels, npx);
  ts_mrf_result_free(&mixed);
  ts_mrf_result_free(&plain);
  assert_int_equal(ts_mrf_synthesize_mixed(&p, &ref, &fine, local, NULL, &mixed, err), 0);
  assert_int_equal(mixed.image.type, TS_PIX_U16);
  assert_int_equal(mixed.ref_w, 40);
  assert_int_equal(mixed.level[1].ref_w, 20);
  assert_int_equal(mixed.level[2].ref_w, 24);
  const uint16_t *out = mixed.image.pixels, *in = fine.pixels;
  for (long i = 0; i < (long)p.width * p.height; i++) {
    uint32_t x = mixed.copy_map[2 * i], y = mixed.copy_map[2 * i + 1];
    assert_true(x < 40 && y < 36);
    for (int c = 0; c < 3; c++) assert_int_equal(out[3 * i + c], in[((long)y * 40 + x) * 3 + c]);
  }
  q = p;
  q.max_batch = 1;
  assert_int_equal(ts_mrf_synthesize_mixed(&q, &ref, &fine, brute, NULL, &via_brute, err), 0);
  assert_same_result(&mixed, &via_brute);
  ts_mrf_result_free(&via_brute);
  ts_mrf_result_free(&mixed);
  ts_search_destroy(local);
  ts_search_destroy(brute);
  ts_image_free(&ref);
  ts_image_free(&fine);
}

/* A mixed run resumed inside or after any level - the switch level
 * included - gives the uninterrupted run's bytes. */
static void mixing_resumes_anywhere(void **state) {
  (void)state;
  ts_image ref, fine;
  make_reference(&ref, 96, 80, TS_PIX_U8);
  make_fine(&fine, 48, 40);
  ts_mrf_params p = inside_params(2);
  p.mix_level = 2;
  ts_search *s;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_search_local_create(&s, 2, NULL, err), 0);
  ts_mrf_result base, r;
  assert_int_equal(ts_mrf_synthesize_mixed(&p, &ref, &fine, s, NULL, &base, err), 0);
  inside_checkpoints ic = {.levels = p.levels};
  ts_mrf_hooks save = {.checkpoint = keep_inside, .checkpoint_ctx = &ic, .checkpoint_interval = 1e-12};
  assert_int_equal(ts_mrf_synthesize_mixed(&p, &ref, &fine, s, &save, &r, err), 0);
  ts_mrf_result_free(&r);
  saved_checkpoints sc = {.levels = p.levels};
  ts_mrf_hooks ends = {.checkpoint = keep_checkpoint, .checkpoint_ctx = &sc};
  assert_int_equal(ts_mrf_synthesize_mixed(&p, &ref, &fine, s, &ends, &r, err), 0);
  ts_mrf_result_free(&r);
  int switch_seen = 0;
  for (int k = 0; k < ic.n + p.levels - 1; k++) {
    const uint8_t *bytes = k < ic.n ? ic.bytes[k] : sc.bytes[k - ic.n + 1];
    size_t len = k < ic.n ? ic.len[k] : sc.len[k - ic.n + 1];
    ts_mrf_checkpoint ck;
    assert_int_equal(ts_checkpoint_decode(bytes, len, 42, 1u << 20, &ck, err), 0);
    switch_seen += ck.level == 1 && ck.step < ck.steps;
    ts_mrf_hooks resume = {.resume = &ck};
    if (ts_mrf_synthesize_mixed(&p, &ref, &fine, s, &resume, &r, err) != 0) fail_msg("checkpoint %d: %s", k, err);
    assert_true(r.resumed);
    assert_same_result(&base, &r);
    ts_mrf_result_free(&r);
    ts_checkpoint_free(&ck);
  }
  assert_true(switch_seen > 0);
  inside_free(&ic);
  for (int l = 0; l < TS_MRF_MAX_LEVELS; l++) free(sc.bytes[l]);
  ts_mrf_result_free(&base);
  ts_search_destroy(s);
  ts_image_free(&ref);
  ts_image_free(&fine);
}

/* The copy-map shortcut, forced on (kernel 1, no constancy needed): level
 * 1 measures (over 64 candidates), level 0 copies blocks, the result is
 * marked lossy and is the same through the SIMD backend on 2 threads and
 * the brute-force one fed one query at a time (the copies reach the
 * replica as placements); every candidate was either copied or measured. */
static void copy_accel_is_deterministic_and_reported(void **state) {
  (void)state;
  ts_image ref;
  make_reference(&ref, 96, 80, TS_PIX_U8);
  ts_mrf_params p = inside_params(1); /* parity */
  p.levels = 3;
  p.width = 96;
  p.height = 80;
  p.copy_accel = 1;
  p.accel_kernel = 1;
  p.accel_min = 0;
  ts_search *local, *brute = brute_create();
  char err[TS_ERR_LEN];
  assert_int_equal(ts_search_local_create(&local, 2, NULL, err), 0);
  ts_search_local_set_inline(local, 0);
  ts_mrf_result a, b;
  run(&p, &ref, local, &a);
  p.max_batch = 1;
  run(&p, &ref, brute, &b);
  assert_same_result(&a, &b);
  assert_true(a.lossy);
  assert_int_equal(a.accel[2].role, TS_ACCEL_NONE);
  assert_int_equal(a.accel[1].role, TS_ACCEL_VALIDATE);
  assert_int_equal(a.accel[1].copied, 0);
  assert_int_equal(a.accel[1].measured, a.accel[1].candidates);
  assert_true(a.accel[1].measured >= 64);
  const ts_mrf_accel_stats *st = &a.accel[0];
  assert_int_equal(st->role, TS_ACCEL_ON);
  assert_true(st->copied > 0 && st->searches_saved >= st->copied);
  assert_int_equal(st->copied + st->measured, st->candidates);
  assert_int_equal(st->pool_measured, a.accel[1].measured);
  ts_mrf_result_free(&a);
  ts_mrf_result_free(&b);
  ts_search_destroy(local);
  ts_search_destroy(brute);
  ts_image_free(&ref);
}

/* Without a level above to measure first, the shortcut never copies: with
 * two levels the result is the exact one, not marked lossy. A resume of a
 * --copy-accel job is refused with the reason (such jobs save none). */
static void copy_accel_needs_a_measured_level_and_takes_no_checkpoints(void **state) {
  (void)state;
  ts_image ref;
  make_reference(&ref, 96, 80, TS_PIX_U8);
  ts_mrf_params p = inside_params(1);
  p.levels = 2;
  ts_search *s;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_search_local_create(&s, 2, NULL, err), 0);
  ts_mrf_result exact, accel;
  saved_checkpoints sc = {.levels = p.levels};
  ts_mrf_hooks save = {.checkpoint = keep_checkpoint, .checkpoint_ctx = &sc};
  assert_int_equal(ts_mrf_synthesize(&p, &ref, s, &save, &exact, err), 0);
  p.copy_accel = 1;
  p.accel_min = 0;
  run(&p, &ref, s, &accel);
  assert_same_result(&exact, &accel);
  assert_false(accel.lossy);
  assert_int_equal(accel.accel[0].role, TS_ACCEL_VALIDATE);
  ts_mrf_result_free(&accel);
  ts_mrf_checkpoint ck;
  assert_int_equal(ts_checkpoint_decode(sc.bytes[1], sc.len[1], 42, 1u << 20, &ck, err), 0);
  ts_mrf_hooks resume = {.resume = &ck};
  assert_int_equal(ts_mrf_synthesize(&p, &ref, s, &resume, &accel, err), TS_EINVAL);
  assert_non_null(strstr(err, "--copy-accel takes no checkpoints"));
  ts_checkpoint_free(&ck);
  free(sc.bytes[1]);
  ts_mrf_result_free(&exact);
  ts_search_destroy(s);
  ts_image_free(&ref);
}

/* The options' ranges, and a fine reference too small for its levels or
 * of another channel count under --rgb-search, all listed. */
static void extras_bad_parameters_are_listed(void **state) {
  (void)state;
  ts_mrf_params p = small_params();
  p.best_of = 0;
  p.best_of_levels = 4;
  p.mix_level = 3;
  p.accel_kernel = 4;
  p.accel_min = 1.5;
  char msg[2048];
  assert_int_equal(ts_mrf_check(&p, 64, 64, 3, msg, sizeof(msg)), TS_EINVAL);
  const char *want[] = {"--best-of 0", "--best-of-levels 4", "--mix-level 3", "--copy-accel-kernel 4",
                        "--copy-accel-min 1.5"};
  for (size_t i = 0; i < sizeof(want) / sizeof(want[0]); i++)
    if (strstr(msg, want[i]) == NULL) fail_msg("'%s' not in '%s'", want[i], msg);
  p = small_params();
  p.mix_level = 1;
  p.rgb_search = 1;
  assert_int_equal(ts_mrf_check(&p, 64, 64, 3, msg, sizeof(msg)), 0);
  assert_int_equal(ts_mrf_check_fine(&p, 6, 40, 1, 3, msg, sizeof(msg)), TS_EINVAL);
  assert_non_null(strstr(msg, "--rgb-search"));
  assert_non_null(strstr(msg, "the --ref-fine image (6x40) is smaller"));
  msg[0] = '\0';
  p.mix_level = 2;
  assert_int_equal(ts_mrf_check_fine(&p, 12, 12, 3, 3, msg, sizeof(msg)), TS_EINVAL);
  assert_non_null(strstr(msg, "--mix-level 2: the --ref-fine image (12x12) is 6x6 at level 1"));
  msg[0] = '\0';
  assert_int_equal(ts_mrf_check_fine(&p, 40, 40, 3, 3, msg, sizeof(msg)), 0);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(engine_matches_brute_force),
    cmocka_unit_test(threads_and_variants_give_same_bytes),
    cmocka_unit_test(seed_changes_output),
    cmocka_unit_test(colour_is_gathered_through_copy_map),
    cmocka_unit_test(resuming_after_any_level_gives_same_bytes),
    cmocka_unit_test(foreign_checkpoint_is_refused),
    cmocka_unit_test(resuming_inside_a_level_gives_same_bytes),
    cmocka_unit_test(resumed_usage_reaches_the_backend),
    cmocka_unit_test(inconsistent_inside_checkpoint_is_refused),
    cmocka_unit_test(bad_parameters_are_all_listed),
    cmocka_unit_test(best_of_equals_a_plain_run_of_the_chosen_seed),
    cmocka_unit_test(best_of_resumes_after_the_choice),
    cmocka_unit_test(mixing_takes_the_coarse_levels_from_ref_and_the_rest_from_fine),
    cmocka_unit_test(mixing_resumes_anywhere),
    cmocka_unit_test(copy_accel_is_deterministic_and_reported),
    cmocka_unit_test(copy_accel_needs_a_measured_level_and_takes_no_checkpoints),
    cmocka_unit_test(extras_bad_parameters_are_listed),
};

TS_TEST_MAIN(tests)
