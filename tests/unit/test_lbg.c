/* test_lbg.c - LBG partitioning (lbg.h) and partitioned slices
 * (slice_lbg.c) against definitions written out here: the codebook's
 * build (convergence, determinism over threads, the median), each
 * vector's partition, the distances to the centroids and the nearest
 * ones; and the two-stage search, lossy and exact, over sets with
 * classes, a validity plane, masked queries, usage penalties and ties,
 * whole and in three slices sent through the wire format. */
#include <math.h>
#include <stdlib.h>

#include "anchors.h"
#include "error.h"
#include "lbg.h"
#include "msg.h"
#include "pool.h"
#include "rng.h"
#include "slice.h"
#include "ts_test.h"
#include "usage.h"
#include "window.h"

enum { W = 40, H = 36, CW = 20, CH = 18, NCLASS = 3, NQ = 48 };

/* A window of two weighted fine parts (a 3x3 square over plane 0, weight
 * 3; plane 1's centre, weight 7), a zero-weight part (plane 2's centre)
 * and a 2x2 coarse square, weight 2. */
typedef struct {
  int16_t fdx[9], fdy[9], cdx[4], cdy[4];
  ts_window_spec spec;
  ts_window w;
  ts_anchors a;
  ts_plane fine[3], coarse[1], labels, mask, valid;
  ts_levelplanes lp;
  uint32_t vb;
} fset;

/* Planes that repeat a small pattern with a little noise: clusters of
 * vectors, and many exact duplicates (ties). */
static void fill_planes(fset *f, uint64_t seed) {
  ts_rng rng;
  ts_rng_seed(&rng, seed, 7);
  memset(&f->lp, 0, sizeof(f->lp));
  for (int p = 0; p < 3; p++) {
    assert_int_equal(ts_plane_alloc(&f->fine[p], W, H), 0);
    for (int y = 0; y < H; y++)
      for (int x = 0; x < W; x++) {
        int v = 40 * ((x / 4 + y / 3 + p) % 5) + (ts_rng_below(&rng, 6) == 0 ? (int)ts_rng_below(&rng, 30) : 0);
        f->fine[p].px[y * W + x] = (uint8_t)v;
      }
    f->lp.fine[p] = &f->fine[p];
  }
  assert_int_equal(ts_plane_alloc(&f->coarse[0], CW, CH), 0);
  for (int i = 0; i < CW * CH; i++) f->coarse[0].px[i] = (uint8_t)(60 * (i % 3) + (i / CW) % 2);
  f->lp.coarse[0] = &f->coarse[0];
}

static void set_up(fset *f, uint64_t seed, int labelled) {
  memset(f, 0, sizeof(*f));
  for (int k = 0; k < 9; k++) f->fdx[k] = (int16_t)(k % 3 - 1), f->fdy[k] = (int16_t)(k / 3 - 1);
  for (int k = 0; k < 4; k++) f->cdx[k] = (int16_t)(k % 2), f->cdy[k] = (int16_t)(k / 2);
  ts_window_spec *s = &f->spec;
  s->nplanes[TS_SRC_FINE] = 3, s->nplanes[TS_SRC_COARSE] = 1;
  s->noff[TS_SRC_FINE] = 9, s->noff[TS_SRC_COARSE] = 4;
  s->dx[TS_SRC_FINE] = f->fdx, s->dy[TS_SRC_FINE] = f->fdy;
  s->dx[TS_SRC_COARSE] = f->cdx, s->dy[TS_SRC_COARSE] = f->cdy;
  s->extent[TS_SRC_FINE] = (ts_box){-1, -1, 2, 2};
  s->extent[TS_SRC_COARSE] = (ts_box){0, 0, 2, 2};
  s->centre = 1, s->block = 1, s->nparts = 4; /* usage: the anchor pixel, inside every slice's rows */
  s->part[0] = (ts_part){TS_SRC_FINE, 0, 1, 3};
  s->part[1] = (ts_part){TS_SRC_FINE, 1, 1, 7};
  s->part[2] = (ts_part){TS_SRC_FINE, 2, 1, 0};
  s->part[3] = (ts_part){TS_SRC_COARSE, 0, 1, 2};
  char err[TS_ERR_LEN];
  assert_int_equal(ts_window_init(&f->w, s, err), 0);
  f->vb = ts_window_bytes(&f->w);
  fill_planes(f, seed);
  const ts_plane *labels = NULL, *valid = NULL;
  if (labelled) { /* three classes and a hole the windows avoid */
    assert_int_equal(ts_plane_alloc(&f->labels, W, H), 0);
    assert_int_equal(ts_plane_alloc(&f->mask, W, H), 0);
    for (int i = 0; i < W * H; i++) f->labels.px[i] = (uint8_t)((i % W + 2 * (i / W)) % NCLASS), f->mask.px[i] = 1;
    for (int y = 12; y < 17; y++)
      for (int x = 8; x < 15; x++) f->mask.px[y * W + x] = 0;
    assert_int_equal(ts_anchors_valid_from_mask(&f->mask, &s->extent[TS_SRC_FINE], &f->valid), 0);
    labels = &f->labels;
    valid = &f->valid;
  }
  assert_int_equal(ts_anchors_init(&f->a, &f->w, W, H, CW, CH, labels, labelled ? NCLASS : 1, valid, err), 0);
}

