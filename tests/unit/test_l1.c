/* test_l1.c - L1 nearest-neighbour kernels: every variant this CPU supports
 * must return exactly what a brute-force scan over ts_l1_distance returns
 * (distance and index, ties to the lowest index), for single and batched
 * scans, over odd shapes, weighted parts, masks, penalties and sub-ranges;
 * and ts_l1_distance must equal a direct computation on the vectors.
 *
 * Setting TEXSYN_SIMD limits the variants under test to that one and the
 * ones below it, e.g. TEXSYN_SIMD=avx2 under valgrind, which cannot run
 * AVX-512 code. Each variant has a test of its own (test_l1_variant_*),
 * skipped, with the reason, when the CPU lacks it or TEXSYN_SIMD leaves it
 * out: the comparisons then ran without it. */
#include "ts_test.h"

#include "error.h"
#include "l1.h"
#include "rng.h"

/* ---- helpers ---- */

/* A reference set plus queries, masks and penalties, all random. */
typedef struct {
  ts_l1_set set;
  uint32_t vbytes;
  uint32_t nq;
  uint8_t *queries;
  uint8_t *masks;    /* NULL unless requested */
  uint32_t *penalty; /* NULL unless requested */
} fixture;

static uint8_t rand_byte(ts_rng *rng, uint32_t alphabet) {
  return (uint8_t)ts_rng_below(rng, alphabet);
}

/* Penalties mixing zeros, small values and values near 2^32. */
static uint32_t rand_penalty(ts_rng *rng) {
  switch (ts_rng_below(rng, 4)) {
  case 0:
    return 0;
  case 1:
    return ts_rng_below(rng, 64);
  case 2:
    return UINT32_MAX - ts_rng_below(rng, 16);
  default:
    return (uint32_t)ts_rng_next(rng);
  }
}

/* alphabet: bytes are drawn from [0, alphabet); small alphabets make many
 * equal distances, which exercises the tie rule. mask_density: 0 for no
 * masks, else the percentage of bytes kept. */
static void fixture_make(fixture *f, ts_rng *rng, uint32_t nvec, uint32_t nchunks, uint32_t nfine,
                         uint32_t wfine, uint32_t wcoarse, uint32_t nq, uint32_t alphabet,
                         uint32_t mask_density, int with_penalty) {
  memset(f, 0, sizeof(*f));
  assert_int_equal(ts_l1_set_init(&f->set, nvec, nchunks), 0);
  assert_int_equal(ts_l1_set_weigh_fine_coarse(&f->set, nfine, wfine, wcoarse, NULL), 0);
  f->vbytes = nchunks * TS_L1_CHUNK;
  f->nq = nq;
  uint8_t *vec = malloc(f->vbytes);
  assert_non_null(vec);
  for (uint32_t v = 0; v < nvec; v++) {
    for (uint32_t i = 0; i < f->vbytes; i++) vec[i] = rand_byte(rng, alphabet);
    ts_l1_set_put(&f->set, v, vec);
  }
  free(vec);
  f->queries = malloc((size_t)nq * f->vbytes);
  assert_non_null(f->queries);
  for (size_t i = 0; i < (size_t)nq * f->vbytes; i++) f->queries[i] = rand_byte(rng, alphabet);
  if (mask_density > 0) {
    f->masks = malloc((size_t)nq * f->vbytes);
    assert_non_null(f->masks);
    for (size_t i = 0; i < (size_t)nq * f->vbytes; i++)
      f->masks[i] = ts_rng_below(rng, 100) < mask_density ? 0xFF : 0x00;
  }
  if (with_penalty) {
    size_t n = (size_t)f->set.ngroups * TS_L1_GROUP;
    f->penalty = malloc(n * sizeof(uint32_t));
    assert_non_null(f->penalty);
    for (size_t i = 0; i < n; i++) f->penalty[i] = rand_penalty(rng);
  }
}

static void fixture_free(fixture *f) {
  ts_l1_set_free(&f->set);
  free(f->queries);
  free(f->masks);
  free(f->penalty);
}

/* A part's weight: 0, the largest, small, or any 32-bit value. */
static uint64_t rand_weight(ts_rng *rng) {
  switch (ts_rng_below(rng, 4)) {
  case 0:
    return 0;
  case 1:
    return TS_L1_MAX_WEIGHT;
  case 2:
    return 1 + ts_rng_below(rng, 16);
  default:
    return (uint32_t)ts_rng_next(rng);
  }
}

/* Cuts nchunks chunks into nparts non-empty parts at random places, with
 * random weights, and sets them on f's set. */
static void fixture_parts(fixture *f, ts_rng *rng, uint32_t nparts) {
  uint32_t nchunks = f->set.nchunks, end[TS_L1_MAX_PARTS];
  uint64_t weight[TS_L1_MAX_PARTS];
  assert_true(nparts >= 1 && nparts <= nchunks);
  /* Choose nparts - 1 of the nchunks - 1 cut points, in order. */
  for (uint32_t c = 1, p = 0; c < nchunks; c++)
    if (ts_rng_below(rng, nchunks - c) < nparts - 1 - p) end[p++] = c;
  end[nparts - 1] = nchunks;
  for (uint32_t p = 0; p < nparts; p++) weight[p] = rand_weight(rng);
  char err[TS_ERR_LEN] = "";
  assert_int_equal(ts_l1_set_weigh(&f->set, nparts, end, weight, err), 0);
}

/* D(q, v) straight from the definition in l1.h, on the vector as stored
 * (ts_l1_set_get) and with the part of each byte looked up on its own. */
