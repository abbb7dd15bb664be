/* test_patchmatch.c - the PatchMatch field (patchmatch.h): a pass gives
 * the same field on 1 or 3 threads, with its tiles swept in two calls, and
 * with the scalar or SSE2 distance; distances, occurrence counts and block
 * sums against plain loops; a target cut from the source is found exactly;
 * the uniformity penalty spreads a field over more of a flat source; a
 * field entry off the source and a target of the wrong size are refused. */
#include "error.h"
#include "patchmatch.h"
#include "pool.h"
#include "rng.h"
#include "ts_test.h"

enum { P = 5, R = P / 2, NPL = 4 }; /* planes: an RGB part and a grey part */

typedef struct {
  ts_plane src[NPL], tgt[NPL];
  ts_window win;
  ts_pm_field f;
  int tw, th;
  uint32_t *in;
} scene;

static void window_make(ts_window *win) {
  int16_t dx[P * P], dy[P * P];
  for (int i = 0; i < P * P; i++) {
    dx[i] = (int16_t)(i % P);
    dy[i] = (int16_t)(i / P);
  }
  ts_window_spec s = {.nplanes = {NPL, 0}, .noff = {P * P, 0}, .dx = {dx, NULL}, .dy = {dy, NULL},
                      .extent = {{0, 0, P, P}}, .block = P, .nparts = 2};
  s.part[0] = (ts_part){TS_SRC_FINE, 0, 3, 280};
  s.part[1] = (ts_part){TS_SRC_FINE, 3, 1, 420};
  char err[TS_ERR_LEN];
  assert_int_equal(ts_window_init(win, &s, err), 0);
}

/* Smooth random planes (sums of a few waves plus noise) so that patches
 * differ and PatchMatch has something to follow. */
static void plane_fill(ts_plane *pl, int w, int h, ts_rng *rng, int noise) {
  assert_int_equal(ts_plane_alloc(pl, w, h), 0);
  int fx = 1 + (int)ts_rng_below(rng, 7), fy = 1 + (int)ts_rng_below(rng, 7);
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      int v = 128 + (int)(60 * ((x * fx + y * fy) % 37) / 37) - 30 + (int)ts_rng_below(rng, (uint32_t)noise + 1);
      pl->px[(size_t)y * (size_t)w + (size_t)x] = (uint8_t)(v < 0 ? 0 : v > 255 ? 255 : v);
    }
}

/* A source sw x sh, a target (tw + P - 1) x (th + P - 1) cut from the
 * source at (ox, oy) when cut, else random; a seeded random field. */
static void scene_make(scene *s, int sw, int sh, int tw, int th, int cut, uint64_t seed) {
  ts_rng rng;
  ts_rng_seed(&rng, seed, 0);
  memset(s, 0, sizeof(*s));
  s->tw = tw;
  s->th = th;
  window_make(&s->win);
  const ts_plane *sp[NPL];
  int ow = tw + P - 1, oh = th + P - 1, ox = 3, oy = 2;
  for (int k = 0; k < NPL; k++) {
    plane_fill(&s->src[k], sw, sh, &rng, 40);
    sp[k] = &s->src[k];
    if (cut) {
      assert_int_equal(ts_plane_alloc(&s->tgt[k], ow, oh), 0);
      for (int y = 0; y < oh; y++)
        memcpy(s->tgt[k].px + (size_t)y * (size_t)ow, s->src[k].px + (size_t)(y + oy) * (size_t)sw + ox, (size_t)ow);
    } else {
      plane_fill(&s->tgt[k], ow, oh, &rng, 40);
    }
  }
  char err[TS_ERR_LEN];
  assert_int_equal(ts_pm_field_init(&s->f, &s->win, sp, 3, err), 0);
  const ts_plane *tp[NPL] = {&s->tgt[0], &s->tgt[1], &s->tgt[2], &s->tgt[3]};
  assert_int_equal(ts_pm_field_target(&s->f, tp, err), 0);
  s->in = malloc(2 * sizeof(uint32_t) * (size_t)tw * (size_t)th);
  assert_non_null(s->in);
  for (int i = 0; i < tw * th; i++) {
    s->in[2 * i] = R + ts_rng_below(&rng, (uint32_t)(sw - 2 * R));
    s->in[2 * i + 1] = R + ts_rng_below(&rng, (uint32_t)(sh - 2 * R));
  }
}

static void scene_free(scene *s) {
  ts_pm_field_free(&s->f);
  ts_window_free(&s->win);
  for (int k = 0; k < NPL; k++) {
    ts_plane_free(&s->src[k]);
    ts_plane_free(&s->tgt[k]);
  }
  free(s->in);
}

static uint32_t *field_new(const scene *s) {
  uint32_t *f = malloc(2 * sizeof(uint32_t) * (size_t)s->tw * (size_t)s->th);
  assert_non_null(f);
  return f;
}