static void tear_down(fset *f) {
  for (int p = 0; p < 3; p++) ts_plane_free(&f->fine[p]);
  ts_plane_free(&f->coarse[0]);
  ts_plane_free(&f->labels);
  ts_plane_free(&f->mask);
  ts_plane_free(&f->valid);
  ts_anchors_free(&f->a);
  ts_window_free(&f->w);
}

/* The weighted L1 of l1.h by its definition: part weights byte by byte,
 * masked bytes counting for nothing. */
static uint64_t dist_def(const fset *f, const uint8_t *q, const uint8_t *v, const uint8_t *m) {
  uint64_t d = 0;
  int part = 0;
  for (uint32_t k = 0; k < f->vb; k++) {
    while (k >= f->w.part_end[part] * TS_L1_CHUNK) part++;
    int a = m ? q[k] & m[k] : q[k], b = m ? v[k] & m[k] : v[k];
    d += (uint64_t)(a > b ? a - b : b - a) * f->w.spec.part[part].weight;
  }
  return d;
}

static void vec_of(const fset *f, uint32_t global, uint8_t *v) {
  int x, y;
  ts_anchors_pos(&f->a, global, &x, &y);
  ts_vec_ref(&f->w, &f->lp, x, y, v);
}

/* The nearest centroid of v by definition (ties to the lowest). */
static uint32_t nearest_def(const fset *f, const ts_lbg_codebook *cb, int c, const uint8_t *v, const uint8_t *m,
                            uint64_t *dist) {
  uint32_t best = UINT32_MAX;
  uint64_t bd = UINT64_MAX;
  for (uint32_t k = 0; k < cb->npart[c]; k++) {
    uint64_t d = dist_def(f, v, cb->cent + (size_t)(cb->first[c] + k) * f->vb, m);
    if (d < bd) bd = d, best = k;
  }
  if (dist) *dist = bd;
  return best;
}

static const ts_l1_impl *kernel(void) {
  const ts_l1_impl *simd;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_l1_select(&simd, err), 0);
  return simd;
}

static void build(const fset *f, ts_lbg_codebook *cb, uint32_t p, uint32_t probe, int exact, uint64_t seed,
                  ts_pool *pool, ts_lbg_report *rep) {
  ts_lbg_params lp = {p, probe, exact, seed, 0};
  char err[TS_ERR_LEN];
  if (ts_lbg_build(cb, &f->w, &f->a, &f->lp, &lp, pool, kernel(), rep, err) != 0) fail_msg("%s", err);
}

/* ---- the codebook --------------------------------------------------------- */

static int byte_cmp(const void *a, const void *b) { return *(const uint8_t *)a - *(const uint8_t *)b; }

/* LBG as lbg.h states it, in plain loops: seeds drawn like the build's,
 * every vector to its nearest centroid, each centroid to its members'
 * lower median byte by byte (empty: stays), until the summed movement is
 * 0 or changes by less than 2 %; then the centroids some vector is
 * nearest to. Class c of f into cent (room for p), their count. */
