/* test_resample.c - area averaging (common/resample.h): halving takes the
 * mean of each 2x2 block, a fraction weighs partly covered pixels by their
 * overlap, types stay or become float, and a bad size is refused. */
#include "ts_test.h"

#include "error.h"
#include "image.h"
#include "resample.h"

static void fill_u8(ts_image *img, const uint8_t *v) {
  memcpy(img->pixels, v, (size_t)img->width * img->height * img->channels);
}

static void halving_takes_the_mean_of_each_block(void **state) {
  (void)state;
  ts_image in = {0}, out = {0};
  char err[TS_ERR_LEN];
  assert_int_equal(ts_image_alloc(&in, 4, 2, 1, TS_PIX_U8, err), 0);
  const uint8_t v[8] = {0, 4, 100, 101, 8, 12, 103, 103};
  fill_u8(&in, v);
  assert_int_equal(ts_image_resample(&in, 2, 1, &out, err), 0);
  assert_int_equal(out.type, TS_PIX_U8);
  const uint8_t *o = out.pixels;
  assert_int_equal(o[0], 6);   /* (0 + 4 + 8 + 12) / 4 */
  assert_int_equal(o[1], 102); /* 407 / 4 = 101.75 */
  ts_image_free(&in);
  ts_image_free(&out);
}

static void a_fraction_weighs_pixels_by_their_overlap(void **state) {
  (void)state;
  ts_image in = {0}, out = {0};
  char err[TS_ERR_LEN];
  assert_int_equal(ts_image_alloc(&in, 3, 1, 1, TS_PIX_F32, err), 0);
  float *p = in.pixels;
  p[0] = 0.0f, p[1] = 0.3f, p[2] = 0.9f;
  /* 3 -> 2: output 0 covers [0, 1.5): pixel 0 whole, half of pixel 1. */
  assert_int_equal(ts_image_resample(&in, 2, 1, &out, err), 0);
  const float *o = out.pixels;
  assert_float_equal(o[0], (0.0 + 0.5 * 0.3) / 1.5, 1e-6);
  assert_float_equal(o[1], (0.5 * 0.3 + 0.9) / 1.5, 1e-6);
  ts_image_free(&in);
  ts_image_free(&out);
}

static void channels_stay_apart_and_16_bit_stays(void **state) {
  (void)state;
  ts_image in = {0}, out = {0};
  char err[TS_ERR_LEN];
  assert_int_equal(ts_image_alloc(&in, 2, 2, 2, TS_PIX_U16, err), 0);
  uint16_t *p = in.pixels;
  const uint16_t second[4] = {60000, 60000, 60001, 60003};
  for (int i = 0; i < 4; i++) p[2 * i] = 1000, p[2 * i + 1] = second[i];
  assert_int_equal(ts_image_resample(&in, 1, 1, &out, err), 0);
  assert_int_equal(out.type, TS_PIX_U16);
  const uint16_t *o = out.pixels;
  assert_int_equal(o[0], 1000);
  assert_int_equal(o[1], 60001);
  ts_image_free(&in);
  ts_image_free(&out);
}

static void a_size_below_one_is_refused(void **state) {
  (void)state;
  ts_image in = {0}, out = {0};
  char err[TS_ERR_LEN];
  assert_int_equal(ts_image_alloc(&in, 2, 2, 1, TS_PIX_U8, err), 0);
  assert_int_equal(ts_image_resample(&in, 0, 1, &out, err), TS_EINVAL);
  assert_string_equal(err, "cannot resample to 0x1");
  assert_null(out.pixels);
  ts_image_free(&in);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(halving_takes_the_mean_of_each_block),
    cmocka_unit_test(a_fraction_weighs_pixels_by_their_overlap),
    cmocka_unit_test(channels_stay_apart_and_16_bit_stays),
    cmocka_unit_test(a_size_below_one_is_refused),
};

TS_TEST_MAIN(tests)