static uint64_t direct_distance(const fixture *f, uint32_t v, const uint8_t *query,
                                const uint8_t *mask, const uint32_t *penalty) {
  uint8_t vec[TS_L1_MAX_CHUNKS * TS_L1_CHUNK];
  ts_l1_set_get(&f->set, v, vec);
  uint64_t d = penalty != NULL ? penalty[v] : 0;
  for (uint32_t i = 0; i < f->vbytes; i++) {
    uint32_t p = 0;
    while (i / TS_L1_CHUNK >= f->set.part_end[p]) p++;
    if (mask == NULL || mask[i] != 0)
      d += (uint64_t)abs((int)vec[i] - (int)query[i]) * f->set.part_weight[p];
  }
  return d;
}

static void expect_direct_distances(const fixture *f) {
  for (uint32_t q = 0; q < f->nq; q++) {
    const uint8_t *query = f->queries + (size_t)q * f->vbytes;
    const uint8_t *mask = f->masks != NULL ? f->masks + (size_t)q * f->vbytes : NULL;
    for (uint32_t v = 0; v < f->set.nvec; v += 1 + v % 5)
      assert_true(ts_l1_distance(&f->set, v, query, mask, f->penalty) ==
                  direct_distance(f, v, query, mask, f->penalty));
  }
}

static int better(uint64_t dist, uint32_t index, const ts_l1_best *b) {
  return dist < b->dist || (dist == b->dist && index < b->index);
}

/* Brute force over ts_l1_distance, merged into best like a scan. */
static void brute(const fixture *f, uint32_t g0, uint32_t g1, ts_l1_best *best) {
  uint32_t v1 = g1 * TS_L1_GROUP < f->set.nvec ? g1 * TS_L1_GROUP : f->set.nvec;
  for (uint32_t q = 0; q < f->nq; q++) {
    const uint8_t *query = f->queries + (size_t)q * f->vbytes;
    const uint8_t *mask = f->masks != NULL ? f->masks + (size_t)q * f->vbytes : NULL;
    for (uint32_t v = g0 * TS_L1_GROUP; v < v1; v++) {
      uint64_t d = ts_l1_distance(&f->set, v, query, mask, f->penalty);
      if (better(d, v, &best[q])) {
        best[q].dist = d;
        best[q].index = v;
      }
    }
  }
}

/* The variants under test: all supported ones, or those up to TEXSYN_SIMD. */
static int variant_tested(ts_simd id) {
  const char *env = getenv("TEXSYN_SIMD");
  ts_simd limit = env != NULL && env[0] != '\0' ? ts_simd_from_name(env) : TS_SIMD_COUNT;
  return id <= limit && ts_l1_impl_get(id) != NULL;
}

static void expect_same(const char *what, const char *variant, uint32_t nq,
                        const ts_l1_best *want, const ts_l1_best *got) {
  for (uint32_t q = 0; q < nq; q++) {
    if (want[q].dist != got[q].dist || want[q].index != got[q].index) {
      print_error("%s: %s query %u: want dist %llu index %u, got dist %llu index %u\n", what,
                  variant, q, (unsigned long long)want[q].dist, want[q].index,
                  (unsigned long long)got[q].dist, got[q].index);
      fail();
    }
  }
}

/* Every tested variant, single and batch, over groups [g0, g1) starting
 * from `init` (NULL: reset), must equal brute force. */
static void check_range(const fixture *f, uint32_t g0, uint32_t g1, const ts_l1_best *init) {
  size_t n = f->nq;
  ts_l1_best *want = malloc(n * sizeof(*want));
  ts_l1_best *got = malloc(n * sizeof(*got));
  assert_non_null(want);
  assert_non_null(got);
  if (init != NULL)
    memcpy(want, init, n * sizeof(*want));
  else
    ts_l1_best_reset(want, n);
  brute(f, g0, g1, want);
  for (int id = 0; id < TS_SIMD_COUNT; id++) {
    if (!variant_tested((ts_simd)id)) continue;
    const ts_l1_impl *impl = ts_l1_impl_get((ts_simd)id);
    ts_l1_scan_fn *fns[2] = {impl->single, impl->batch};
    for (int k = 0; k < 2; k++) {
      if (init != NULL)
        memcpy(got, init, n * sizeof(*got));
      else
        ts_l1_best_reset(got, n);
      fns[k](&f->set, g0, g1, f->queries, f->masks, f->penalty, f->nq, got);
      expect_same(k == 0 ? "single" : "batch", impl->name, f->nq, want, got);
    }
  }
  free(want);
  free(got);
}

static void check_all(const fixture *f) { check_range(f, 0, f->set.ngroups, NULL); }

/* Restores TEXSYN_SIMD after a test that sets it. */
static char *save_env(void) {
  const char *v = getenv("TEXSYN_SIMD");
  return v != NULL ? strdup(v) : NULL;
}

static void restore_env(char *saved) {
  if (saved != NULL)
    setenv("TEXSYN_SIMD", saved, 1);
  else
    unsetenv("TEXSYN_SIMD");
  free(saved);
}

/* ---- sets, bests, reference distance ---- */

static void test_l1_set_layout(void **state) {
  (void)state;
  ts_l1_set set;
  assert_int_equal(ts_l1_set_init(&set, 10, 0), TS_EINVAL);
  assert_int_equal(ts_l1_set_init(&set, 10, TS_L1_MAX_CHUNKS + 1), TS_EINVAL);
  assert_int_equal(ts_l1_set_init(&set, 0, 3), 0);
  assert_int_equal(set.ngroups, 0);
  ts_l1_set_free(&set);

  assert_int_equal(ts_l1_set_init(&set, 13, 3), 0);
  assert_int_equal(set.nvec, 13);
  assert_int_equal(set.ngroups, 2);
  assert_int_equal(set.nparts, 1); /* one part of weight 1 */
  assert_int_equal(set.part_end[0], 3);
  assert_true(set.part_weight[0] == 1);
  assert_int_equal((uintptr_t)set.data % TS_L1_ALIGN, 0);
  uint8_t vec[24], back[24];
  for (uint32_t v = 0; v < 13; v++) {
    for (int i = 0; i < 24; i++) vec[i] = (uint8_t)(v * 24 + i + 1);
    ts_l1_set_put(&set, v, vec);
  }
  for (uint32_t v = 0; v < 13; v++) {
    ts_l1_set_get(&set, v, back);
    for (int i = 0; i < 24; i++) {
      assert_int_equal(back[i], (uint8_t)(v * 24 + i + 1));
      /* The documented interleaved layout. */
      size_t at = ((size_t)(v / 8) * 3 + i / 8) * 64 + (v % 8) * 8 + i % 8;
      assert_int_equal(set.data[at], back[i]);
    }
  }
  /* Padding lanes (vectors 13..15 of group 1) stay zero. */
  for (uint32_t v = 13; v < 16; v++)
    for (int k = 0; k < 3; k++)
      for (int j = 0; j < 8; j++) assert_int_equal(set.data[(3 + k) * 64 + (v % 8) * 8 + j], 0);
  ts_l1_set_free(&set);
  assert_null(set.data);
}