static uint32_t plain_lbg(const fset *f, int c, uint32_t p, uint64_t seed, uint8_t *cent, uint32_t *iters) {
  uint32_t n = f->a.count[c], k = p < n ? p : n, vb = f->vb;
  uint8_t *v = malloc((size_t)n * vb), *col = malloc(n), *next = malloc((size_t)k * vb), *all = malloc((size_t)k * vb);
  uint32_t *idx = malloc(sizeof(uint32_t) * n), *near = malloc(sizeof(uint32_t) * n);
  for (uint32_t i = 0; i < n; i++) vec_of(f, f->a.base[c] + i, v + (size_t)i * vb), idx[i] = i;
  ts_rng rng;
  ts_rng_seed(&rng, seed, (uint64_t)c);
  for (uint32_t i = 0; i < k; i++) {
    uint32_t j = i + ts_rng_below(&rng, n - i), t = idx[i];
    idx[i] = idx[j], idx[j] = t;
    memcpy(all + (size_t)i * vb, v + (size_t)idx[i] * vb, vb);
  }
  ts_lbg_codebook cb = {.npart = {k}, .first = {0, k}, .cent = all};
  double before = 0;
  int converged = 0;
  for (*iters = 0; !converged && *iters < TS_LBG_MAX_ITER;) {
    for (uint32_t i = 0; i < n; i++) near[i] = nearest_def(f, &cb, 0, v + (size_t)i * vb, NULL, NULL);
    double moved = 0;
    for (uint32_t j = 0; j < k; j++) {
      uint32_t m = 0;
      for (uint32_t b = 0; b < vb; b++) {
        m = 0;
        for (uint32_t i = 0; i < n; i++)
          if (near[i] == j) col[m++] = v[(size_t)i * vb + b];
        qsort(col, m, 1, byte_cmp);
        next[(size_t)j * vb + b] = m ? col[(m - 1) / 2] : all[(size_t)j * vb + b];
      }
      moved += (double)dist_def(f, all + (size_t)j * vb, next + (size_t)j * vb, NULL);
    }
    memcpy(all, next, (size_t)k * vb);
    ++*iters;
    converged = moved == 0 || (*iters > 1 && fabs(moved - before) < 0.02 * before);
    before = moved;
  }
  uint32_t kept = 0;
  for (uint32_t j = 0; j < k; j++) {
    int used = 0;
    for (uint32_t i = 0; i < n && !used; i++) used = nearest_def(f, &cb, 0, v + (size_t)i * vb, NULL, NULL) == j;
    if (used) memcpy(cent + (size_t)kept++ * vb, all + (size_t)j * vb, vb);
  }
  free(v), free(col), free(next), free(all), free(idx), free(near);
  return kept;
}

/* The build (bounds that skip scans, histograms kept between iterations,
 * threads) makes exactly the codebook of plain LBG. */
static void codebook_is_plain_lbg(void **state) {
  (void)state;
  fset f;
  set_up(&f, 23, 1);
  ts_pool *pool;
  assert_int_equal(ts_pool_create(&pool, 2), 0);
  for (int t = 0; t < 2; t++) {
    uint32_t p = t ? 20 : 7;
    ts_lbg_codebook cb;
    ts_lbg_report rep;
    build(&f, &cb, p, 1, 0, 5 + (uint64_t)t, pool, &rep);
    uint32_t most = 0;
    for (int c = 0; c < NCLASS; c++) {
      uint8_t *want = malloc((size_t)p * f.vb);
      uint32_t iters, kept = plain_lbg(&f, c, p, 5 + (uint64_t)t, want, &iters);
      assert_int_equal(cb.npart[c], kept);
      assert_memory_equal(cb.cent + (size_t)cb.first[c] * f.vb, want, (size_t)kept * f.vb);
      most = iters > most ? iters : most;
      free(want);
    }
    assert_int_equal(rep.iterations, most);
    ts_lbg_free(&cb);
  }
  ts_pool_destroy(pool);
  tear_down(&f);
}

/* The build converges on clustered data, gives the same codebook on 1 or
 * 3 threads, keeps only centroids some vector is nearest to, and reports
 * partition sizes that add up to the set. */
