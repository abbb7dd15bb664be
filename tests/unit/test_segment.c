/* test_segment.c - texture segmentation (server/engines/segment.h): the
 * pieces after the search on small synthetic maps (regions, noise
 * reduction, level weights, fusion, accuracy counts), the checks, and a
 * whole single-level run against a brute-force 1-NN classifier. */
#include <stdlib.h>

#include "rng.h"
#include "segment.h"
#include "ts_test.h"

/* A map from rows of digits (the class of each pixel). */
static uint8_t *map_of(const char *const *rows, int w, int h) {
  uint8_t *m = malloc((size_t)w * (size_t)h);
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) m[y * w + x] = (uint8_t)(rows[y][x] - '0');
  return m;
}

static void assert_map(const uint8_t *m, const char *const *rows, int w, int h) {
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++)
      if (m[y * w + x] != rows[y][x] - '0') fail_msg("pixel (%d, %d) is %d, want %c", x, y, m[y * w + x], rows[y][x]);
}

/* ---- regions --------------------------------------------------------------- */

static void components_are_4_connected_in_raster_order(void **state) {
  (void)state;
  const char *rows[] = {
      "00110",
      "01100",
      "10001",
      "10221",
  };
  uint8_t *m = map_of(rows, 5, 4);
  uint32_t comp[20], n;
  assert_int_equal(ts_seg_components(m, 5, 4, comp, &n), 0);
  /* Numbered by first pixel: the 0s top-left (0), the 1s of the top rows
   * (1), the 0s from (4, 0) round to (1, 3) (2), the 1s of the left
   * column's foot (3), of the right one's (4), the 2s (5). */
  const uint32_t want[20] = {0, 0, 1, 1, 2,  /* */
                             0, 1, 1, 2, 2,  /* */
                             3, 2, 2, 2, 4,  /* */
                             3, 2, 5, 5, 4};
  for (int i = 0; i < 20; i++) assert_int_equal(comp[i], want[i]);
  assert_int_equal(n, 6);
  free(m);
}

/* Diagonal neighbours are not connected. */
static void components_ignore_diagonals(void **state) {
  (void)state;
  const char *rows[] = {"10", "01"};
  uint8_t *m = map_of(rows, 2, 2);
  uint32_t comp[4], n;
  assert_int_equal(ts_seg_components(m, 2, 2, comp, &n), 0);
  assert_int_equal(n, 4);
  free(m);
}

/* ---- noise reduction --------------------------------------------------------- */

static void denoise_removes_small_regions_only(void **state) {
  (void)state;
  const char *rows[] = {
      "0000000",
      "0110000",
      "0110000",
      "0000222",
      "0000222",
      "0000222",
  };
  uint8_t *m = map_of(rows, 7, 6);
  ts_seg_denoise_stats st;
  assert_int_equal(ts_seg_denoise(m, 7, 6, 4, &st), 0); /* the 2x2 blob has 4 pixels: stays */
  assert_map(m, rows, 7, 6);
  assert_int_equal(st.merged, 0);
  assert_int_equal(ts_seg_denoise(m, 7, 6, 5, &st), 0);
  const char *want[] = {
      "0000000",
      "0000000",
      "0000000",
      "0000222",
      "0000222",
      "0000222",
  };
  assert_map(m, want, 7, 6);
  assert_int_equal(st.merged, 1);
  assert_int_equal(st.passes, 1);
  free(m);
}

/* The border is counted in pixel edges; equal counts go to the lower
 * class. */
static void denoise_takes_the_majority_of_the_border_ties_low(void **state) {
  (void)state;
  const char *rows[] = {
      "3333",
      "3113",
      "2222",
  };
  uint8_t *m = map_of(rows, 4, 3);
  ts_seg_denoise_stats st;
  /* The 1s touch 3 by 4 edges (above 2, sides 2) and 2 by 2: they go to
   * 3. */
  assert_int_equal(ts_seg_denoise(m, 4, 3, 3, &st), 0);
  const char *want[] = {"3333", "3333", "2222"};
  assert_map(m, want, 4, 3);
  const char *tie[] = {"3113", "2222"};
  uint8_t *t = map_of(tie, 4, 2);
  /* The lone 3s (1 pixel each) go first: each touches 1 once and 2 once,
   * so each takes the lower class, 1. The 1s, their neighbour, wait, and
   * next pass are 4 pixels: no longer small. */
  assert_int_equal(ts_seg_denoise(t, 4, 2, 3, &st), 0);
  const char *want_tie[] = {"1111", "2222"};
  assert_map(t, want_tie, 4, 2);
  free(m);
  free(t);
}