static void test_l1_best_merge(void **state) {
  (void)state;
  ts_l1_best a[5], b[5];
  ts_l1_best_reset(a, 5);
  ts_l1_best_reset(b, 5);
  assert_true(a[0].dist == UINT64_MAX);
  a[0] = (ts_l1_best){10, 7, 0};
  b[0] = (ts_l1_best){10, 3, 0}; /* equal distance, lower index: wins */
  a[1] = (ts_l1_best){10, 3, 0};
  b[1] = (ts_l1_best){10, 7, 0}; /* equal distance, higher index: loses */
  a[2] = (ts_l1_best){10, 3, 0};
  b[2] = (ts_l1_best){9, 70, 0}; /* smaller distance: wins */
  a[3] = (ts_l1_best){0, 1, 0};  /* b[3] reset: never replaces */
  b[4] = (ts_l1_best){5, 2, 0};  /* a[4] reset: anything replaces */
  ts_l1_best_merge(a, b, 5);
  assert_int_equal(a[0].index, 3);
  assert_int_equal(a[1].index, 3);
  assert_int_equal(a[2].index, 70);
  assert_int_equal(a[2].dist, 9);
  assert_int_equal(a[3].index, 1);
  assert_int_equal(a[4].index, 2);
  assert_int_equal(a[4].dist, 5);
}

/* ts_l1_distance against a direct computation on the vectors as given. */
static void test_l1_distance_reference(void **state) {
  (void)state;
  ts_rng rng;
  ts_rng_seed(&rng, 11, 0);
  const uint32_t nvec = 21, nchunks = 5, vbytes = 40;
  ts_l1_set set;
  assert_int_equal(ts_l1_set_init(&set, nvec, nchunks), 0);
  assert_int_equal(ts_l1_set_weigh_fine_coarse(&set, 2, 65536, 37, NULL), 0);
  uint8_t vecs[21][40], q[40], m[40];
  uint32_t pen[24];
  for (uint32_t v = 0; v < nvec; v++) {
    for (uint32_t i = 0; i < vbytes; i++) vecs[v][i] = (uint8_t)ts_rng_next(&rng);
    ts_l1_set_put(&set, v, vecs[v]);
  }
  for (uint32_t i = 0; i < vbytes; i++) {
    q[i] = (uint8_t)ts_rng_next(&rng);
    m[i] = ts_rng_below(&rng, 2) ? 0xFF : 0;
  }
  for (int i = 0; i < 24; i++) pen[i] = rand_penalty(&rng);
  for (uint32_t v = 0; v < nvec; v++) {
    uint64_t fine = 0, coarse = 0, mfine = 0, mcoarse = 0;
    for (uint32_t i = 0; i < vbytes; i++) {
      uint64_t d = (uint64_t)abs((int)vecs[v][i] - (int)q[i]);
      *(i < 16 ? &fine : &coarse) += d;
      if (m[i]) *(i < 16 ? &mfine : &mcoarse) += d;
    }
    assert_true(ts_l1_distance(&set, v, q, NULL, NULL) == fine * 65536 + coarse * 37);
    assert_true(ts_l1_distance(&set, v, q, m, pen) == mfine * 65536 + mcoarse * 37 + pen[v]);
  }
  ts_l1_set_free(&set);
}

/* ---- every variant against brute force ---- */

static void test_l1_shapes(void **state) {
  (void)state;
  static const uint32_t nvecs[] = {1, 7, 8, 9, 63, 1001};
  static const uint32_t nchunks[] = {1, 3, 7, 8, 9, 13, 16, 17, 40, 130};
  ts_rng rng;
  ts_rng_seed(&rng, 1, 0);
  for (size_t a = 0; a < sizeof(nvecs) / sizeof(nvecs[0]); a++) {
    for (size_t b = 0; b < sizeof(nchunks) / sizeof(nchunks[0]); b++) {
      uint32_t nc = nchunks[b];
      /* nfine: all fine, all coarse, and one split in between. */
      uint32_t nfines[3] = {nc, 0, nc > 1 ? 1 + ts_rng_below(&rng, nc - 1) : 1};
      for (int i = 0; i < 3; i++) {
        fixture f;
        fixture_make(&f, &rng, nvecs[a], nc, nfines[i], 1 + ts_rng_below(&rng, 5),
                     1 + ts_rng_below(&rng, 5), 3, 256, 0, 0);
        check_all(&f);
        fixture_free(&f);
      }
    }
  }
}

static void test_l1_weights(void **state) {
  (void)state;
  static const uint32_t w[][2] = {{1, 1}, {65536, 37}, {0, 5}, {7, 0}, {UINT32_MAX, 1},
                                  {UINT32_MAX, UINT32_MAX - 1}};
  ts_rng rng;
  ts_rng_seed(&rng, 2, 0);
  for (size_t i = 0; i < sizeof(w) / sizeof(w[0]); i++) {
    fixture f;
    fixture_make(&f, &rng, 301, 7, 3, w[i][0], w[i][1], 5, 256, 0, 0);
    check_all(&f);
    fixture_free(&f);
    fixture_make(&f, &rng, 77, 12, 5, w[i][0], w[i][1], 5, 4, 0, 1);
    check_all(&f);
    fixture_free(&f);
  }
}