static void lbg_converges_and_is_deterministic(void **state) {
  (void)state;
  fset f;
  set_up(&f, 3, 1);
  ts_pool *pool;
  assert_int_equal(ts_pool_create(&pool, 3), 0);
  ts_lbg_codebook one, three, other;
  ts_lbg_report r1, r3;
  build(&f, &one, 12, 1, 0, 99, NULL, &r1);
  build(&f, &three, 12, 1, 0, 99, pool, &r3);
  assert_true(r1.converged);
  assert_true(r1.iterations >= 2 && r1.iterations < TS_LBG_MAX_ITER);
  assert_int_equal(r1.iterations, r3.iterations);
  assert_int_equal(one.first[NCLASS], three.first[NCLASS]);
  assert_memory_equal(one.npart, three.npart, sizeof(one.npart));
  assert_memory_equal(one.cent, three.cent, (size_t)one.first[NCLASS] * f.vb);
  assert_int_equal(r1.partitions, one.first[NCLASS]);
  /* every kept centroid is some vector's nearest; sizes add up */
  uint8_t v[TS_L1_MAX_CHUNKS * TS_L1_CHUNK];
  uint32_t *size = calloc(one.first[NCLASS], sizeof(uint32_t));
  for (int c = 0; c < NCLASS; c++) {
    assert_true(one.npart[c] >= 2 && one.npart[c] <= 12);
    for (uint32_t i = 0; i < f.a.count[c]; i++) {
      vec_of(&f, f.a.base[c] + i, v);
      size[one.first[c] + nearest_def(&f, &one, c, v, NULL, NULL)]++;
    }
  }
  uint32_t lo = UINT32_MAX, hi = 0;
  for (uint32_t k = 0; k < one.first[NCLASS]; k++) {
    assert_true(size[k] > 0);
    lo = size[k] < lo ? size[k] : lo;
    hi = size[k] > hi ? size[k] : hi;
  }
  assert_int_equal(r1.size_min, lo);
  assert_int_equal(r1.size_max, hi);
  free(size);
  /* another seed draws other seeds */
  build(&f, &other, 12, 1, 0, 100, NULL, NULL);
  assert_true(other.first[NCLASS] != one.first[NCLASS] ||
              memcmp(other.cent, one.cent, (size_t)one.first[NCLASS] * f.vb) != 0);
  ts_lbg_free(&one);
  ts_lbg_free(&three);
  ts_lbg_free(&other);
  ts_pool_destroy(pool);
  tear_down(&f);
}


/* One partition: its centroid is the lower median of all the vectors,
 * byte by byte (the seeds move there, then stay: converged). */
static void one_partition_is_the_median(void **state) {
  (void)state;
  fset f;
  set_up(&f, 5, 0);
  ts_lbg_codebook cb;
  ts_lbg_report r;
  build(&f, &cb, 1, 1, 0, 1, NULL, &r);
  assert_int_equal(cb.npart[0], 1);
  assert_true(r.converged);
  assert_int_equal(r.iterations, 2);
  uint32_t n = f.a.count[0];
  uint8_t *all = malloc((size_t)n * f.vb), *col = malloc(n);
  for (uint32_t i = 0; i < n; i++) vec_of(&f, i, all + (size_t)i * f.vb);
  for (uint32_t b = 0; b < f.vb; b++) {
    for (uint32_t i = 0; i < n; i++) col[i] = all[(size_t)i * f.vb + b];
    qsort(col, n, 1, byte_cmp);
    assert_int_equal(cb.cent[b], col[(n - 1) / 2]);
  }
  free(all);
  free(col);
  ts_lbg_free(&cb);
  tear_down(&f);
}

/* Assignment, distances to every centroid and the nearest partitions,
 * against the definitions, with masks and with duplicate centroids (ties
 * to the lowest). */