/* Two small regions side by side: the smaller goes first, and its
 * neighbour waits for the next pass, where it is seen at its new size. */
static void denoise_sees_regions_as_they_are(void **state) {
  (void)state;
  const char *rows[] = {
      "000000",
      "011200",
      "011200",
      "000000",
  };
  uint8_t *m = map_of(rows, 6, 4);
  ts_seg_denoise_stats st;
  /* The 2s (2 pixels) go first: they touch 1 by 2 edges and 0 by 4, so
   * they become 0. The 1s (4 pixels) were their neighbour: next pass,
   * they become 0 too. */
  assert_int_equal(ts_seg_denoise(m, 6, 4, 5, &st), 0);
  const char *want[] = {"000000", "000000", "000000", "000000"};
  assert_map(m, want, 6, 4);
  assert_int_equal(st.merged, 2);
  assert_int_equal(st.passes, 2);
  /* Two small regions inside a large one, each the other's neighbour: */
  const char *grow[] = {
      "111111",
      "110011",
      "112211",
      "111111",
  };
  uint8_t *g = map_of(grow, 6, 4);
  /* The 0s (2) and the 2s (2) are small (min 4); the 0s are first in
   * raster order: they touch 1 by 4 edges and 2 by 2: 1. The 2s wait
   * (neighbours of a changed region), and next pass go to 1. */
  assert_int_equal(ts_seg_denoise(g, 6, 4, 4, &st), 0);
  const char *want_g[] = {"111111", "111111", "111111", "111111"};
  assert_map(g, want_g, 6, 4);
  assert_int_equal(st.passes, 2);
  free(m);
  free(g);
}

/* A region with no border (the whole image) stays, whatever its size. */
static void denoise_keeps_a_region_without_border(void **state) {
  (void)state;
  uint8_t m[6] = {4, 4, 4, 4, 4, 4};
  ts_seg_denoise_stats st;
  assert_int_equal(ts_seg_denoise(m, 3, 2, 100, &st), 0);
  for (int i = 0; i < 6; i++) assert_int_equal(m[i], 4);
  assert_int_equal(st.merged, 0);
}

/* A checkerboard is all small regions: they merge until none is small. */
static void denoise_ends_on_a_checkerboard(void **state) {
  (void)state;
  enum { W = 40, H = 30 };
  uint8_t *m = malloc(W * H);
  for (int i = 0; i < W * H; i++) m[i] = (uint8_t)(((i % W) + (i / W)) & 1);
  ts_seg_denoise_stats st;
  assert_int_equal(ts_seg_denoise(m, W, H, 10, &st), 0);
  uint32_t comp[W * H], n, size[W * H] = {0};
  assert_int_equal(ts_seg_components(m, W, H, comp, &n), 0);
  for (int i = 0; i < W * H; i++) size[comp[i]]++;
  for (uint32_t c = 0; c < n; c++) assert_true(n == 1 || size[c] >= 10);
  free(m);
}

/* ---- weights and fusion ------------------------------------------------------ */

static void weights_are_rates_normalised_over_levels(void **state) {
  (void)state;
  /* 3 levels x 2 classes (level-major). Class 0: rates 0.5, 0.25, 0.25;
   * class 1: no pixel at level 2, rates 0 and 0 at levels 0 and 1. */
  const uint64_t total[6] = {100, 10, 40, 10, 4, 0};
  const uint64_t correct[6] = {50, 0, 10, 0, 1, 0};
  double rate[6], weight[6];
  ts_seg_weights(3, 2, correct, total, rate, weight);
  assert_true(rate[0] == 0.5 && rate[2] == 0.25 && rate[4] == 0.25);
  assert_true(weight[0] == 0.5 && weight[2] == 0.25 && weight[4] == 0.25);
  assert_true(rate[1] == 0 && rate[3] == 0 && rate[5] == -1);
  /* Class 1 right nowhere: its levels weigh the same. */
  for (int l = 0; l < 3; l++) assert_true(weight[2 * l + 1] == 1.0 / 3);
}

