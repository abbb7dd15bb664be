/* test_repetition.c - the repetition score of a copy map
 * (server/engines/repetition.h): two large pieces from the same source
 * area repeat, from different areas or different references they do not;
 * pieces smaller than side x side never count; pixels without a source
 * are left out; a source outside its reference is refused. */
#include "ts_test.h"

#include "error.h"
#include "repetition.h"

enum { W = 64, H = 32 };

/* Left half from (lx, 0), right half from (rx, 0), each one piece. */
static void halves(uint32_t *copy, int lx, int rx) {
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) {
      int i = y * W + x;
      copy[2 * i] = (uint32_t)(x < W / 2 ? lx + x : rx + x - W / 2);
      copy[2 * i + 1] = (uint32_t)y;
    }
}

static void the_same_piece_twice_repeats(void **state) {
  (void)state;
  static uint32_t copy[2 * W * H];
  char err[TS_ERR_LEN];
  ts_repetition r;
  halves(copy, 0, 0);
  assert_int_equal(ts_repetition_score(copy, NULL, 1, W, H, 64, 32, 16, &r, err), 0);
  assert_int_equal(r.patches, 2);
  assert_int_equal(r.large_patches, 2);
  assert_int_equal(r.repeated, W * H);
  assert_true(r.share == 1.0);
  halves(copy, 0, 16); /* overlapping by half: the overlap repeats, twice */
  assert_int_equal(ts_repetition_score(copy, NULL, 1, W, H, 64, 32, 16, &r, err), 0);
  assert_int_equal(r.repeated, 2 * 16 * H);
  halves(copy, 0, 32); /* disjoint */
  assert_int_equal(ts_repetition_score(copy, NULL, 1, W, H, 64, 32, 16, &r, err), 0);
  assert_int_equal(r.repeated, 0);
  assert_int_equal(r.large, W * H);
}

static void other_references_and_small_pieces_do_not_count(void **state) {
  (void)state;
  static uint32_t copy[2 * W * H];
  static uint8_t id[W * H];
  char err[TS_ERR_LEN];
  ts_repetition r;
  halves(copy, 0, 0);
  for (int i = 0; i < W * H; i++) id[i] = (uint8_t)(i % W >= W / 2);
  assert_int_equal(ts_repetition_score(copy, id, 2, W, H, 64, 32, 16, &r, err), 0);
  assert_int_equal(r.repeated, 0);
  /* 8x8 blocks, every one from the same place: many repeats, none large. */
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) copy[2 * (y * W + x)] = (uint32_t)(x % 8), copy[2 * (y * W + x) + 1] = (uint32_t)(y % 8);
  assert_int_equal(ts_repetition_score(copy, NULL, 1, W, H, 64, 32, 16, &r, err), 0);
  assert_int_equal(r.patches, (W / 8) * (H / 8));
  assert_int_equal(r.large, 0);
  assert_true(r.share == 0.0);
  assert_int_equal(ts_repetition_score(copy, NULL, 1, W, H, 64, 32, 8, &r, err), 0);
  assert_true(r.share == 1.0);
  /* A pixel without a source is left out; one outside is refused. */
  copy[0] = UINT32_MAX;
  assert_int_equal(ts_repetition_score(copy, NULL, 1, W, H, 64, 32, 8, &r, err), 0);
  assert_int_equal(r.pixels, W * H - 1);
  copy[2] = 64;
  assert_int_equal(ts_repetition_score(copy, NULL, 1, W, H, 64, 32, 8, &r, err), TS_EINVAL);
  assert_non_null(strstr(err, "outside 64x32"));
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(the_same_piece_twice_repeats),
    cmocka_unit_test(other_references_and_small_pieces_do_not_count),
};

int main(void) { return cmocka_run_group_tests(tests, NULL, NULL); }