static void assignment_and_order_match_brute_force(void **state) {
  (void)state;
  fset f;
  set_up(&f, 7, 0);
  enum { K = 40 };
  ts_rng rng;
  ts_rng_seed(&rng, 11, 1);
  uint8_t *cent = malloc((size_t)K * f.vb);
  for (int k = 0; k < K; k++) vec_of(&f, ts_rng_below(&rng, f.a.count[0]), cent + (size_t)k * f.vb);
  memcpy(cent + 30 * f.vb, cent + 3 * f.vb, f.vb); /* a tie: 3 wins over 30 */
  ts_l1_set set;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_lbg_centroid_set(&set, &f.w, cent, K, err), 0);
  ts_lbg_codebook cb = {.npart = {K}, .first = {0, K}, .cent = cent};
  uint32_t n = f.a.count[0];
  uint8_t *vecs = malloc((size_t)n * f.vb);
  for (uint32_t i = 0; i < n; i++) vec_of(&f, i, vecs + (size_t)i * f.vb);
  ts_l1_best *near = malloc(sizeof(ts_l1_best) * n);
  ts_pool *pool;
  assert_int_equal(ts_pool_create(&pool, 2), 0);
  ts_lbg_assign(&set, vecs, n, pool, kernel(), near);
  for (uint32_t i = 0; i < n; i++) {
    uint64_t d;
    assert_int_equal(near[i].index, nearest_def(&f, &cb, 0, vecs + (size_t)i * f.vb, NULL, &d));
    assert_int_equal(near[i].dist, d);
    assert_int_not_equal(near[i].index, 30);
  }
  uint64_t dist[K];
  uint32_t order[K];
  uint8_t mask[TS_L1_MAX_CHUNKS * TS_L1_CHUNK];
  for (int t = 0; t < 60; t++) {
    const uint8_t *q = vecs + (size_t)ts_rng_below(&rng, n) * f.vb;
    for (uint32_t b = 0; b < f.vb; b++) mask[b] = ts_rng_below(&rng, 3) ? 0xFF : 0x00;
    const uint8_t *m = t % 2 ? mask : NULL;
    ts_lbg_dists(&set, cent, K, q, m, dist);
    for (int k = 0; k < K; k++) assert_int_equal(dist[k], dist_def(&f, q, cent + (size_t)k * f.vb, m));
    uint32_t want = (uint32_t)(t % K) + 1; /* few (insertion) and many (a sort) */
    ts_lbg_nearest(dist, K, want, order);
    for (uint32_t i = 0; i < want; i++) { /* exactly the i-th in (distance, index) order */
      uint32_t before = 0;
      for (int k = 0; k < K; k++)
        before += dist[k] < dist[order[i]] || (dist[k] == dist[order[i]] && (uint32_t)k < order[i]);
      assert_int_equal(before, i);
    }
  }
  ts_pool_destroy(pool);
  ts_l1_set_free(&set);
  free(near);
  free(vecs);
  free(cent);
  tear_down(&f);
}

/* The bound skips only when strictly above the best. */
static void bound_is_strict(void **state) {
  (void)state;
  assert_false(ts_lbg_skips(10, 4, 6)); /* 10 - 4 = 6: a tie may hide there */
  assert_true(ts_lbg_skips(10, 4, 5));
  assert_false(ts_lbg_skips(3, 4, 0)); /* the query inside the partition's ball */
  assert_false(ts_lbg_skips(4, 4, 0));
  assert_true(ts_lbg_skips(UINT64_MAX, 0, UINT64_MAX - 1));
}

/* ---- partitioned search ----------------------------------------------------- */

/* A batch: reference vectors (exact copies: ties with the duplicates),
 * near ones and ones between clusters, every class, masks when asked. */
typedef struct {
  uint8_t *q, *m;
  uint8_t klass[NQ];
} batch;

static void make_batch(const fset *f, batch *b, uint64_t seed, int masked) {
  ts_rng rng;
  ts_rng_seed(&rng, seed, 5);
  b->q = malloc((size_t)NQ * f->vb);
  b->m = masked ? malloc((size_t)NQ * f->vb) : NULL;
  for (int i = 0; i < NQ; i++) {
    int c = i % f->a.nclass;
    b->klass[i] = (uint8_t)c;
    uint8_t *q = b->q + (size_t)i * f->vb;
    vec_of(f, f->a.base[c] + ts_rng_below(&rng, f->a.count[c]), q);
    if (i % 3 == 1) q[ts_rng_below(&rng, 9)] ^= (uint8_t)ts_rng_below(&rng, 64);
    if (i % 3 == 2) /* between clusters: half of another vector's bytes */
      for (uint32_t k = 0; k < f->vb; k += 2) q[k] = (uint8_t)(f->fine[0].px[ts_rng_below(&rng, W * H)] & q[k + 1]);
    for (uint32_t k = 0; masked && k < f->vb; k++) b->m[(size_t)i * f->vb + k] = ts_rng_below(&rng, 4) ? 0xFF : 0x00;
  }
}

static void free_batch(batch *b) {
  free(b->q);
  free(b->m);
}