static void test_l1_masks(void **state) {
  (void)state;
  static const uint32_t nchunks[] = {1, 3, 7, 12, 19, 40};
  static const uint32_t density[] = {100, 90, 50, 10, 1};
  ts_rng rng;
  ts_rng_seed(&rng, 3, 0);
  for (size_t a = 0; a < sizeof(nchunks) / sizeof(nchunks[0]); a++) {
    for (size_t b = 0; b < sizeof(density) / sizeof(density[0]); b++) {
      uint32_t nc = nchunks[a];
      fixture f;
      fixture_make(&f, &rng, 203, nc, ts_rng_below(&rng, nc + 1), 3, 2, 4, 256, density[b],
                   (int)(b & 1));
      check_all(&f);
      fixture_free(&f);
    }
  }
  /* Long masked vectors in a batch larger than what is pre-ANDed at once. */
  fixture big;
  fixture_make(&big, &rng, 100, 300, 120, 2, 7, 20, 256, 50, 1);
  check_all(&big);
  fixture_free(&big);
  /* An all-zero mask makes every distance 0: the first vector wins. */
  fixture f;
  fixture_make(&f, &rng, 50, 3, 1, 9, 4, 2, 256, 1, 0);
  memset(f.masks, 0, (size_t)f.nq * f.vbytes);
  check_all(&f);
  fixture_free(&f);
}

static void test_l1_penalty(void **state) {
  (void)state;
  ts_rng rng;
  ts_rng_seed(&rng, 4, 0);
  static const uint32_t nchunks[] = {1, 7, 12, 33};
  for (size_t a = 0; a < sizeof(nchunks) / sizeof(nchunks[0]); a++) {
    for (uint32_t alphabet = 2; alphabet <= 256; alphabet *= 16) {
      fixture f;
      fixture_make(&f, &rng, 517, nchunks[a], nchunks[a] / 2, 1, 3, 6, alphabet, 0, 1);
      check_all(&f);
      fixture_free(&f);
    }
  }
}

/* Duplicates of a query planted at several indices (across lanes, groups
 * and blocks) tie at distance 0 and the lowest index must win. Then the same
 * with two symbols per byte, where most distances tie by chance. */
static void test_l1_ties(void **state) {
  (void)state;
  static const uint32_t nchunks[] = {1, 7, 12, 20};
  static const uint32_t spots[][3] = {{4999, 2000, 17}, {6, 5, 13}, {8, 16, 4000},
                                      {3, 11, 19},      {900, 4001, 5002}};
  ts_rng rng;
  ts_rng_seed(&rng, 5, 0);
  for (size_t a = 0; a < sizeof(nchunks) / sizeof(nchunks[0]); a++) {
    fixture f;
    fixture_make(&f, &rng, 5003, nchunks[a], 1, 2, 1, 9, 256, 0, 0);
    for (uint32_t q = 0; q < 5; q++)
      for (int i = 0; i < 3; i++)
        ts_l1_set_put(&f.set, spots[q][i], f.queries + (size_t)q * f.vbytes);
    ts_l1_best best[9];
    ts_l1_best_reset(best, 9);
    brute(&f, 0, f.set.ngroups, best);
    for (uint32_t q = 0; q < 5; q++) {
      uint32_t lo = spots[q][0];
      for (int i = 1; i < 3; i++) lo = spots[q][i] < lo ? spots[q][i] : lo;
      assert_true(best[q].dist == 0);
      assert_int_equal(best[q].index, lo);
    }
    check_all(&f);
    fixture_free(&f);

    fixture_make(&f, &rng, 5003, nchunks[a], 1, 2, 1, 9, 2, 0, 0);
    check_all(&f);
    /* Starting from a best that ties: an equal distance at a lower index
     * replaces it, at a higher index it stays. */
    ts_l1_best init[9];
    ts_l1_best_reset(init, 9);
    brute(&f, 0, f.set.ngroups, init);
    init[0].index = f.set.nvec; /* same distance, index beyond every vector */
    init[1].index = 0;
    init[2].dist = 0;
    init[2].index = 7;
    check_range(&f, 0, f.set.ngroups, init);
    fixture_free(&f);
  }
}

/* Scanning pieces of the group range, in any order into one best array, or
 * into separate arrays merged afterwards, equals scanning the whole range. */