static void nearest_rounds_to_the_level_pixel(void **state) {
  (void)state;
  /* Level-1 pixel x sits on level-0 pixel 2x: 0,1 -> 0 and 1 (round half
   * up), 2 -> 1, 3 -> 2 (clamped to a 2-pixel level: 1). */
  assert_int_equal(ts_seg_nearest(0, 1, 4), 0);
  assert_int_equal(ts_seg_nearest(1, 1, 4), 1);
  assert_int_equal(ts_seg_nearest(2, 1, 4), 1);
  assert_int_equal(ts_seg_nearest(3, 1, 4), 2);
  assert_int_equal(ts_seg_nearest(3, 1, 2), 1);
  assert_int_equal(ts_seg_nearest(5, 2, 8), 1);
  assert_int_equal(ts_seg_nearest(6, 2, 8), 2);
  assert_int_equal(ts_seg_nearest(7, 0, 8), 7);
}

static void fusion_is_the_weighted_vote(void **state) {
  (void)state;
  /* Level 0 (4x2) and level 1 (2x1). Weights level-major, 3 classes:
   * class 0 trusts level 1 (0.3 / 0.7), class 1 level 0 (0.8 / 0.2),
   * class 2 both alike (0.5 / 0.5). */
  const uint8_t l0[8] = {0, 1, 2, 2, 1, 1, 2, 0};
  const uint8_t l1[2] = {0, 2};
  const uint8_t *lab[2] = {l0, l1};
  const int lw[2] = {4, 2}, lh[2] = {2, 1};
  const double weight[6] = {0.3, 0.8, 0.5, 0.7, 0.2, 0.5};
  uint8_t out[8];
  ts_seg_fuse(2, 3, lab, lw, lh, weight, 4, 2, out);
  /* Pixel x takes level-1 pixel round(x / 2): 0, 1, 1, 2 -> clamped 1.
   *   (0,0): 0 vs 0           -> 0
   *   (1,0): 1 (0.8) vs 2 (0.5) -> 1
   *   (2,0): 2 vs 2           -> 2
   *   (3,0): 2 vs 2           -> 2
   *   (0,1): 1 (0.8) vs 0 (0.7) -> 1
   *   (1,1): 1 (0.8) vs 2 (0.5) -> 1
   *   (2,1): 2 vs 2           -> 2
   *   (3,1): 0 (0.3) vs 2 (0.5) -> 2 */
  const uint8_t want[8] = {0, 1, 2, 2, 1, 1, 2, 2};
  for (int i = 0; i < 8; i++) assert_int_equal(out[i], want[i]);
}

/* Equal scores go to the lower class. */
static void fusion_ties_go_to_the_lower_class(void **state) {
  (void)state;
  const uint8_t l0[1] = {2}, l1[1] = {1};
  const uint8_t *lab[2] = {l0, l1};
  const int lw[2] = {1, 1}, lh[2] = {1, 1};
  const double weight[6] = {0.5, 0.5, 0.5, 0.5, 0.5, 0.5};
  uint8_t out[1];
  ts_seg_fuse(2, 3, lab, lw, lh, weight, 1, 1, out);
  assert_int_equal(out[0], 1);
}

static void upsample_takes_the_nearest_pixel(void **state) {
  (void)state;
  const uint8_t l[4] = {1, 2, 3, 4}; /* 2x2 at level 1 */
  uint8_t out[12];
  ts_seg_upsample(l, 2, 2, 1, 4, 3, out);
  const uint8_t want[12] = {1, 2, 2, 2, 3, 4, 4, 4, 3, 4, 4, 4};
  for (int i = 0; i < 12; i++) assert_int_equal(out[i], want[i]);
}

static void count_tallies_per_truth_class(void **state) {
  (void)state;
  const uint8_t pred[6] = {0, 0, 1, 1, 2, 0}, truth[6] = {0, 1, 1, 1, 2, 2};
  uint64_t pixels[3] = {0}, correct[3] = {0};
  ts_seg_count(pred, truth, 6, pixels, correct);
  assert_int_equal(pixels[0], 1);
  assert_int_equal(pixels[1], 3);
  assert_int_equal(pixels[2], 2);
  assert_int_equal(correct[0], 1);
  assert_int_equal(correct[1], 2);
  assert_int_equal(correct[2], 1);
}