/* Exhaustive search by definition, or (cb not NULL) among the vectors of
 * the query's `probe` nearest partitions, nearness by the masked distance
 * to the centroids and a vector's partition by its nearest centroid. */
static ts_l1_best best_def(const fset *f, const batch *b, int i, const ts_usage *u, uint64_t usage_k,
                           const ts_lbg_codebook *cb, uint32_t probe) {
  int c = b->klass[i];
  const uint8_t *q = b->q + (size_t)i * f->vb, *m = b->m ? b->m + (size_t)i * f->vb : NULL;
  uint8_t *allowed = NULL;
  if (cb != NULL) {
    uint64_t d[256];
    uint32_t order[256];
    for (uint32_t k = 0; k < cb->npart[c]; k++) d[k] = dist_def(f, q, cb->cent + (size_t)(cb->first[c] + k) * f->vb, m);
    ts_lbg_nearest(d, cb->npart[c], probe < cb->npart[c] ? probe : cb->npart[c], order);
    allowed = calloc(cb->npart[c], 1);
    for (uint32_t k = 0; k < probe && k < cb->npart[c]; k++) allowed[order[k]] = 1;
  }
  ts_l1_best best = {UINT64_MAX, UINT32_MAX, 0};
  uint8_t v[TS_L1_MAX_CHUNKS * TS_L1_CHUNK];
  for (uint32_t j = f->a.base[c]; j < f->a.base[c] + f->a.count[c]; j++) {
    vec_of(f, j, v);
    if (allowed != NULL && !allowed[nearest_def(f, cb, c, v, NULL, NULL)]) continue;
    uint64_t d = dist_def(f, q, v, m) + (usage_k ? ts_usage_penalty(u->u[j], usage_k) : 0);
    if (d < best.dist) best.dist = d, best.index = j;
  }
  free(allowed);
  return best;
}

/* Copies of 3x3 blocks at random places, counted in u. */
static void count_copies(ts_usage *u, uint64_t seed) {
  ts_rng rng;
  ts_rng_seed(&rng, seed, 9);
  for (int i = 0; i < 150; i++)
    ts_usage_commit(u, (int)ts_rng_below(&rng, W - 3), (int)ts_rng_below(&rng, H - 3), 3, 3, 1);
}

/* Slice k of n of the partitioned set (with u's usage counters when u is
 * not NULL), through the wire format. */
static ts_slice *load_slice(const fset *f, const ts_lbg_codebook *cb, int k, int n, const ts_usage *u,
                            ts_pool *pool) {
  uint32_t i0[TS_MAX_CLASSES], i1[TS_MAX_CLASSES];
  for (int c = 0; c < f->a.nclass; c++) {
    i0[c] = f->a.count[c] * (uint32_t)k / (uint32_t)n;
    i1[c] = f->a.count[c] * (uint32_t)(k + 1) / (uint32_t)n;
  }
  ts_refset rs = {0, &f->w, &f->a, &f->lp, f->labels.px ? &f->labels : NULL, f->valid.px ? &f->valid : NULL,
                  u != NULL, u};
  static ts_slice_desc m, back;
  char err[TS_ERR_LEN];
  ts_slice_describe(&m, &rs, u, 1, 1, 0, i0, i1, NULL);
  ts_slice_describe_lbg(&m, cb);
  ts_wr wr;
  ts_wr_init(&wr);
  ts_msg_slice_write(&wr, &m);
  assert_int_equal(ts_wr_status(&wr), 0);
  ts_frame fr = {'N', 1, (uint32_t)wr.len, wr.buf};
  if (ts_msg_slice_read(&fr, &back, err) != 0) fail_msg("%s", err);
  ts_slice *sl;
  if (ts_slice_load(&sl, &back, NULL, pool, err) != 0) fail_msg("slice %d of %d: %s", k, n, err);
  ts_wr_free(&wr);
  assert_int_equal(ts_slice_lbg(sl), cb->mode);
  return sl;
}