static void test_l1_subranges(void **state) {
  (void)state;
  ts_rng rng;
  ts_rng_seed(&rng, 6, 0);
  static const uint32_t shapes[][3] = {{2001, 7, 3}, {999, 12, 5}, {333, 40, 20}, {77, 1, 1}};
  for (size_t s = 0; s < sizeof(shapes) / sizeof(shapes[0]); s++) {
    fixture f;
    fixture_make(&f, &rng, shapes[s][0], shapes[s][1], shapes[s][2], 5, 3, 7, 8, 0, 1);
    uint32_t ng = f.set.ngroups;
    for (int trial = 0; trial < 4; trial++) {
      /* Random cut points, and every piece checked against brute force. */
      uint32_t cuts[6] = {0, ts_rng_below(&rng, ng + 1), ts_rng_below(&rng, ng + 1),
                          ts_rng_below(&rng, ng + 1), ts_rng_below(&rng, ng + 1), ng};
      for (int i = 1; i < 6; i++)
        for (int j = i; j > 0 && cuts[j] < cuts[j - 1]; j--) {
          uint32_t t = cuts[j];
          cuts[j] = cuts[j - 1];
          cuts[j - 1] = t;
        }
      ts_l1_best full[7];
      ts_l1_best_reset(full, 7);
      brute(&f, 0, ng, full);
      for (int i = 0; i < 5; i++) check_range(&f, cuts[i], cuts[i + 1], NULL);
      for (int id = 0; id < TS_SIMD_COUNT; id++) {
        if (!variant_tested((ts_simd)id)) continue;
        const ts_l1_impl *impl = ts_l1_impl_get((ts_simd)id);
        ts_l1_best one[7], merged[7], piece[7];
        ts_l1_best_reset(one, 7);
        ts_l1_best_reset(merged, 7);
        for (int i = 4; i >= 0; i--) { /* last piece first */
          impl->batch(&f.set, cuts[i], cuts[i + 1], f.queries, f.masks, f.penalty, 7, one);
          ts_l1_best_reset(piece, 7);
          impl->single(&f.set, cuts[i], cuts[i + 1], f.queries, f.masks, f.penalty, 7, piece);
          ts_l1_best_merge(merged, piece, 7);
        }
        expect_same("pieces into one best", impl->name, 7, full, one);
        expect_same("merged pieces", impl->name, 7, full, merged);
      }
    }
    /* An empty range, or no queries, leaves best untouched. */
    for (int id = 0; id < TS_SIMD_COUNT; id++) {
      if (!variant_tested((ts_simd)id)) continue;
      const ts_l1_impl *impl = ts_l1_impl_get((ts_simd)id);
      ts_l1_best untouched[7];
      ts_l1_best_reset(untouched, 7);
      impl->batch(&f.set, 3, 3, f.queries, f.masks, f.penalty, 7, untouched);
      impl->single(&f.set, 3, 3, f.queries, f.masks, f.penalty, 7, untouched);
      impl->batch(&f.set, 0, ng, f.queries, f.masks, f.penalty, 0, untouched);
      for (int q = 0; q < 7; q++) assert_true(untouched[q].dist == UINT64_MAX);
    }
    fixture_free(&f);
  }
}

static void test_l1_batch_sizes(void **state) {
  (void)state;
  ts_rng rng;
  ts_rng_seed(&rng, 7, 0);
  for (uint32_t nq = 1; nq <= 70; nq++) {
    fixture f;
    uint32_t nc = nq % 3 == 0 ? 7 : nq % 3 == 1 ? 12 : 19;
    fixture_make(&f, &rng, 97 + nq, nc, nc / 3, 4, 1, nq, nq % 2 ? 256 : 3, nq % 5 == 0 ? 70 : 0,
                 nq % 4 == 0);
    check_all(&f);
    fixture_free(&f);
  }
}

/* The largest distances: 255 against 0 in every byte of 512 chunks, weights
 * and penalties at 2^32 - 1. All arithmetic must stay exact in 64 bits. */
static void test_l1_overflow_bounds(void **state) {
  (void)state;
  const uint32_t nvec = 19, nchunks = TS_L1_MAX_CHUNKS, nfine = 200;
  fixture f;
  ts_rng rng;
  ts_rng_seed(&rng, 8, 0);
  fixture_make(&f, &rng, nvec, nchunks, nfine, UINT32_MAX, UINT32_MAX - 1, 2, 256, 0, 1);
  uint8_t *vec = malloc(f.vbytes);
  assert_non_null(vec);
  memset(vec, 255, f.vbytes);
  for (uint32_t v = 0; v < nvec; v++) {
    vec[v % f.vbytes] = v == 17 ? 0 : 255; /* vector 17 is one byte closer */
    ts_l1_set_put(&f.set, v, vec);
    vec[v % f.vbytes] = 255;
    f.penalty[v] = UINT32_MAX;
  }
  free(vec);
  memset(f.queries, 0, (size_t)f.nq * f.vbytes);
  memset(f.queries + f.vbytes, 255, f.vbytes); /* query 1: distance 0 to all but 17 */
  uint64_t fine = 255ull * 8 * nfine, coarse = 255ull * 8 * (nchunks - nfine);
  uint64_t top = fine * UINT32_MAX + coarse * (UINT32_MAX - 1ull) + UINT32_MAX;
  assert_true(ts_l1_distance(&f.set, 0, f.queries, NULL, f.penalty) == top);
  assert_true(ts_l1_distance(&f.set, 17, f.queries, NULL, f.penalty) ==
              top - 255ull * (17 < nfine * 8 ? UINT32_MAX : UINT32_MAX - 1ull));
  check_all(&f);
  ts_l1_best best[2];
  ts_l1_best_reset(best, 2);
  ts_l1_impl_get(TS_SIMD_SCALAR)->batch(&f.set, 0, f.set.ngroups, f.queries, NULL, f.penalty, 2,
                                        best);
  assert_int_equal(best[0].index, 17);
  assert_true(best[0].dist == top - 255ull * UINT32_MAX);
  assert_int_equal(best[1].index, 0);
  assert_true(best[1].dist == UINT32_MAX);
  fixture_free(&f);
}

/* ---- weighted parts ---- */

/* 1, 2, 3, 7, 20 and 32 parts at random cuts with random weights (0 and the
 * largest among them), plain, masked and with penalties, over vector counts
 * that leave the last group partial, against brute force and the direct
 * distance. 3 and more parts take the kernels' MANY instances. */
static void test_l1_parts(void **state) {
  (void)state;
  static const uint32_t nparts[] = {1, 2, 3, 7, 20, 32};
  ts_rng rng;
  ts_rng_seed(&rng, 9, 0);
  for (size_t a = 0; a < sizeof(nparts) / sizeof(nparts[0]); a++) {
    uint32_t np = nparts[a];
    const uint32_t nchunks[] = {np, np + 1 + ts_rng_below(&rng, 8), 40};
    for (size_t b = 0; b < sizeof(nchunks) / sizeof(nchunks[0]); b++) {
      for (int variant = 0; variant < 4; variant++) {
        uint32_t density = variant & 1 ? 60 : 0, nvec = 77 + 126 * (uint32_t)b;
        uint32_t nq = variant == 3 ? 13 : 1 + 2 * (uint32_t)variant;
        fixture f;
        fixture_make(&f, &rng, nvec, nchunks[b], 0, 1, 1, nq, variant == 2 ? 3 : 256, density,
                     variant >= 2);
        fixture_parts(&f, &rng, np);
        expect_direct_distances(&f);
        check_all(&f);
        fixture_free(&f);
      }
    }
  }
  /* Long masked vectors in 32 parts, in a batch larger than what is
   * pre-ANDed at once. */
  fixture big;
  fixture_make(&big, &rng, 100, 300, 0, 1, 1, 20, 256, 50, 1);
  fixture_parts(&big, &rng, 32);
  check_all(&big);
  fixture_free(&big);
}