/* ---- checks -------------------------------------------------------------------- */

static const char *const kNames[] = {"--input in.png", "--train a.png", "--labels a-lbl.png", "--train b.png",
                                     "--labels b-lbl.png", "--truth t.png"};

static void header_check_lists_every_problem_with_its_file(void **state) {
  (void)state;
  ts_seg_params p;
  ts_seg_params_default(&p);
  p.pairs = 2;
  p.truth = 1;
  p.window = 8;
  ts_image_info info[6] = {
      {100, 100, 1, TS_PIX_U8},                    /* input */
      {64, 64, 1, TS_PIX_U8}, {80, 60, 1, TS_PIX_U8},  /* labels of another size */
      {20, 20, 1, TS_PIX_U8}, {20, 20, 3, TS_PIX_F32}, /* too small; colour, float labels */
      {100, 90, 1, TS_PIX_U8},                     /* truth of another size */
  };
  char msg[4096];
  assert_int_equal(ts_seg_check_headers(&p, info, kNames, msg, sizeof(msg)), TS_EINVAL);
  assert_non_null(strstr(msg, "--window 8"));
  assert_non_null(strstr(msg, "--labels a-lbl.png is 80x60, its training image --train a.png 64x64"));
  assert_non_null(strstr(msg, "--labels b-lbl.png has 3 channels"));
  assert_non_null(strstr(msg, "--labels b-lbl.png is float: a label raster holds whole numbers"));
  assert_non_null(strstr(msg, "--truth t.png is 100x90"));
  /* The window is bad, so the sizes against it are not judged. */
  assert_null(strstr(msg, "too small"));
  p.window = 9;
  info[4] = (ts_image_info){20, 20, 1, TS_PIX_U16};
  assert_int_equal(ts_seg_check_headers(&p, info, kNames, msg, sizeof(msg)), TS_EINVAL);
  /* 20x20 at level 3 of 3 is 5x5; 64x64's halves there are 8x16. */
  assert_non_null(strstr(msg, "--train b.png is 20x20: at level 3 of 3 it is 5x5, too small for a 9x9 window; "
                              "use at least 36x36"));
  assert_non_null(strstr(msg, "--train a.png is 64x64: at level 3 of 3 the halves its self-segmentation weighs "
                              "the levels with are 8x16, too small for a 9x9 window; use at least 72x36"));
  p.levels = 1;
  info[3] = (ts_image_info){9, 9, 1, TS_PIX_U8};
  info[4] = (ts_image_info){9, 9, 1, TS_PIX_U8};
  info[2] = (ts_image_info){64, 64, 1, TS_PIX_U8};
  info[5] = (ts_image_info){100, 100, 1, TS_PIX_U16};
  assert_int_equal(ts_seg_check_headers(&p, info, kNames, msg, sizeof(msg)), 0);
}

static void fill_u8(ts_image *img, int w, int h, int ch, uint8_t v) {
  char err[TS_ERR_LEN];
  assert_int_equal(ts_image_alloc(img, w, h, ch, TS_PIX_U8, err), 0);
  memset(img->pixels, v, (size_t)w * (size_t)h * (size_t)ch);
}

static void check_finds_truth_values_that_are_no_class(void **state) {
  (void)state;
  ts_seg_params p;
  ts_seg_params_default(&p);
  p.pairs = 2;
  p.truth = 1;
  p.levels = 1;
  ts_image img[6];
  fill_u8(&img[0], 20, 20, 1, 100);
  fill_u8(&img[1], 20, 20, 1, 50);
  fill_u8(&img[2], 20, 20, 1, 7);
  fill_u8(&img[3], 20, 20, 1, 60);
  fill_u8(&img[4], 20, 20, 1, 0);
  fill_u8(&img[5], 20, 20, 1, 7);
  ((uint8_t *)img[5].pixels)[10] = 9;
  ((uint8_t *)img[5].pixels)[11] = 250;
  const ts_image *in[6] = {&img[0], &img[1], &img[2], &img[3], &img[4], &img[5]};
  char msg[4096];
  assert_int_equal(ts_seg_check(&p, in, kNames, msg, sizeof(msg)), TS_EINVAL);
  assert_string_equal(msg, "--truth t.png holds 2 label values no --labels raster has (9, 250); the classes are 0, 7");
  ((uint8_t *)img[5].pixels)[10] = 0;
  ((uint8_t *)img[5].pixels)[11] = 7;
  assert_int_equal(ts_seg_check(&p, in, kNames, msg, sizeof(msg)), 0);
  ts_seg_classes c;
  ts_seg_classes_find(&p, in, &c);
  assert_int_equal(c.n, 2);
  assert_int_equal(c.value[0], 0);
  assert_int_equal(c.value[1], 7);
  assert_int_equal(c.wide, 0);
  for (int k = 0; k < 6; k++) ts_image_free(&img[k]);
}