/* Scans a batch over n slices (n = 1: the whole set) and merges. */
static void search(const fset *f, const ts_lbg_codebook *cb, int n, const batch *b, const ts_usage *u,
                   uint64_t usage_k, ts_pool *pool, ts_l1_best *out, uint64_t *pairs) {
  ts_slice *sl[3];
  for (int k = 0; k < n; k++) sl[k] = load_slice(f, cb, k, n, u, pool);
  ts_l1_best part[NQ];
  ts_l1_best_reset(out, NQ);
  *pairs = 0;
  char err[TS_ERR_LEN];
  for (int k = 0; k < n; k++) {
    ts_vec_batch vb = {NQ, b->q, b->m, b->klass, usage_k};
    uint64_t p;
    if (ts_slice_scan(sl[k], pool, pool ? 0 : 1, kernel(), &vb, part, &p, err) != 0) fail_msg("%s", err);
    *pairs += p;
    for (int i = 0; i < NQ; i++)
      if (part[i].index != UINT32_MAX) ts_l1_best_merge(&out[i], &part[i], 1);
    ts_slice_free(sl[k]);
  }
}

/* Exact pruning returns the exhaustive results, bit for bit, whole or in
 * slices, with classes, a hole, masks, usage penalties and ties, for any
 * partitions and probe - and compares fewer vectors than exhaustive. */
static void exact_pruning_matches_brute_force(void **state) {
  (void)state;
  fset f;
  set_up(&f, 13, 1);
  ts_pool *pool;
  assert_int_equal(ts_pool_create(&pool, 2), 0);
  ts_usage u;
  assert_int_equal(ts_usage_init(&u, &f.a, 1, 1), 0);
  count_copies(&u, 4);
  uint64_t usage_k = ts_usage_factor(&u, 2.0, ts_window_unit_distance(&f.w));
  static const uint32_t parts[] = {1, 6, 40}, probes[] = {1, 3};
  uint64_t total = 0;
  for (int c = 0; c < NCLASS; c++) total += (uint64_t)f.a.count[c] * (NQ / NCLASS);
  for (int t = 0; t < 12; t++) {
    uint32_t p = parts[t % 3], probe = probes[t / 3 % 2];
    int masked = t / 6 % 2, n = t % 2 ? 3 : 1;
    int with_usage = t % 4 == 1;
    ts_lbg_codebook cb;
    build(&f, &cb, p, probe, 1, (uint64_t)t, NULL, NULL);
    batch b;
    make_batch(&f, &b, (uint64_t)t, masked);
    ts_l1_best got[NQ];
    uint64_t pairs;
    search(&f, &cb, n, &b, with_usage ? &u : NULL, with_usage ? usage_k : 0, t % 3 ? pool : NULL, got, &pairs);
    for (int i = 0; i < NQ; i++) {
      ts_l1_best want = best_def(&f, &b, i, &u, with_usage ? usage_k : 0, NULL, 0);
      if (got[i].index != want.index || got[i].dist != want.dist)
        fail_msg("case %d (P %u, probe %u, %s, %d slices) query %d: %u at %llu, not %u at %llu", t, p, probe,
                 masked ? "masked" : "plain", n, i, got[i].index, (unsigned long long)got[i].dist, want.index,
                 (unsigned long long)want.dist);
    }
    if (p == 40 && !masked && !with_usage) assert_true(pairs < total); /* something was pruned */
    free_batch(&b);
    ts_lbg_free(&cb);
  }
  ts_usage_free(&u);
  ts_pool_destroy(pool);
  tear_down(&f);
}

/* The lossy search answers the best of the query's probed partitions (by
 * definition), the same whole or in slices; probing every partition is
 * the exhaustive search. */