/* Every weight 0: only the penalties count (or nothing, and the first
 * vector wins); a part of weight 0 next to others is ignored. */
static void test_l1_parts_zero_weights(void **state) {
  (void)state;
  ts_rng rng;
  ts_rng_seed(&rng, 10, 0);
  static const uint32_t end[3] = {2, 5, 9};
  static const uint64_t zeros[3] = {0, 0, 0}, middle_off[3] = {3, 0, 7};
  for (int with_penalty = 0; with_penalty < 2; with_penalty++) {
    fixture f;
    fixture_make(&f, &rng, 203, 9, 0, 1, 1, 7, 256, 0, with_penalty);
    assert_int_equal(ts_l1_set_weigh(&f.set, 3, end, zeros, NULL), 0);
    for (uint32_t v = 0; v < f.set.nvec; v++)
      assert_true(ts_l1_distance(&f.set, v, f.queries, NULL, f.penalty) ==
                  (with_penalty ? f.penalty[v] : 0));
    check_all(&f);
    /* Changing the bytes of the weight-0 part changes nothing. */
    assert_int_equal(ts_l1_set_weigh(&f.set, 3, end, middle_off, NULL), 0);
    ts_l1_best before[7], after[7];
    ts_l1_best_reset(before, 7);
    brute(&f, 0, f.set.ngroups, before);
    for (size_t i = 2 * TS_L1_CHUNK; i < 5 * TS_L1_CHUNK; i++) f.queries[i] ^= 0x5A;
    ts_l1_best_reset(after, 7);
    brute(&f, 0, f.set.ngroups, after);
    assert_true(before[0].dist == after[0].dist);
    assert_int_equal(before[0].index, after[0].index);
    check_all(&f);
    fixture_free(&f);
  }
}

/* The largest distance with 32 parts: 255 against 0 in every byte of 512
 * chunks, every weight and penalty at its largest, exact in 64 bits. */
static void test_l1_parts_overflow_bounds(void **state) {
  (void)state;
  const uint32_t nvec = 19, nchunks = TS_L1_MAX_CHUNKS;
  fixture f;
  ts_rng rng;
  ts_rng_seed(&rng, 12, 0);
  fixture_make(&f, &rng, nvec, nchunks, 0, 1, 1, 2, 256, 0, 1);
  uint32_t end[TS_L1_MAX_PARTS];
  uint64_t weight[TS_L1_MAX_PARTS];
  for (uint32_t p = 0; p < TS_L1_MAX_PARTS; p++) {
    end[p] = (p + 1) * (nchunks / TS_L1_MAX_PARTS) - (p < TS_L1_MAX_PARTS - 1 ? p % 3 : 0);
    weight[p] = TS_L1_MAX_WEIGHT;
  }
  assert_int_equal(ts_l1_set_weigh(&f.set, TS_L1_MAX_PARTS, end, weight, NULL), 0);
  uint8_t *vec = malloc(f.vbytes);
  assert_non_null(vec);
  memset(vec, 255, f.vbytes);
  for (uint32_t v = 0; v < nvec; v++) {
    vec[(v * 211) % f.vbytes] = v == 11 ? 0 : 255; /* vector 11 is one byte closer */
    ts_l1_set_put(&f.set, v, vec);
    vec[(v * 211) % f.vbytes] = 255;
    f.penalty[v] = UINT32_MAX;
  }
  free(vec);
  memset(f.queries, 0, (size_t)f.nq * f.vbytes);
  memset(f.queries + f.vbytes, 255, f.vbytes);
  uint64_t top = 255ull * f.vbytes * TS_L1_MAX_WEIGHT + UINT32_MAX;
  assert_true(top < (uint64_t)1 << 53); /* the bound l1.h proves */
  assert_true(ts_l1_distance(&f.set, 0, f.queries, NULL, f.penalty) == top);
  check_all(&f);
  ts_l1_best best[2];
  ts_l1_best_reset(best, 2);
  ts_l1_impl_get(TS_SIMD_SCALAR)->batch(&f.set, 0, f.set.ngroups, f.queries, NULL, f.penalty, 2,
                                        best);
  assert_int_equal(best[0].index, 11);
  assert_true(best[0].dist == top - 255ull * TS_L1_MAX_WEIGHT);
  assert_int_equal(best[1].index, 0);
  assert_true(best[1].dist == UINT32_MAX);
  fixture_free(&f);
}

/* One refused setting: TS_EINVAL, a message naming `needle`, and the set's
 * parts as they were. */
static void expect_refused(ts_l1_set *set, uint32_t nparts, const uint32_t *end,
                           const uint64_t *weight, const char *needle) {
  ts_l1_set before = *set;
  char err[TS_ERR_LEN] = "";
  assert_int_equal(ts_l1_set_weigh(set, nparts, end, weight, err), TS_EINVAL);
  print_message("message: %s\n", err);
  assert_non_null(strstr(err, needle));
  assert_memory_equal(set, &before, sizeof(before));
  assert_int_equal(ts_l1_set_weigh(set, nparts, end, weight, NULL), TS_EINVAL);
}