/* passes passes from s->in into a new field, on a pool of nthreads. */
static uint32_t *run_passes(scene *s, int passes, int nthreads, uint64_t k, int scalar) {
  ts_pool *pool;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_pool_create(&pool, nthreads), 0);
  uint32_t *cur = field_new(s), *next = field_new(s);
  memcpy(cur, s->in, 2 * sizeof(uint32_t) * (size_t)s->tw * (size_t)s->th);
  for (int q = 0; q < passes; q++) {
    ts_pm_job j = {s->tw, s->th, cur, k, 77, (uint32_t)q, scalar};
    assert_int_equal(ts_pm_field_pass(&s->f, &j, NULL, 0, pool, next, err), 0);
    uint32_t *t = cur;
    cur = next;
    next = t;
  }
  free(next);
  ts_pool_destroy(pool);
  return cur;
}

static size_t field_bytes(const scene *s) { return 2 * sizeof(uint32_t) * (size_t)s->tw * (size_t)s->th; }

/* ---- plain loops ------------------------------------------------------- */

static uint64_t brute_distance(const scene *s, int x, int y, int cx, int cy) {
  uint64_t d = 0;
  for (int k = 0; k < NPL; k++) {
    uint64_t w = k < 3 ? 280 : 420, sum = 0;
    for (int dy = 0; dy < P; dy++)
      for (int dx = 0; dx < P; dx++) {
        int a = ts_plane_at(&s->tgt[k], x + dx, y + dy), b = ts_plane_at(&s->src[k], cx - R + dx, cy - R + dy);
        sum += (uint64_t)(a > b ? a - b : b - a);
      }
    d += w * sum;
  }
  return d;
}

/* ---- tests ------------------------------------------------------------- */

static void threads_tiles_and_variants_agree(void **state) {
  (void)state;
  scene s;
  scene_make(&s, 90, 70, 150, 130, 0, 5); /* 3 x 3 tiles, ragged edges */
  uint64_t k = 1ull << 30;
  uint32_t *one = run_passes(&s, 3, 1, k, 0), *three = run_passes(&s, 3, 3, k, 0);
  uint32_t *scalar = run_passes(&s, 3, 3, k, 1);
  assert_memory_equal(one, three, field_bytes(&s));
  assert_memory_equal(one, scalar, field_bytes(&s));
  /* One pass with its tiles in two calls (as two workers would). */
  ts_pool *pool;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_pool_create(&pool, 2), 0);
  uint32_t *whole = field_new(&s), *split = field_new(&s);
  ts_pm_job j = {s.tw, s.th, s.in, k, 9, 1, 0};
  assert_int_equal(ts_pm_field_pass(&s.f, &j, NULL, 0, pool, whole, err), 0);
  int nt = ts_pm_tiles(s.tw, s.th);
  assert_int_equal(nt, 9);
  uint32_t odd[8], even[8];
  int no = 0, ne = 0;
  for (int t = 0; t < nt; t++) {
    if (t % 2) odd[no++] = (uint32_t)t;
    else even[ne++] = (uint32_t)t;
  }
  assert_int_equal(ts_pm_field_pass(&s.f, &j, odd, no, pool, split, err), 0);
  assert_int_equal(ts_pm_field_pass(&s.f, &j, even, ne, pool, split, err), 0);
  assert_memory_equal(whole, split, field_bytes(&s));
  ts_pool_destroy(pool);
  free(whole);
  free(split);
  free(one);
  free(three);
  free(scalar);
  scene_free(&s);
}

/* Every pixel's final match is no worse than where it started: a pass
 * keeps a candidate only when strictly better. */
static void a_pass_never_makes_a_match_worse(void **state) {
  (void)state;
  scene s;
  scene_make(&s, 60, 50, 70, 65, 0, 11);
  uint32_t *out = run_passes(&s, 1, 2, 0, 0);
  int improved = 0;
  for (int y = 0; y < s.th; y++)
    for (int x = 0; x < s.tw; x++) {
      const uint32_t *a = &s.in[2 * (y * s.tw + x)], *b = &out[2 * (y * s.tw + x)];
      uint64_t da = brute_distance(&s, x, y, (int)a[0], (int)a[1]), db = brute_distance(&s, x, y, (int)b[0], (int)b[1]);
      assert_true(db <= da);
      improved += db < da;
    }
  assert_true(improved > s.tw * s.th / 2);
  free(out);
  scene_free(&s);
}

/* A target cut from the source at (3, 2): after a few passes nearly every
 * pixel away from the padded edge finds its own place, distance 0. */
static void a_cut_of_the_source_is_found(void **state) {
  (void)state;
  scene s;
  scene_make(&s, 120, 100, 80, 70, 1, 3);
  uint32_t *out = run_passes(&s, 6, 2, 0, 0);
  int exact = 0, n = 0;
  for (int y = 0; y < s.th; y++)
    for (int x = 0; x < s.tw; x++, n++) {
      const uint32_t *c = &out[2 * (y * s.tw + x)];
      exact += c[0] == (uint32_t)(x + 3 + R) && c[1] == (uint32_t)(y + 2 + R);
    }
  assert_true(exact >= n * 95 / 100);
  free(out);
  scene_free(&s);
}

