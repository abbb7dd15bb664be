/* test_stylit_energy.c - the stylization's quality tools: the energy
 * against a brute-force scorer (plain loops over every source patch, the
 * weights worked out by hand), a copy of the exemplar covering all of
 * it, a wrong-sized image and a step of 0 refused; apply-nnf of a stylize run's NNF
 * over the style giving that run's output byte for byte; the error map of
 * a run against the brute-force distance of each pixel's patch to the
 * patch its NNF entry names, and never below the energy; the energy's JSON
 * line read back, and the energy engine giving the measure's line. */
#include <math.h>

#include "engine.h"
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

/* Each pixel's error is the brute-force distance of its patch in the
 * run's output to the source patch of its NNF entry, in grey levels; the
 * map's mean is at least the energy, the least such distance. */
static void error_map_is_each_patch_distance_to_its_nnf_patch(void **state) {
  (void)state;
  scene s;
  scene_make(&s, 3, 13);
  s.p.iters = 2;
  char err[TS_ERR_LEN];
  ts_search *search;
  assert_int_equal(ts_search_local_create(&search, 2, NULL, err), 0);
  ts_stylit_result res;
  assert_int_equal(ts_stylit_run(&s.p, s.in, search, NULL, &res, err), 0);
  float map[TW * TH];
  assert_int_equal(ts_stylit_error_map(&s.p, s.in, &res, map, err), 0);
  channel ch[8];
  int nch = channels_of(&s, &res.image, ch);
  uint64_t unit = 0;
  for (int k = 0; k < nch; k++) unit += ch[k].w * 9;
  double sum = 0;
  for (int y = 0; y < TH; y++)
    for (int x = 0; x < TW; x++) {
      const uint32_t *c = &res.nnf[2 * (y * TW + x)];
      uint64_t d = patch_dist(ch, nch, 3, x, y, (int)c[0] - 1, (int)c[1] - 1);
      assert_true(map[y * TW + x] == (float)((double)d / (double)unit));
      sum += map[y * TW + x];
    }
  ts_stylit_energy en;
  measure(&s, &res.image, 1, &en);
  assert_true(sum / (TW * TH) >= en.energy - 1e-9);
  assert_true(sum > 0);
  ts_stylit_result_free(&res);
  ts_search_destroy(search);
  scene_free(&s);
}

/* The JSON line reads back to the same values, and only that very line
 * is taken: cut anywhere, spaced otherwise, with a NUL, a value of another
 * type or anything after it, it is refused with a message. */
static void energy_json_reads_back_only_its_own_line(void **state) {
  (void)state;
  ts_stylit_energy e = {6.587873, 0.836589, 768, 2, 5}, back;
  char line[256], err[TS_ERR_LEN];
  int n = ts_stylit_energy_json(&e, line, sizeof(line));
  assert_string_equal(line, "{\"energy\": 6.587873, \"coverage\": 0.836589, \"coverage_of\": \"exemplar pixels\", "
                            "\"samples\": 768, \"step\": 2, \"patch_size\": 5}\n");
  assert_int_equal(ts_stylit_energy_json_read(line, (size_t)n, &back, err), 0);
  assert_true(back.energy == e.energy && back.coverage == e.coverage);
  assert_true(back.samples == 768 && back.step == 2 && back.patch == 5);
  for (int cut = 0; cut < n; cut++) {
    err[0] = '\0';
    assert_int_equal(ts_stylit_energy_json_read(line, (size_t)cut, &back, err), TS_EFORMAT);
    assert_non_null(strstr(err, "energy engine"));
  }
  const char *bad[] = {
      "{\"energy\":6.587873, \"coverage\": 0.836589, \"coverage_of\": \"exemplar pixels\", \"samples\": 768, "
      "\"step\": 2, \"patch_size\": 5}\n",
      "{\"energy\": 6.5878730, \"coverage\": 0.836589, \"coverage_of\": \"exemplar pixels\", \"samples\": 768, "
      "\"step\": 2, \"patch_size\": 5}\n",
      "{\"energy\": 6.587873, \"coverage\": 0.836589, \"coverage_of\": \"exemplar pixels\", \"samples\": -768, "
      "\"step\": 2, \"patch_size\": 5}\n",
      "{\"energy\": nan, \"coverage\": 0.836589, \"coverage_of\": \"exemplar pixels\", \"samples\": 768, "
      "\"step\": 2, \"patch_size\": 5}\n",
      "{\"energy\": 6.587873, \"coverage\": 0.836589, \"coverage_of\": \"exemplar pixels\", \"samples\": 768, "
      "\"step\": 2, \"patch_size\": 5}\n{}",
  };
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++)
    assert_int_equal(ts_stylit_energy_json_read(bad[i], strlen(bad[i]), &back, err), TS_EFORMAT);
  line[10] = '\0';
  assert_int_equal(ts_stylit_energy_json_read(line, (size_t)n, &back, err), TS_EFORMAT);
}