static void test_l1_weigh_refuses(void **state) {
  (void)state;
  ts_l1_set set;
  assert_int_equal(ts_l1_set_init(&set, 10, 40), 0);
  uint32_t end[TS_L1_MAX_PARTS + 1];
  uint64_t weight[TS_L1_MAX_PARTS + 1];
  for (uint32_t p = 0; p <= TS_L1_MAX_PARTS; p++) {
    end[p] = p + 1;
    weight[p] = p;
  }
  expect_refused(&set, 0, end, weight, "0 weighted parts: need 1..32");
  end[TS_L1_MAX_PARTS] = 40;
  expect_refused(&set, TS_L1_MAX_PARTS + 1, end, weight, "33 weighted parts: need 1..32");
  end[TS_L1_MAX_PARTS - 1] = 40; /* 32 parts: fine */
  char err[TS_ERR_LEN] = "";
  assert_int_equal(ts_l1_set_weigh(&set, TS_L1_MAX_PARTS, end, weight, err), 0);
  assert_int_equal(set.nparts, TS_L1_MAX_PARTS);

  ts_l1_set_free(&set);
  assert_int_equal(ts_l1_set_init(&set, 10, 7), 0);
  const uint32_t empty[3] = {3, 3, 7}, backwards[3] = {4, 2, 7}, past[2] = {3, 9},
                 short_[2] = {3, 6}, first_empty[2] = {0, 7};
  const uint64_t w3[3] = {1, 2, 3};
  expect_refused(&set, 3, empty, w3, "weighted part 1 ends at chunk 3");
  expect_refused(&set, 3, backwards, w3, "weighted part 1 ends at chunk 2");
  expect_refused(&set, 2, past, w3, "part 1 ends at chunk 9: parts must be non-empty, in order "
                                    "and within the vector's 7 chunks");
  expect_refused(&set, 2, short_, w3, "end at chunk 6, but the vectors have 7 chunks");
  expect_refused(&set, 2, first_empty, w3, "weighted part 0 ends at chunk 0");
  const uint32_t two[2] = {3, 7};
  const uint64_t too_heavy[2] = {1, TS_L1_MAX_WEIGHT + 1};
  expect_refused(&set, 2, two, too_heavy, "part 1: weight 4294967296 is above the largest");
  const uint64_t heaviest[2] = {TS_L1_MAX_WEIGHT, 0};
  assert_int_equal(ts_l1_set_weigh(&set, 2, two, heaviest, err), 0);
  assert_true(set.part_weight[0] == TS_L1_MAX_WEIGHT);

  /* The fine/coarse helper: empty parts left out, the same checks. */
  assert_int_equal(ts_l1_set_weigh_fine_coarse(&set, 3, 5, 9, err), 0);
  assert_int_equal(set.nparts, 2);
  assert_int_equal(set.part_end[0], 3);
  assert_int_equal(set.part_end[1], 7);
  assert_true(set.part_weight[0] == 5 && set.part_weight[1] == 9);
  assert_int_equal(ts_l1_set_weigh_fine_coarse(&set, 7, 5, 0, err), 0);
  assert_int_equal(set.nparts, 1);
  assert_true(set.part_end[0] == 7 && set.part_weight[0] == 5);
  assert_int_equal(ts_l1_set_weigh_fine_coarse(&set, 0, 5, 9, err), 0);
  assert_int_equal(set.nparts, 1);
  assert_true(set.part_end[0] == 7 && set.part_weight[0] == 9);
  assert_int_equal(ts_l1_set_weigh_fine_coarse(&set, 8, 5, 9, err), TS_EINVAL);
  print_message("message: %s\n", err);
  assert_non_null(strstr(err, "8 fine chunks, but the vectors have only 7"));
  assert_int_equal(ts_l1_set_weigh_fine_coarse(&set, 3, (uint64_t)1 << 40, 9, err), TS_EINVAL);
  print_message("message: %s\n", err);
  assert_non_null(strstr(err, "weight 1099511627776 is above the largest"));
  assert_true(set.part_end[0] == 7 && set.part_weight[0] == 9); /* unchanged */
  ts_l1_set_free(&set);
}

/* ---- one test per variant ---- */

/* Variant `id` is here and is the one the tests above compare against
 * brute force: it has its name and id, TEXSYN_SIMD selects it by name,
 * and its single and batch scans of a set with weighted parts, masks and
 * penalties equal brute force. A variant this CPU lacks is skipped, not
 * passed: the comparisons above left it out. */
static void variant_is_tested(ts_simd id) {
  static const char *names[] = {"scalar", "mmx", "sse2", "avx2", "avx512"};
  const ts_l1_impl *impl = ts_l1_impl_get(id);
  if (impl == NULL) ts_test_skip("the CPU lacks %s", names[id]);
  if (!variant_tested(id)) ts_test_skip("TEXSYN_SIMD=%s leaves %s untested", getenv("TEXSYN_SIMD"), names[id]);
  assert_int_equal(impl->id, id);
  assert_string_equal(impl->name, names[id]);
  char *saved = save_env();
  setenv("TEXSYN_SIMD", names[id], 1);
  const ts_l1_impl *chosen = NULL;
  char err[TS_ERR_LEN] = "";
  assert_int_equal(ts_l1_select(&chosen, err), 0);
  assert_ptr_equal(chosen, impl);
  restore_env(saved);
  ts_rng rng;
  ts_rng_seed(&rng, 13, (uint64_t)id);
  fixture f;
  fixture_make(&f, &rng, 517, 19, 0, 1, 1, 9, 256, 60, 1);
  fixture_parts(&f, &rng, 5);
  ts_l1_best want[9], got[9];
  ts_l1_best_reset(want, 9);
  brute(&f, 0, f.set.ngroups, want);
  ts_l1_best_reset(got, 9);
  impl->single(&f.set, 0, f.set.ngroups, f.queries, f.masks, f.penalty, 9, got);
  expect_same("single", impl->name, 9, want, got);
  ts_l1_best_reset(got, 9);
  impl->batch(&f.set, 0, f.set.ngroups, f.queries, f.masks, f.penalty, 9, got);
  expect_same("batch", impl->name, 9, want, got);
  fixture_free(&f);
}

