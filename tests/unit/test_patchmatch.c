/* test_patchmatch.c - the PatchMatch field (patchmatch.h): a pass gives
 * the same field on 1 or 3 threads, with its tiles swept in two calls, and
 * with the scalar or SSE2 distance; a pass against plain loops of its
 * contract, for every distance kernel (patches 3 and 5 with one 16-byte
 * chunk per part row, patch 7 with two) with and without the penalty;
 * distances, occurrence counts and block sums against plain loops; a target
 * cut from the source is found exactly; the uniformity penalty spreads a
 * field over more of a flat source; a field entry off the source and a
 * target of the wrong size are refused. */
#include "error.h"
#include "patchmatch.h"
#include "pool.h"
#include "rng.h"
#include "ts_test.h"

enum { P = 5, R = P / 2, NPL = 4 }; /* planes: an RGB part and a grey part */
enum { MAXP = 7 };                  /* the largest patch a scene takes */

typedef struct {
  ts_plane src[NPL], tgt[NPL];
  ts_window win;
  ts_pm_field f;
  int p, tw, th;
  uint32_t *in;
} scene;

static const uint32_t kWeight[NPL] = {280, 280, 280, 420}; /* per plane */

static void window_make(ts_window *win, int p) {
  int16_t dx[MAXP * MAXP], dy[MAXP * MAXP];
  for (int i = 0; i < p * p; i++) {
    dx[i] = (int16_t)(i % p);
    dy[i] = (int16_t)(i / p);
  }
  ts_window_spec s = {.nplanes = {NPL, 0}, .noff = {p * p, 0}, .dx = {dx, NULL}, .dy = {dy, NULL},
                      .extent = {{0, 0, (int16_t)p, (int16_t)p}}, .block = p, .nparts = 2};
  s.part[0] = (ts_part){TS_SRC_FINE, 0, 3, kWeight[0]};
  s.part[1] = (ts_part){TS_SRC_FINE, 3, 1, kWeight[3]};
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

/* A source sw x sh, a target (tw + p - 1) x (th + p - 1) cut from the
 * source at (ox, oy) when cut, else random; a seeded random field. */
static void scene_make_p(scene *s, int p, int sw, int sh, int tw, int th, int cut, uint64_t seed) {
  ts_rng rng;
  ts_rng_seed(&rng, seed, 0);
  memset(s, 0, sizeof(*s));
  s->p = p;
  s->tw = tw;
  s->th = th;
  window_make(&s->win, p);
  const ts_plane *sp[NPL];
  int ow = tw + p - 1, oh = th + p - 1, ox = 3, oy = 2, r = p / 2;
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
    s->in[2 * i] = (uint32_t)r + ts_rng_below(&rng, (uint32_t)(sw - 2 * r));
    s->in[2 * i + 1] = (uint32_t)r + ts_rng_below(&rng, (uint32_t)(sh - 2 * r));
  }
}

static void scene_make(scene *s, int sw, int sh, int tw, int th, int cut, uint64_t seed) {
  scene_make_p(s, P, sw, sh, tw, th, cut, seed);
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
  int p = s->p, r = p / 2;
  uint64_t d = 0;
  for (int k = 0; k < NPL; k++) {
    uint64_t sum = 0;
    for (int dy = 0; dy < p; dy++)
      for (int dx = 0; dx < p; dx++) {
        int a = ts_plane_at(&s->tgt[k], x + dx, y + dy), b = ts_plane_at(&s->src[k], cx - r + dx, cy - r + dy);
        sum += (uint64_t)(a > b ? a - b : b - a);
      }
    d += kWeight[k] * sum;
  }
  return d;
}

/* A pass as patchmatch.h words it, in plain loops: tile by tile, the
 * occurrence counts of the input plus the tile's own moves kept as counts
 * and summed over a patch for each penalty. */
typedef struct {
  const scene *s;
  int sw, sh, r;
  uint32_t *counts; /* of the input, then the tile's moves */
  uint64_t k;
} plain_pass;

static uint64_t plain_distance(const plain_pass *pp, int x, int y, int cx, int cy) {
  uint64_t d = brute_distance(pp->s, x, y, cx, cy);
  if (pp->k == 0) return d;
  uint32_t u = 0;
  for (int dy = -pp->r; dy <= pp->r; dy++)
    for (int dx = -pp->r; dx <= pp->r; dx++) u += pp->counts[(cy + dy) * pp->sw + cx + dx];
  unsigned __int128 pen = ((unsigned __int128)u * pp->k) >> 32;
  return d + (pen > UINT32_MAX ? UINT32_MAX : (uint32_t)pen);
}

static void count_patch(uint32_t *counts, int sw, int r, int cx, int cy, int delta) {
  for (int dy = -r; dy <= r; dy++)
    for (int dx = -r; dx <= r; dx++) counts[(cy + dy) * sw + cx + dx] += (uint32_t)delta;
}

typedef struct {
  uint64_t d;
  int cx, cy;
} plain_best;

static void plain_try(const plain_pass *pp, int x, int y, long cx, long cy, plain_best *b) {
  if (cx < pp->r || cy < pp->r || cx >= pp->sw - pp->r || cy >= pp->sh - pp->r) return;
  uint64_t d = plain_distance(pp, x, y, (int)cx, (int)cy);
  long nx = pp->sw - 2 * pp->r, j = (cy - pp->r) * nx + cx - pp->r, bj = (b->cy - pp->r) * nx + b->cx - pp->r;
  if (d < b->d || (d == b->d && j < bj)) *b = (plain_best){d, (int)cx, (int)cy};
}

static long clamp_long(long v, long lo, long hi) { return v < lo ? lo : v > hi ? hi : v; }