static void lossy_probe_is_its_definition(void **state) {
  (void)state;
  fset f;
  set_up(&f, 17, 1);
  ts_pool *pool;
  assert_int_equal(ts_pool_create(&pool, 3), 0);
  for (int t = 0; t < 6; t++) {
    uint32_t p = t < 4 ? 8 : 30, probe = t < 2 ? 1 : t < 4 ? 3 : 30;
    int masked = t % 2;
    ts_lbg_codebook cb;
    build(&f, &cb, p, probe, 0, 40 + (uint64_t)t, pool, NULL);
    batch b;
    make_batch(&f, &b, 50 + (uint64_t)t, masked);
    ts_l1_best whole[NQ], sliced[NQ];
    uint64_t pw, ps;
    search(&f, &cb, 1, &b, NULL, 0, pool, whole, &pw);
    search(&f, &cb, 3, &b, NULL, 0, NULL, sliced, &ps);
    assert_int_equal(pw, ps); /* the same vectors compared */
    int all = probe >= cb.npart[0] && probe >= cb.npart[1] && probe >= cb.npart[2], lost = 0;
    for (int i = 0; i < NQ; i++) {
      ts_l1_best want = best_def(&f, &b, i, NULL, 0, all ? NULL : &cb, probe);
      assert_int_equal(whole[i].index, want.index);
      assert_int_equal(whole[i].dist, want.dist);
      assert_int_equal(sliced[i].index, want.index);
      assert_int_equal(sliced[i].dist, want.dist);
      lost += want.dist > best_def(&f, &b, i, NULL, 0, NULL, 0).dist;
    }
    if (probe == 1) assert_true(lost > 0); /* lossy indeed: some best lies in another partition */
    if (all) assert_int_equal(lost, 0);
    free_batch(&b);
    ts_lbg_free(&cb);
  }
  ts_pool_destroy(pool);
  tear_down(&f);
}

/* ---- the codebook on the wire ---------------------------------------------- */

/* A worker refuses a codebook that does not fit the set (each problem
 * named), and a message whose centroids are cut short. */
static void bad_codebooks_are_refused(void **state) {
  (void)state;
  fset f;
  set_up(&f, 19, 1);
  ts_lbg_codebook cb;
  build(&f, &cb, 5, 1, 0, 1, NULL, NULL);
  ts_refset rs = {0, &f.w, &f.a, &f.lp, &f.labels, &f.valid, 0, NULL};
  static const uint32_t i0[TS_MAX_CLASSES] = {0};
  static ts_slice_desc m, back;
  char err[TS_ERR_LEN];
  /* room for the centroids the altered codebooks claim */
  uint8_t *room = calloc((size_t)(cb.first[NCLASS] + f.a.count[1] + 1), f.vb + 8);
  for (int k = 0; k < 4; k++) {
    ts_slice_describe(&m, &rs, NULL, 1, 1, 0, i0, f.a.count, NULL);
    ts_slice_describe_lbg(&m, &cb);
    m.lbg.cent = room;
    const char *want = NULL;
    switch (k) {
    case 0: m.lbg.npart[1] = f.a.count[1] + 1, want = "partitions for class 1"; break;
    case 1: m.lbg.npart[2] = 0, want = "partitions for class 2"; break;
    case 2: m.lbg.vbytes = f.vb + 8, want = "bytes"; break;
    case 3: m.lbg.probe = 0, want = "probing 0"; break;
    }
    ts_wr wr;
    ts_wr_init(&wr);
    ts_msg_slice_write(&wr, &m);
    ts_frame fr = {'N', 1, (uint32_t)wr.len, wr.buf};
    ts_slice *sl = NULL;
    int rc = ts_msg_slice_read(&fr, &back, err);
    if (rc == 0) rc = ts_slice_load(&sl, &back, NULL, NULL, err);
    assert_int_equal(rc, TS_EINVAL);
    if (strstr(err, want) == NULL) fail_msg("case %d: %s", k, err);
    assert_null(sl);
    ts_wr_free(&wr);
  }
  /* the centroids cut short */
  ts_slice_describe(&m, &rs, NULL, 1, 1, 0, i0, f.a.count, NULL);
  ts_slice_describe_lbg(&m, &cb);
  ts_wr wr;
  ts_wr_init(&wr);
  ts_msg_slice_write(&wr, &m);
  ts_frame fr = {'N', 1, (uint32_t)wr.len - 5, wr.buf};
  assert_int_equal(ts_msg_slice_read(&fr, &back, err), TS_EPROTO);
  assert_non_null(strstr(err, "codebook"));
  ts_wr_free(&wr);
  free(room);
  ts_lbg_free(&cb);
  tear_down(&f);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(lbg_converges_and_is_deterministic),
    cmocka_unit_test(one_partition_is_the_median),
    cmocka_unit_test(codebook_is_plain_lbg),
    cmocka_unit_test(assignment_and_order_match_brute_force),
    cmocka_unit_test(bound_is_strict),
    cmocka_unit_test(exact_pruning_matches_brute_force),
    cmocka_unit_test(lossy_probe_is_its_definition),
    cmocka_unit_test(bad_codebooks_are_refused),
};

TS_TEST_MAIN(tests)