static void occurrences_and_block_sums_match_loops(void **state) {
  (void)state;
  scene s;
  scene_make(&s, 40, 30, 50, 45, 0, 8);
  int sw = 40, sh = 30, nx = sw - P + 1, ny = sh - P + 1;
  uint32_t *counts = calloc((size_t)sw * sh, 4), *ub = calloc((size_t)nx * ny, 4), *col = calloc((size_t)sw, 4);
  uint32_t *want = calloc((size_t)sw * sh, 4);
  ts_pm_occurrences(s.in, (size_t)s.tw * (size_t)s.th, P, sw, sh, counts);
  for (int i = 0; i < s.tw * s.th; i++)
    for (int y = (int)s.in[2 * i + 1] - R; y <= (int)s.in[2 * i + 1] + R; y++)
      for (int x = (int)s.in[2 * i] - R; x <= (int)s.in[2 * i] + R; x++) want[y * sw + x]++;
  assert_memory_equal(counts, want, (size_t)sw * sh * 4);
  ts_pm_block_sums(counts, P, sw, sh, col, ub);
  for (int y = 0; y < ny; y++)
    for (int x = 0; x < nx; x++) {
      uint32_t sum = 0;
      for (int dy = 0; dy < P; dy++)
        for (int dx = 0; dx < P; dx++) sum += counts[(y + dy) * sw + x + dx];
      assert_int_equal(ub[y * nx + x], sum);
    }
  free(counts);
  free(ub);
  free(col);
  free(want);
  scene_free(&s);
}

/* Source and target one flat grey: without the penalty every patch keeps
 * its random start's neighbourhood (all distances 0, ties to the lowest
 * index pull them together); with it they spread over more of the source. */
static size_t covered(const scene *s, const uint32_t *f, int sw, int sh) {
  uint32_t *counts = calloc((size_t)sw * sh, 4);
  ts_pm_occurrences(f, (size_t)s->tw * (size_t)s->th, P, sw, sh, counts);
  size_t n = 0;
  for (int i = 0; i < sw * sh; i++) n += counts[i] > 0;
  free(counts);
  return n;
}

static void the_penalty_spreads_the_field(void **state) {
  (void)state;
  scene s;
  scene_make(&s, 64, 64, 64, 64, 0, 21);
  for (int k = 0; k < NPL; k++) {
    memset(s.src[k].px, 100, 64 * 64);
    memset(s.tgt[k].px, 100, (size_t)s.tgt[k].w * s.tgt[k].h);
  }
  char err[TS_ERR_LEN];
  const ts_plane *sp[NPL] = {&s.src[0], &s.src[1], &s.src[2], &s.src[3]};
  const ts_plane *tp[NPL] = {&s.tgt[0], &s.tgt[1], &s.tgt[2], &s.tgt[3]};
  ts_pm_field_free(&s.f);
  assert_int_equal(ts_pm_field_init(&s.f, &s.win, sp, 2, err), 0);
  assert_int_equal(ts_pm_field_target(&s.f, tp, err), 0);
  uint32_t *plain = run_passes(&s, 4, 2, 0, 0), *spread = run_passes(&s, 4, 2, 1ull << 32, 0);
  size_t a = covered(&s, plain, 64, 64), b = covered(&s, spread, 64, 64);
  assert_true(b > a + a / 4);
  free(plain);
  free(spread);
  scene_free(&s);
}

static void bad_fields_and_targets_are_refused(void **state) {
  (void)state;
  scene s;
  scene_make(&s, 40, 30, 20, 20, 0, 4);
  ts_pool *pool;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_pool_create(&pool, 1), 0);
  uint32_t *out = field_new(&s);
  s.in[2 * 7] = 1; /* x 1 < r: no patch centre */
  ts_pm_job j = {s.tw, s.th, s.in, 0, 1, 0, 0};
  assert_int_equal(ts_pm_field_pass(&s.f, &j, NULL, 0, pool, out, err), TS_EINVAL);
  assert_non_null(strstr(err, "entry 7"));
  s.in[2 * 7] = R;
  j.tw = 21;
  assert_int_equal(ts_pm_field_pass(&s.f, &j, NULL, 0, pool, out, err), TS_EINVAL);
  assert_non_null(strstr(err, "does not fit"));
  j.tw = 20;
  uint32_t tile = 5;
  assert_int_equal(ts_pm_field_pass(&s.f, &j, &tile, 1, pool, out, err), TS_EINVAL);
  free(out);
  ts_pool_destroy(pool);
  scene_free(&s);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(threads_tiles_and_variants_agree),
    cmocka_unit_test(a_pass_never_makes_a_match_worse),
    cmocka_unit_test(a_cut_of_the_source_is_found),
    cmocka_unit_test(occurrences_and_block_sums_match_loops),
    cmocka_unit_test(the_penalty_spreads_the_field),
    cmocka_unit_test(bad_fields_and_targets_are_refused),
};

TS_TEST_MAIN(tests)
