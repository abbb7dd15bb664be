/* test_stylit_energy.c - the stylization's quality tools: the energy
 * against a brute-force scorer (plain loops over every source patch, the
 * weights worked out by hand), a copy of the exemplar covering all of
 * it, a wrong-sized image and a step of 0 refused; apply-nnf of a stylize run's NNF
 * over the style giving that run's output byte for byte. */
#include <math.h>

#include "error.h"
#include "image.h"
#include "rng.h"
#include "search.h"
#include "stylit.h"
#include "ts_test.h"

enum { SW = 17, SH = 13, TW = 11, TH = 9 };

/* A scene of the engine's order: RGB style, a grey guide (weight 0.5 by
 * default, 1 / 2 guides) and an RGB guide weighted 0.25, random 8-bit. */
typedef struct {
  ts_image img[5];
  const ts_image *in[5];
  ts_stylit_params p;
} scene;

static void random_image(ts_image *img, int w, int h, int ch, ts_rng *rng) {
  char err[TS_ERR_LEN];
  assert_int_equal(ts_image_alloc(img, w, h, ch, TS_PIX_U8, err), 0);
  uint8_t *px = img->pixels;
  for (size_t i = 0; i < (size_t)w * (size_t)h * (size_t)ch; i++) px[i] = (uint8_t)ts_rng_below(rng, 256);
}

static void scene_make(scene *s, int patch, uint64_t seed) {
  ts_rng rng;
  ts_rng_seed(&rng, seed, 0);
  random_image(&s->img[0], SW, SH, 3, &rng);
  random_image(&s->img[1], SW, SH, 1, &rng);
  random_image(&s->img[2], TW, TH, 1, &rng);
  random_image(&s->img[3], SW, SH, 3, &rng);
  random_image(&s->img[4], TW, TH, 3, &rng);
  for (int k = 0; k < 5; k++) s->in[k] = &s->img[k];
  ts_stylit_params_default(&s->p);
  s->p.patch = patch;
  s->p.guides = 2;
  s->p.weight[1] = 0.25;
  char msg[1024];
  assert_int_equal(ts_stylit_check(&s->p, s->in, msg, sizeof(msg)), 0);
}

static void scene_free(scene *s) {
  for (int k = 0; k < 5; k++) ts_image_free(&s->img[k]);
}

/* ---- the brute-force scorer -------------------------------------------- */

/* Per compared channel: its image, which input, and its weight in 1/840
 * (style 1 / 3 channels, grey guide 0.5 / 1, RGB guide 0.25 / 3). */
typedef struct {
  const ts_image *src, *tgt;
  int c;
  uint64_t w;
} channel;

static uint8_t px_at(const ts_image *img, int x, int y, int c) {
  x = x < 0 ? 0 : x >= img->width ? img->width - 1 : x;
  y = y < 0 ? 0 : y >= img->height ? img->height - 1 : y;
  return ((const uint8_t *)img->pixels)[((size_t)y * (size_t)img->width + (size_t)x) * (size_t)img->channels +
                                        (size_t)c];
}

static int channels_of(const scene *s, const ts_image *out, channel *ch) {
  int n = 0;
  for (int c = 0; c < 3; c++) ch[n++] = (channel){&s->img[0], out, c, 280};
  ch[n++] = (channel){&s->img[1], &s->img[2], 0, 420};
  for (int c = 0; c < 3; c++) ch[n++] = (channel){&s->img[3], &s->img[4], c, 70};
  return n;
}

/* The weighted L1 distance of the target patch centred at (tx, ty) (edge
 * pixels repeated) to the source patch with top-left corner (sx, sy). */
static uint64_t patch_dist(const channel *ch, int nch, int p, int tx, int ty, int sx, int sy) {
  uint64_t d = 0;
  for (int dy = 0; dy < p; dy++)
    for (int dx = 0; dx < p; dx++)
      for (int k = 0; k < nch; k++) {
        int a = px_at(ch[k].tgt, tx - p / 2 + dx, ty - p / 2 + dy, ch[k].c);
        int b = px_at(ch[k].src, sx + dx, sy + dy, ch[k].c);
        d += ch[k].w * (uint64_t)(a > b ? a - b : b - a);
      }
  return d;
}

static void brute_energy(const scene *s, const ts_image *out, int step, double *energy, double *coverage) {
  channel ch[8];
  int nch = channels_of(s, out, ch), p = s->p.patch;
  uint64_t unit = 0, sum = 0;
  for (int k = 0; k < nch; k++) unit += ch[k].w * (uint64_t)(p * p);
  uint8_t covered[SH][SW] = {{0}};
  int n = 0;
  for (int ty = 0; ty < out->height; ty += step)
    for (int tx = 0; tx < out->width; tx += step, n++) {
      uint64_t best = UINT64_MAX;
      int bx = 0, by = 0;
      for (int sy = 0; sy + p <= SH; sy++)
        for (int sx = 0; sx + p <= SW; sx++) {
          uint64_t d = patch_dist(ch, nch, p, tx, ty, sx, sy);
          if (d < best) best = d, bx = sx, by = sy;
        }
      sum += best;
      for (int y = by; y < by + p; y++)
        for (int x = bx; x < bx + p; x++) covered[y][x] = 1;
    }
  int used = 0;
  for (int y = 0; y < SH; y++)
    for (int x = 0; x < SW; x++) used += covered[y][x];
  *energy = (double)sum / n / (double)unit;
  *coverage = (double)used / (SW * SH);
}

