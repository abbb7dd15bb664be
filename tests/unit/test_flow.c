/* test_flow.c - optical flow (common/flow.h): the warp moves an image by
 * its flow and undoes a known shift exactly; the forward-backward check
 * marks the pixels that leave the frame and those whose flows disagree,
 * and no others; the inverse of a shift is its negation, the uncovered
 * pixels marked; OpenCV's DIS flow (libtexsyn-flow.so) recovers a known
 * shift of a real photograph, gives the same bytes as when this test was
 * written, and refuses frames too small for it. */
#include "ts_test.h"

#include <math.h>
#include <sodium.h>

#include "error.h"
#include "flow.h"
#include "image.h"

/* A constant flow (u, v) over w x h pixels (the caller frees it). */
static float *constant_flow(int w, int h, float u, float v) {
  float *uv = malloc(sizeof(float) * 2 * (size_t)w * h);
  assert_non_null(uv);
  for (int i = 0; i < w * h; i++) uv[2 * i] = u, uv[2 * i + 1] = v;
  return uv;
}

static void warp_by_a_whole_shift_moves_every_inside_pixel(void **state) {
  (void)state;
  enum { W = 40, H = 30, C = 2 };
  float src[W * H * C], dst[W * H * C];
  for (int i = 0; i < W * H * C; i++) src[i] = (float)((i * 7919) % 251);
  float *uv = constant_flow(W, H, 3.0f, -2.0f);
  ts_flow_warp(src, W, H, C, uv, dst);
  for (int y = 2; y < H; y++)
    for (int x = 0; x < W - 3; x++)
      for (int c = 0; c < C; c++) assert_true(dst[(y * W + x) * C + c] == src[((y - 2) * W + x + 3) * C + c]);
  /* Outside, the edge repeats: (W-1, y) samples column W-1 of row y-2. */
  assert_true(dst[(5 * W + W - 1) * C] == src[(3 * W + W - 1) * C]);
  free(uv);
}

/* A linear ramp is what bilinear sampling reproduces exactly, so a
 * fractional shift is undone to the last bit but for rounding. */
static float ramp(float x, float y) { return 2.0f * x + 3.0f * y + 1.0f; }

static void warping_a_shifted_image_by_its_flow_gives_the_original(void **state) {
  (void)state;
  enum { W = 32, H = 24 };
  const float su = 1.5f, sv = 0.25f; /* B(x) = A(x - s): A's content moved by s */
  float a[W * H], b[W * H], back[W * H];
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) a[y * W + x] = ramp((float)x, (float)y), b[y * W + x] = ramp(x - su, y - sv);
  float *f = constant_flow(W, H, su, sv); /* the flow from A to B */
  ts_flow_warp(b, W, H, 1, f, back);
  for (int y = 0; y < H - 1; y++)
    for (int x = 0; x < W - 2; x++) assert_float_equal(back[y * W + x], a[y * W + x], 1e-4);
  free(f);
}

static void occlusion_marks_the_pixels_that_leave_the_frame(void **state) {
  (void)state;
  enum { W = 20, H = 10 };
  float *f = constant_flow(W, H, 3.0f, 0.0f), *b = constant_flow(W, H, -3.0f, 0.0f);
  uint8_t occ[W * H];
  assert_int_equal(ts_flow_occlusion(f, b, W, H, occ), 3 * H);
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) assert_int_equal(occ[y * W + x], x >= W - 3);
  free(f);
  free(b);
}

static void occlusion_marks_where_the_way_back_differs(void **state) {
  (void)state;
  enum { W = 20, H = 10 };
  float *f = constant_flow(W, H, 2.0f, 1.0f), *b = constant_flow(W, H, -2.0f, -1.0f);
  /* In B, a block the backward flow says stayed put: what lands there
   * from A does not come back (an occluder moved in front of it). */
  for (int y = 4; y < 8; y++)
    for (int x = 10; x < 15; x++) b[2 * (y * W + x)] = 0.0f, b[2 * (y * W + x) + 1] = 0.0f;
  uint8_t occ[W * H];
  size_t n = ts_flow_occlusion(f, b, W, H, occ);
  size_t expected = 0;
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) {
      int left = x + 2 > W - 1 || y + 1 > H - 1;
      /* Bilinear sampling at whole positions reads exactly one pixel. */
      int blocked = x + 2 >= 10 && x + 2 < 15 && y + 1 >= 4 && y + 1 < 8;
      assert_int_equal(occ[y * W + x], left || blocked);
      expected += (size_t)(left || blocked);
    }
  assert_int_equal(n, expected);
  free(f);
  free(b);
}