/* ---- a whole run ------------------------------------------------------------------ */

/* A rectangle of a grey image and of its labels (lbl NULL: an input). */
typedef struct {
  const ts_image *img, *lbl;
  int x0, y0, w, h;
} region;

static region whole(const ts_image *img, const ts_image *lbl) { return (region){img, lbl, 0, 0, img->width, img->height}; }

/* Pixel (x, y) of a region, past its edges the edge pixel. */
static int at_clamped(const ts_image *img, const region *r, int x, int y) {
  x = x < 0 ? 0 : x >= r->w ? r->w - 1 : x;
  y = y < 0 ? 0 : y >= r->h ? r->h - 1 : y;
  return ((const uint8_t *)img->pixels)[(r->y0 + y) * img->width + r->x0 + x];
}

/* The 1-NN label of pixel (x, y) of q: its n x n window (q read past its
 * edges as the edge pixel) against every window inside every reference
 * region, in order, row-major; the first of the nearest wins. */
static int brute_label(const region *q, int x, int y, const region *refs, int nref, int n) {
  int r = n / 2, label = -1;
  long best = -1;
  for (int t = 0; t < nref; t++) {
    const region *f = &refs[t];
    for (int ay = 0; ay + n <= f->h; ay++)
      for (int ax = 0; ax + n <= f->w; ax++) {
        long d = 0;
        for (int j = 0; j < n; j++)
          for (int i = 0; i < n; i++)
            d += labs((long)at_clamped(q->img, q, x - r + i, y - r + j) - at_clamped(f->img, f, ax + i, ay + j));
        if (best < 0 || d < best) {
          best = d;
          label = at_clamped(f->lbl, f, ax + r, ay + r);
        }
      }
  }
  return label;
}

/* Input 0 and two training pairs of random 4-grey-level images (many
 * equal distances: the ties matter), labels changing inside the training
 * images (10 + column / 4 and 20 + column / 4). */
static void random_job(ts_image *img, const int (*size)[2]) {
  ts_rng rng;
  ts_rng_seed(&rng, 42, 0);
  for (int k = 0; k < 5; k++) {
    fill_u8(&img[k], size[k][0], size[k][1], 1, 0);
    uint8_t *px = img[k].pixels;
    for (int i = 0; i < size[k][0] * size[k][1]; i++)
      px[i] = k == 2 || k == 4 ? (uint8_t)(5 * k + (i % size[k][0]) / 4) : (uint8_t)(64 * ts_rng_below(&rng, 4));
  }
}

static void run_job(const ts_seg_params *p, const ts_image *const *in, ts_seg_result *res) {
  char err[TS_ERR_LEN], msg[4096];
  const char *names[5] = {"in", "a", "al", "b", "bl"};
  assert_int_equal(ts_seg_check(p, in, names, msg, sizeof(msg)), 0);
  ts_search *search;
  assert_int_equal(ts_search_local_create(&search, 3, NULL, err), 0);
  ts_search_local_set_inline(search, 0);
  if (ts_seg_run(p, in, search, NULL, res, err) != 0) fail_msg("%s", err);
  ts_search_destroy(search);
}

