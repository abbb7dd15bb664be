/* test_pyramid.c - Gaussian reduction (seed 002 eqs. 2.1-2.3), RNG. */
#include <stdlib.h>

#include "plane.h"
#include "rng.h"
#include "ts_test.h"

static void reduce_constant_stays_constant(void **state) {
  (void)state;
  ts_plane a, b;
  assert_int_equal(ts_plane_alloc(&a, 9, 6), 0);
  memset(a.px, 77, 54);
  assert_int_equal(ts_plane_reduce(&a, &b), 0);
  assert_int_equal(b.w, 4); /* odd column lost, as in the seed */
  assert_int_equal(b.h, 3);
  for (int i = 0; i < 12; i++) assert_int_equal(b.px[i], 77);
  ts_plane_free(&a);
  ts_plane_free(&b);
}

/* Hand-computed: one bright pixel (200) at (4, 4) of a 10x10 plane reaches
 * each coarse pixel with the product of its two taps / 400. */
static void reduce_impulse_matches_kernel(void **state) {
  (void)state;
  ts_plane a, b;
  assert_int_equal(ts_plane_alloc(&a, 10, 10), 0);
  a.px[4 * 10 + 4] = 200;
  assert_int_equal(ts_plane_reduce(&a, &b), 0);
  /* coarse (2,2) samples fine (4,4) with tap 8*8/400 */
  assert_int_equal(b.px[2 * 5 + 2], (200 * 64 + 200) / 400);
  /* coarse (1,2): fine x = 2 + i, i = 2 -> tap 1; y tap 8 -> 200*8/400 = 4 */
  assert_int_equal(b.px[2 * 5 + 1], (200 * 8 + 200) / 400);
  /* coarse (1,1): taps 1*1 -> 0.5 rounds to 1 */
  assert_int_equal(b.px[1 * 5 + 1], (200 * 1 + 200) / 400);
  assert_int_equal(b.px[0], 0);
  ts_plane_free(&a);
  ts_plane_free(&b);
}

static void reduce_mirrors_borders(void **state) {
  (void)state;
  ts_plane a, b;
  assert_int_equal(ts_plane_alloc(&a, 4, 4), 0);
  for (int i = 0; i < 16; i++) a.px[i] = (uint8_t)(i % 4 == 0 ? 100 : 0);
  assert_int_equal(ts_plane_reduce(&a, &b), 0);
  /* coarse (0,y): taps at x=-2,-1,0,1,2 -> mirrored 2,1,0,1,2: only x=0
   * is bright, weight 8/20 -> 40 */
  assert_int_equal(b.px[0], 40);
  assert_int_equal(b.px[2], 40);
  ts_plane_free(&a);
  ts_plane_free(&b);
}

static void pyramid_levels_halve(void **state) {
  (void)state;
  ts_plane base, lv[5];
  assert_int_equal(ts_plane_alloc(&base, 64, 40), 0);
  for (int i = 0; i < 64 * 40; i++) base.px[i] = (uint8_t)(i * 7);
  assert_int_equal(ts_pyramid_build(&base, 5, lv), 0);
  int w = 64, h = 40;
  for (int l = 0; l < 5; l++) {
    assert_int_equal(lv[l].w, w);
    assert_int_equal(lv[l].h, h);
    w /= 2;
    h /= 2;
  }
  assert_memory_equal(lv[0].px, base.px, 64 * 40);
  ts_pyramid_free(lv, 5);
  ts_plane_free(&base);
}

static void pyramid_too_small_fails(void **state) {
  (void)state;
  ts_plane base, lv[4];
  assert_int_equal(ts_plane_alloc(&base, 4, 4), 0);
  assert_int_not_equal(ts_pyramid_build(&base, 4, lv), 0);
  ts_plane_free(&base);
}

static void rng_is_deterministic_and_unbiased(void **state) {
  (void)state;
  ts_rng a, b, c;
  ts_rng_seed(&a, 42, 0);
  ts_rng_seed(&b, 42, 0);
  ts_rng_seed(&c, 42, 1);
  int same = 1, diff = 0;
  for (int i = 0; i < 100; i++) {
    uint64_t x = ts_rng_next(&a), y = ts_rng_next(&b), z = ts_rng_next(&c);
    same &= x == y;
    diff += x != z;
  }
  assert_true(same);
  assert_true(diff > 90);
  int hist[6] = {0};
  for (int i = 0; i < 60000; i++) hist[ts_rng_below(&a, 6)]++;
  for (int k = 0; k < 6; k++) assert_true(hist[k] > 9500 && hist[k] < 10500);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(reduce_constant_stays_constant),
    cmocka_unit_test(reduce_impulse_matches_kernel),
    cmocka_unit_test(reduce_mirrors_borders),
    cmocka_unit_test(pyramid_levels_halve),
    cmocka_unit_test(pyramid_too_small_fails),
    cmocka_unit_test(rng_is_deterministic_and_unbiased),
};

TS_TEST_MAIN(tests)