/* The DIS flow (into uv, 2 * 256 * 256 floats) between two 256x256 grey
 * frames cut from aero1.jpg, the second's window moved by (5, 3) pixels:
 * the content at (x, y) of the first is at (x - 5, y - 3) in the second. */
static void aero1_flow(float *uv) {
  static uint8_t a[256 * 256], b[256 * 256];
  char path[1024], err[TS_ERR_LEN];
  snprintf(path, sizeof(path), "%s/aerial/aero1.jpg", ts_test_data_dir());
  ts_image img = {0};
  if (ts_image_read(path, &img, NULL, err) != 0) fail_msg("%s", err);
  uint8_t *grey = malloc((size_t)img.width * img.height);
  assert_non_null(grey);
  ts_image_luma8(&img, grey);
  for (int y = 0; y < 256; y++) {
    memcpy(a + y * 256, grey + (size_t)(150 + y) * img.width + 200, 256);
    memcpy(b + y * 256, grey + (size_t)(153 + y) * img.width + 205, 256);
  }
  free(grey);
  ts_image_free(&img);
  if (ts_flow_dis(a, b, 256, 256, uv, err) != 0) fail_msg("%s", err);
}

static void dis_recovers_a_known_shift(void **state) {
  (void)state;
  static float uv[2 * 256 * 256];
  aero1_flow(uv);
  int near = 0, inside = 0;
  for (int y = 16; y < 240; y++)
    for (int x = 16; x < 240; x++, inside++) {
      const float *p = uv + 2 * (y * 256 + x);
      near += fabsf(p[0] + 5.0f) < 0.25f && fabsf(p[1] + 3.0f) < 0.25f;
    }
  assert_true(near > inside * 99 / 100);
}

/* The determinism promise: these bytes on any x86-64 machine with the
 * same OpenCV (Debian's 4.6.0). A change here changes every flicker score
 * and every video made; if it is meant, say why in the commit. */
static void dis_flow_bytes_are_pinned(void **state) {
  (void)state;
  static float uv[2 * 256 * 256];
  aero1_flow(uv);
  unsigned char digest[crypto_hash_sha256_BYTES];
  crypto_hash_sha256(digest, (const unsigned char *)uv, sizeof(uv));
  char hex[2 * crypto_hash_sha256_BYTES + 1];
  sodium_bin2hex(hex, sizeof(hex), digest, sizeof(digest));
  printf("flow sha256 %s by %s\n", hex, ts_flow_method());
  assert_string_equal(hex, "79b60f884cde0a9b52281297e870806cb7c0b3a4e43ea3d1425f99db12a07c71");
}

static void dis_refuses_frames_too_small(void **state) {
  (void)state;
  uint8_t a[31 * 40] = {0};
  float uv[2 * 31 * 40];
  char err[TS_ERR_LEN];
  assert_int_equal(ts_flow_dis(a, a, 31, 40, uv, err), TS_EINVAL);
  assert_string_equal(err, "optical flow needs frames of at least 32x32 pixels, not 31x40");
}

/* A fractional constant shift inverts to its negation wherever content
 * lands; the columns nothing lands on point out of the frame, so the check
 * marks exactly them occluded. */
static void invert_negates_a_shift_and_marks_the_uncovered_columns(void **state) {
  (void)state;
  enum { W = 24, H = 12 };
  float *f = constant_flow(W, H, 2.5f, 0.0f), *inv = constant_flow(W, H, 0, 0), *wt = constant_flow(W, H, 0, 0);
  uint8_t occ[W * H];
  ts_flow_invert(f, W, H, wt, inv);
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) {
      const float *p = inv + 2 * (y * W + x);
      if (x >= 3) assert_true(p[0] == -2.5f && p[1] == 0.0f); /* sources x - 2.5 +- 0.5 land here */
      else assert_true(x + p[0] < 0.0f);                       /* nothing lands on columns 0..2 */
    }
  assert_int_equal(ts_flow_occlusion(inv, f, W, H, occ), 3 * H);
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) assert_int_equal(occ[y * W + x], x < 3);
  free(f);
  free(inv);
  free(wt);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(invert_negates_a_shift_and_marks_the_uncovered_columns),
    cmocka_unit_test(warp_by_a_whole_shift_moves_every_inside_pixel),
    cmocka_unit_test(warping_a_shifted_image_by_its_flow_gives_the_original),
    cmocka_unit_test(occlusion_marks_the_pixels_that_leave_the_frame),
    cmocka_unit_test(occlusion_marks_where_the_way_back_differs),
    cmocka_unit_test(dis_recovers_a_known_shift),
    cmocka_unit_test(dis_flow_bytes_are_pinned),
    cmocka_unit_test(dis_refuses_frames_too_small),
};

TS_TEST_MAIN(tests)