/* ---- tests --------------------------------------------------------------- */

static void measure(const scene *s, const ts_image *out, int step, ts_stylit_energy *en) {
  char err[TS_ERR_LEN];
  ts_search *search;
  assert_int_equal(ts_search_local_create(&search, 2, NULL, err), 0);
  int rc = ts_stylit_energy_measure(&s->p, s->in, out, step, search, en, err);
  if (rc != 0) fail_msg("%s", err);
  ts_search_destroy(search);
}

static void energy_matches_brute_force(void **state) {
  (void)state;
  const int cases[][3] = {{3, 1, 1}, {3, 2, 2}, {5, 3, 3}, {5, 1, 4}}; /* patch, step, seed */
  for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
    scene s;
    scene_make(&s, cases[i][0], (uint64_t)cases[i][2]);
    ts_image out;
    ts_rng rng;
    ts_rng_seed(&rng, 99, (uint64_t)i);
    random_image(&out, TW, TH, 3, &rng);
    ts_stylit_energy en;
    measure(&s, &out, cases[i][1], &en);
    double e, cov;
    brute_energy(&s, &out, cases[i][1], &e, &cov);
    assert_int_equal(en.samples, ((TW + cases[i][1] - 1) / cases[i][1]) * ((TH + cases[i][1] - 1) / cases[i][1]));
    assert_true(fabs(en.energy - e) <= 1e-9 * e);
    assert_true(e > 0);
    assert_true(fabs(en.coverage - cov) < 1e-12);
    ts_image_free(&out);
    scene_free(&s);
  }
}

/* Target guides that are the source's and an image that is the style:
 * each inner target patch finds its own source patch (random pixels make
 * it the only one at distance 0), so every source pixel is covered; the
 * edge patches, which read repeated pixels, keep the energy above 0, as
 * the brute force says. */
static void a_copy_of_the_exemplar_covers_it_all(void **state) {
  (void)state;
  scene s;
  scene_make(&s, 3, 7);
  ts_image *tg[2] = {&s.img[2], &s.img[4]};
  const ts_image *sg[2] = {&s.img[1], &s.img[3]};
  char err[TS_ERR_LEN];
  for (int k = 0; k < 2; k++) {
    ts_image_free(tg[k]);
    assert_int_equal(ts_image_alloc(tg[k], SW, SH, sg[k]->channels, TS_PIX_U8, err), 0);
    memcpy(tg[k]->pixels, sg[k]->pixels, (size_t)SW * SH * (size_t)sg[k]->channels);
  }
  ts_stylit_energy en;
  measure(&s, &s.img[0], 1, &en);
  double e, cov;
  brute_energy(&s, &s.img[0], 1, &e, &cov);
  assert_true(en.coverage == 1.0);
  assert_true(cov == 1.0);
  assert_true(e > 0);
  assert_true(fabs(en.energy - e) <= 1e-9 * e);
  scene_free(&s);
}

static void an_image_of_the_wrong_size_is_refused(void **state) {
  (void)state;
  scene s;
  scene_make(&s, 3, 5);
  ts_image out;
  ts_rng rng;
  ts_rng_seed(&rng, 1, 0);
  random_image(&out, TW + 1, TH, 3, &rng);
  char err[TS_ERR_LEN];
  ts_search *search;
  assert_int_equal(ts_search_local_create(&search, 1, NULL, err), 0);
  ts_stylit_energy en;
  assert_int_equal(ts_stylit_energy_measure(&s.p, s.in, &out, 1, search, &en, err), TS_EINVAL);
  assert_non_null(strstr(err, "12x9"));
  assert_non_null(strstr(err, "11x9"));
  assert_int_equal(ts_stylit_energy_measure(&s.p, s.in, &s.img[4], 0, search, &en, err), TS_EINVAL);
  ts_search_destroy(search);
  ts_image_free(&out);
  scene_free(&s);
}

static void apply_nnf_of_a_run_gives_its_output(void **state) {
  (void)state;
  scene s;
  scene_make(&s, 3, 11);
  s.p.iters = 2;
  char err[TS_ERR_LEN];
  ts_search *search;
  assert_int_equal(ts_search_local_create(&search, 2, NULL, err), 0);
  ts_stylit_result res;
  assert_int_equal(ts_stylit_run(&s.p, s.in, search, NULL, &res, err), 0);
  ts_image out;
  assert_int_equal(ts_stylit_apply_nnf(res.nnf, TW, TH, 3, &s.img[0], &out, err), 0);
  assert_int_equal(out.channels, 3);
  assert_memory_equal(out.pixels, res.image.pixels, (size_t)TW * TH * 3);
  ts_image_free(&out);
  res.nnf[0] = SW - 1; /* not a patch centre */
  assert_int_equal(ts_stylit_apply_nnf(res.nnf, TW, TH, 3, &s.img[0], &out, err), TS_EINVAL);
  assert_non_null(strstr(err, "pixel (0, 0)"));
  ts_stylit_result_free(&res);
  ts_search_destroy(search);
  scene_free(&s);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(energy_matches_brute_force),
    cmocka_unit_test(a_copy_of_the_exemplar_covers_it_all),
    cmocka_unit_test(an_image_of_the_wrong_size_is_refused),
    cmocka_unit_test(apply_nnf_of_a_run_gives_its_output),
};

TS_TEST_MAIN(tests)