static void one_level_is_the_brute_force_1nn(void **state) {
  (void)state;
  ts_seg_params p;
  ts_seg_params_default(&p);
  p.pairs = 2;
  p.levels = 1;
  p.window = 3;
  const int size[5][2] = {{13, 11}, {10, 9}, {10, 9}, {12, 8}, {12, 8}};
  ts_image img[5];
  random_job(img, size);
  const ts_image *in[5] = {&img[0], &img[1], &img[2], &img[3], &img[4]};
  ts_seg_result res;
  run_job(&p, in, &res);
  assert_int_equal(res.labels.width, 13);
  assert_int_equal(res.labels.type, TS_PIX_U8);
  const uint8_t *got = res.labels.pixels;
  region q = whole(in[0], NULL), refs[2] = {whole(in[1], in[2]), whole(in[3], in[4])};
  for (int y = 0; y < 11; y++)
    for (int x = 0; x < 13; x++) assert_int_equal(got[y * 13 + x], brute_label(&q, x, y, refs, 2, 3));
  ts_seg_result_free(&res);
  for (int k = 0; k < 5; k++) ts_image_free(&img[k]);
}

static int class_of(const ts_seg_result *res, int value) {
  for (int k = 0; k < res->classes.n; k++)
    if (res->classes.value[k] == value) return k;
  fail_msg("label %d is no class", value);
  return -1;
}

/* At level 0 the self-segmentation's counts are those of the brute force:
 * each half of a training image (cut across its longer side) against the
 * other half, then the other training image. */
static void self_segmentation_is_the_brute_force_1nn(void **state) {
  (void)state;
  ts_seg_params p;
  ts_seg_params_default(&p);
  p.pairs = 2;
  p.levels = 2;
  p.window = 3;
  const int size[5][2] = {{9, 9}, {14, 10}, {14, 10}, {12, 16}, {12, 16}};
  ts_image img[5];
  random_job(img, size);
  const ts_image *in[5] = {&img[0], &img[1], &img[2], &img[3], &img[4]};
  ts_seg_result res;
  run_job(&p, in, &res);
  /* The halves: 14x10 cut into 7x10 twice; 12x16 into 12x8 twice. */
  const region half[2][2] = {{{in[1], in[2], 0, 0, 7, 10}, {in[1], in[2], 7, 0, 7, 10}},
                             {{in[3], in[4], 0, 0, 12, 8}, {in[3], in[4], 0, 8, 12, 8}}};
  uint64_t total[TS_SEG_MAX_CLASSES] = {0}, correct[TS_SEG_MAX_CLASSES] = {0};
  for (int t = 0; t < 2; t++)
    for (int s = 0; s < 2; s++) {
      const region *q = &half[t][s];
      region refs[2] = {half[t][1 - s], whole(in[3 - 2 * t], in[4 - 2 * t])};
      for (int y = 0; y < q->h; y++)
        for (int x = 0; x < q->w; x++) {
          int k = class_of(&res, at_clamped(q->lbl, q, x, y));
          total[k]++;
          correct[k] += class_of(&res, brute_label(q, x, y, refs, 2, 3)) == k;
        }
    }
  for (int k = 0; k < res.classes.n; k++) {
    assert_int_equal(res.self_total[k], total[k]);
    assert_int_equal(res.self_correct[k], correct[k]);
  }
  ts_seg_result_free(&res);
  for (int k = 0; k < 5; k++) ts_image_free(&img[k]);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(components_are_4_connected_in_raster_order),
    cmocka_unit_test(components_ignore_diagonals),
    cmocka_unit_test(denoise_removes_small_regions_only),
    cmocka_unit_test(denoise_takes_the_majority_of_the_border_ties_low),
    cmocka_unit_test(denoise_sees_regions_as_they_are),
    cmocka_unit_test(denoise_keeps_a_region_without_border),
    cmocka_unit_test(denoise_ends_on_a_checkerboard),
    cmocka_unit_test(weights_are_rates_normalised_over_levels),
    cmocka_unit_test(nearest_rounds_to_the_level_pixel),
    cmocka_unit_test(fusion_is_the_weighted_vote),
    cmocka_unit_test(fusion_ties_go_to_the_lower_class),
    cmocka_unit_test(upsample_takes_the_nearest_pixel),
    cmocka_unit_test(count_tallies_per_truth_class),
    cmocka_unit_test(header_check_lists_every_problem_with_its_file),
    cmocka_unit_test(check_finds_truth_values_that_are_no_class),
    cmocka_unit_test(one_level_is_the_brute_force_1nn),
    cmocka_unit_test(self_segmentation_is_the_brute_force_1nn),
};

TS_TEST_MAIN(tests)