static void plain_tile(plain_pass *pp, const uint32_t *in, uint32_t *out, uint64_t seed, uint32_t pass, int t) {
  const scene *s = pp->s;
  int ntx = (s->tw + TS_PM_TILE - 1) / TS_PM_TILE, x0 = t % ntx * TS_PM_TILE, y0 = t / ntx * TS_PM_TILE;
  int x1 = x0 + TS_PM_TILE < s->tw ? x0 + TS_PM_TILE : s->tw, y1 = y0 + TS_PM_TILE < s->th ? y0 + TS_PM_TILE : s->th;
  int back = pass & 1, step = back ? -1 : 1;
  ts_rng rng;
  ts_rng_seed(&rng, seed, ((uint64_t)pass << 32) | (uint32_t)t);
  for (int i = 0; i < (y1 - y0) * (x1 - x0); i++) {
    int y = back ? y1 - 1 - i / (x1 - x0) : y0 + i / (x1 - x0), x = back ? x1 - 1 - i % (x1 - x0) : x0 + i % (x1 - x0);
    const uint32_t *cur = &in[2 * (y * s->tw + x)];
    plain_best b = {plain_distance(pp, x, y, (int)cur[0], (int)cur[1]), (int)cur[0], (int)cur[1]};
    int nb[2][2] = {{x - step, y}, {x, y - step}};
    for (int n = 0; n < 2; n++) {
      int nx = nb[n][0], ny = nb[n][1];
      if (nx < 0 || ny < 0 || nx >= s->tw || ny >= s->th) continue;
      int inside = nx >= x0 && nx < x1 && ny >= y0 && ny < y1;
      const uint32_t *f = &(inside ? out : in)[2 * (ny * s->tw + nx)];
      plain_try(pp, x, y, (long)f[0] + (x - nx), (long)f[1] + (y - ny), &b);
    }
    for (long radius = pp->sw > pp->sh ? pp->sw : pp->sh; radius >= 1; radius /= 2) {
      long cx = b.cx + (long)ts_rng_below(&rng, (uint32_t)(2 * radius + 1)) - radius;
      long cy = b.cy + (long)ts_rng_below(&rng, (uint32_t)(2 * radius + 1)) - radius;
      plain_try(pp, x, y, clamp_long(cx, pp->r, pp->sw - 1 - pp->r), clamp_long(cy, pp->r, pp->sh - 1 - pp->r), &b);
    }
    out[2 * (y * s->tw + x)] = (uint32_t)b.cx;
    out[2 * (y * s->tw + x) + 1] = (uint32_t)b.cy;
    count_patch(pp->counts, pp->sw, pp->r, (int)cur[0], (int)cur[1], -1);
    count_patch(pp->counts, pp->sw, pp->r, b.cx, b.cy, 1);
  }
}

static void plain_pass_run(const scene *s, const uint32_t *in, uint64_t k, uint64_t seed, uint32_t pass,
                           uint32_t *out) {
  plain_pass pp = {s, s->src[0].w, s->src[0].h, s->p / 2, calloc((size_t)s->src[0].w * s->src[0].h, 4), k};
  uint32_t *start = calloc((size_t)pp.sw * pp.sh, 4);
  assert_non_null(pp.counts);
  assert_non_null(start);
  for (int i = 0; i < s->tw * s->th; i++) count_patch(start, pp.sw, pp.r, (int)in[2 * i], (int)in[2 * i + 1], 1);
  for (int t = 0; t < ts_pm_tiles(s->tw, s->th); t++) {
    memcpy(pp.counts, start, (size_t)pp.sw * pp.sh * 4);
    plain_tile(&pp, in, out, seed, pass, t);
  }
  free(start);
  free(pp.counts);
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

/* Two passes (both sweep directions) against plain_pass_run on a small
 * source, where many moves touch its edges: patches 3 and 5 take the
 * kernels with one 16-byte chunk per part row, 7 the one with two (21
 * bytes), TEXSYN_SIMD=scalar the plain one; no penalty, a moderate one and
 * one that saturates. */
static void a_pass_follows_its_contract(void **state) {
  (void)state;
  static const uint64_t ks[] = {0, 64ull << 32, 1ull << 52};
  ts_pool *pool;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_pool_create(&pool, 2), 0);
  for (int p = 3; p <= MAXP; p += 2)
    for (size_t ki = 0; ki < sizeof(ks) / sizeof(ks[0]); ki++) {
      scene s;
      scene_make_p(&s, p, 40, 30, 70, 65, 0, 40 + (uint64_t)p);
      uint32_t *in = field_new(&s), *want = field_new(&s), *got = field_new(&s);
      memcpy(in, s.in, field_bytes(&s));
      for (uint32_t pass = 0; pass < 2; pass++) {
        plain_pass_run(&s, in, ks[ki], 5, pass, want);
        for (int scalar = 0; scalar <= 1; scalar++) {
          ts_pm_job j = {s.tw, s.th, in, ks[ki], 5, pass, scalar};
          assert_int_equal(ts_pm_field_pass(&s.f, &j, NULL, 0, pool, got, err), 0);
          assert_memory_equal(got, want, field_bytes(&s));
        }
        memcpy(in, want, field_bytes(&s));
      }
      free(in);
      free(want);
      free(got);
      scene_free(&s);
    }
  ts_pool_destroy(pool);
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
    cmocka_unit_test(a_pass_follows_its_contract),
    cmocka_unit_test(a_pass_never_makes_a_match_worse),
    cmocka_unit_test(a_cut_of_the_source_is_found),
    cmocka_unit_test(occurrences_and_block_sums_match_loops),
    cmocka_unit_test(the_penalty_spreads_the_field),
    cmocka_unit_test(bad_fields_and_targets_are_refused),
};

TS_TEST_MAIN(tests)