/* The energy engine (engine.h) on the scene: its inputs are the scene's
 * and "image"; its check lists the image's problem with the scene's, one
 * per line; its result file is the JSON line of the measure itself. */
static void energy_engine_measures_and_lists_every_problem(void **state) {
  (void)state;
  const ts_engine *e = ts_engine_find("energy");
  assert_non_null(e);
  scene s;
  scene_make(&s, 3, 13);
  ts_image img;
  ts_rng rng;
  ts_rng_seed(&rng, 3, 0);
  random_image(&img, TW, TH, 3, &rng);
  ts_engine_params params;
  e->params_default(&params);
  ts_stylit_energy_params *p = (ts_stylit_energy_params *)params.bytes;
  p->scene = s.p;
  p->step = 2;
  ts_engine_inputs names;
  e->inputs(&params, &names);
  assert_int_equal(names.n, 6);
  assert_string_equal(names.name[0], "style");
  assert_string_equal(names.name[3], "guide_src_1");
  assert_string_equal(names.name[5], "image");
  const ts_image *in[6] = {s.in[0], s.in[1], s.in[2], s.in[3], s.in[4], &img};
  char msg[2048], err[TS_ERR_LEN];
  assert_int_equal(e->check(&params, in, msg, sizeof(msg)), 0);

  ts_search *search;
  assert_int_equal(ts_search_local_create(&search, 2, NULL, err), 0);
  ts_engine_hooks hooks = {0};
  ts_engine_run *run = NULL;
  assert_int_equal(e->run(&params, in, search, &hooks, &run, err), 0);
  char path[32];
  ts_test_put_file(path, "", 0);
  assert_int_equal(e->write_output(run, 0, path, 2, err), 0);
  e->run_free(run);
  char got[256] = "", want[256];
  FILE *f = fopen(path, "r");
  assert_non_null(f);
  assert_non_null(fgets(got, sizeof(got), f));
  fclose(f);
  unlink(path);
  ts_stylit_energy en;
  measure(&s, &img, 2, &en);
  assert_true(ts_stylit_energy_json(&en, want, sizeof(want)) > 0);
  assert_string_equal(got, want);
  assert_int_equal(en.step, 2);
  assert_int_equal(en.patch, 3);

  /* A guide source of the wrong size and an image of the wrong size and
   * channels: both, one per line. */
  ts_image small, grey;
  random_image(&small, SW - 1, SH, 3, &rng);
  random_image(&grey, TW, TH + 1, 1, &rng);
  in[3] = &small;
  in[5] = &grey;
  assert_int_equal(e->check(&params, in, msg, sizeof(msg)), TS_EINVAL);
  assert_non_null(strstr(msg, "guide 2: its source is 16x13, the style 17x13"));
  assert_non_null(strstr(msg, "\n--image is 11x10 with 1 channel; it must have the target guides' size 11x9"));
  p->step = 0;
  in[3] = s.in[3];
  in[5] = &img;
  assert_int_equal(e->check(&params, in, msg, sizeof(msg)), TS_EINVAL);
  assert_string_equal(msg, "--sample 0: need a step of 1..65536 pixels");
  ts_image_free(&small);
  ts_image_free(&grey);
  ts_search_destroy(search);
  ts_image_free(&img);
  scene_free(&s);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(energy_matches_brute_force),
    cmocka_unit_test(a_copy_of_the_exemplar_covers_it_all),
    cmocka_unit_test(an_image_of_the_wrong_size_is_refused),
    cmocka_unit_test(apply_nnf_of_a_run_gives_its_output),
    cmocka_unit_test(error_map_is_each_patch_distance_to_its_nnf_patch),
    cmocka_unit_test(energy_json_reads_back_only_its_own_line),
    cmocka_unit_test(energy_engine_measures_and_lists_every_problem),
};

TS_TEST_MAIN(tests)