static void test_l1_variant_scalar(void **state) { (void)state; variant_is_tested(TS_SIMD_SCALAR); }
static void test_l1_variant_mmx(void **state) { (void)state; variant_is_tested(TS_SIMD_MMX); }
static void test_l1_variant_sse2(void **state) { (void)state; variant_is_tested(TS_SIMD_SSE2); }
static void test_l1_variant_avx2(void **state) { (void)state; variant_is_tested(TS_SIMD_AVX2); }
static void test_l1_variant_avx512(void **state) { (void)state; variant_is_tested(TS_SIMD_AVX512); }

/* ---- selection ---- */

static void test_l1_simd_from_name(void **state) {
  (void)state;
  static const char *names[] = {"scalar", "mmx", "sse2", "avx2", "avx512"};
  for (int i = 0; i < TS_SIMD_COUNT; i++) assert_int_equal(ts_simd_from_name(names[i]), i);
  assert_int_equal(ts_simd_from_name("AVX2"), TS_SIMD_COUNT);
  assert_int_equal(ts_simd_from_name(""), TS_SIMD_COUNT);
  assert_int_equal(ts_simd_from_name(NULL), TS_SIMD_COUNT);
}

static void test_l1_impl_get(void **state) {
  (void)state;
  assert_non_null(ts_l1_impl_get(TS_SIMD_SCALAR));
  assert_non_null(ts_l1_impl_get(TS_SIMD_SSE2)); /* baseline on x86-64 */
  assert_null(ts_l1_impl_get(TS_SIMD_COUNT));
  assert_null(ts_l1_impl_get((ts_simd)-1));
  for (int i = 0; i < TS_SIMD_COUNT; i++) {
    const ts_l1_impl *impl = ts_l1_impl_get((ts_simd)i);
    if (impl == NULL) {
      print_message("variant %d not supported here\n", i);
      continue;
    }
    assert_int_equal(impl->id, i);
    assert_int_equal(ts_simd_from_name(impl->name), i);
    assert_non_null(impl->single);
    assert_non_null(impl->batch);
  }
}

static void test_l1_select_default(void **state) {
  (void)state;
  char *saved = save_env();
  unsetenv("TEXSYN_SIMD");
  const ts_l1_impl *impl = NULL;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_l1_select(&impl, err), 0);
  assert_non_null(impl);
  for (int i = impl->id + 1; i < TS_SIMD_COUNT; i++) assert_null(ts_l1_impl_get((ts_simd)i));
  setenv("TEXSYN_SIMD", "", 1); /* empty counts as unset */
  const ts_l1_impl *again = NULL;
  assert_int_equal(ts_l1_select(&again, err), 0);
  assert_ptr_equal(again, impl);
  restore_env(saved);
}

static void test_l1_select_unknown(void **state) {
  (void)state;
  char *saved = save_env();
  setenv("TEXSYN_SIMD", "avx1024", 1);
  const ts_l1_impl *impl = (const ts_l1_impl *)1;
  char err[TS_ERR_LEN] = "";
  assert_int_equal(ts_l1_select(&impl, err), TS_EINVAL);
  assert_null(impl);
  print_message("message: %s\n", err);
  assert_non_null(strstr(err, "avx1024"));
  assert_non_null(strstr(err, "scalar, mmx, sse2, avx2, avx512"));
  assert_int_equal(ts_l1_select(&impl, NULL), TS_EINVAL); /* err is optional */
  restore_env(saved);
}

static void test_l1_select_forced(void **state) {
  (void)state;
  char *saved = save_env();
  for (int i = 0; i < TS_SIMD_COUNT; i++) {
    const ts_l1_impl *want = ts_l1_impl_get((ts_simd)i);
    static const char *names[] = {"scalar", "mmx", "sse2", "avx2", "avx512"};
    setenv("TEXSYN_SIMD", names[i], 1);
    const ts_l1_impl *impl = NULL;
    char err[TS_ERR_LEN] = "";
    int rc = ts_l1_select(&impl, err);
    if (want != NULL) {
      assert_int_equal(rc, 0);
      assert_ptr_equal(impl, want);
      assert_string_equal(impl->name, names[i]);
    } else {
      assert_int_equal(rc, TS_ENOTSUP);
      assert_null(impl);
      print_message("message: %s\n", err);
      assert_non_null(strstr(err, names[i]));
      assert_non_null(strstr(err, "supported here: scalar"));
    }
  }
  restore_env(saved);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(test_l1_set_layout),
    cmocka_unit_test(test_l1_best_merge),
    cmocka_unit_test(test_l1_distance_reference),
    cmocka_unit_test(test_l1_shapes),
    cmocka_unit_test(test_l1_weights),
    cmocka_unit_test(test_l1_masks),
    cmocka_unit_test(test_l1_penalty),
    cmocka_unit_test(test_l1_ties),
    cmocka_unit_test(test_l1_subranges),
    cmocka_unit_test(test_l1_batch_sizes),
    cmocka_unit_test(test_l1_overflow_bounds),
    cmocka_unit_test(test_l1_parts),
    cmocka_unit_test(test_l1_parts_zero_weights),
    cmocka_unit_test(test_l1_parts_overflow_bounds),
    cmocka_unit_test(test_l1_weigh_refuses),
    cmocka_unit_test(test_l1_variant_scalar),
    cmocka_unit_test(test_l1_variant_mmx),
    cmocka_unit_test(test_l1_variant_sse2),
    cmocka_unit_test(test_l1_variant_avx2),
    cmocka_unit_test(test_l1_variant_avx512),
    cmocka_unit_test(test_l1_simd_from_name),
    cmocka_unit_test(test_l1_impl_get),
    cmocka_unit_test(test_l1_select_default),
    cmocka_unit_test(test_l1_select_unknown),
    cmocka_unit_test(test_l1_select_forced),
};

TS_TEST_MAIN(tests)
