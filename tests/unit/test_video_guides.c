/* test_video_guides.c - the guides of video stylization
 * (server/engines/video_guides.h): the edge guide is 0 on a flat frame and
 * peaks on a step, symmetric about it; the positional guide of the key is
 * each pixel's own place, carried along a flow it follows the content, and
 * where occluded it starts again from the pixel's own place; its planes
 * span 0..255 over the key. */
#include "ts_test.h"

#include "flow.h"
#include "video_guides.h"

enum { W = 24, H = 16 };

static void a_flat_frame_has_no_edges(void **state) {
  (void)state;
  uint8_t luma[W * H], edges[W * H];
  memset(luma, 77, sizeof(luma));
  assert_int_equal(ts_guide_edges(luma, W, H, edges), 0);
  for (int i = 0; i < W * H; i++) assert_int_equal(edges[i], 0);
}

static void a_step_peaks_on_its_edge_and_fades_away(void **state) {
  (void)state;
  uint8_t luma[W * H], edges[W * H];
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) luma[y * W + x] = x < 12 ? 0 : 255;
  assert_int_equal(ts_guide_edges(luma, W, H, edges), 0);
  /* Sobel: |gx| = 4 * 255 on columns 11 and 12, /8 -> 128; the binomial
   * blur across spreads it: (4 + 6) * 128 / 16 = 80 on those columns. */
  for (int y = 0; y < H; y++) {
    const uint8_t *r = edges + y * W;
    assert_int_equal(r[11], 80);
    assert_int_equal(r[12], 80);
    assert_int_equal(r[10], 40); /* (1 + 4) * 128 / 16 */
    assert_int_equal(r[13], 40);
    assert_int_equal(r[9], 8); /* 1 * 128 / 16 */
    for (int x = 0; x < 9; x++) assert_int_equal(r[x], 0);
    for (int x = 15; x < W; x++) assert_int_equal(r[x], 0);
  }
}

static void the_key_position_is_each_pixels_own_place(void **state) {
  (void)state;
  float pos[2 * W * H];
  ts_guide_position_key(W, H, pos);
  assert_true(pos[2 * (5 * W + 7)] == 7.0f && pos[2 * (5 * W + 7) + 1] == 5.0f);
  uint8_t px[W * H], py[W * H];
  ts_guide_position_planes(pos, W, H, px, py);
  assert_int_equal(px[0], 0);
  assert_int_equal(py[0], 0);
  assert_int_equal(px[W * H - 1], 255);
  assert_int_equal(py[W * H - 1], 255);
  assert_int_equal(px[5 * W + 7], 78); /* 7 * 255 / 23 = 77.6 */
}

static void the_position_follows_the_content_and_restarts_where_occluded(void **state) {
  (void)state;
  /* The content moves 2 pixels right a frame: pixel x of the new frame was
   * at x - 2; the 2 columns on the left came in from outside. */
  float key[2 * W * H], pos[2 * W * H], back[2 * W * H], fwd[2 * W * H];
  for (int i = 0; i < W * H; i++) back[2 * i] = -2.0f, back[2 * i + 1] = 0.0f, fwd[2 * i] = 2.0f, fwd[2 * i + 1] = 0.0f;
  uint8_t occluded[W * H];
  assert_int_equal(ts_flow_occlusion(back, fwd, W, H, occluded), 2 * H);
  ts_guide_position_key(W, H, key);
  ts_guide_position_advect(key, back, occluded, W, H, pos);
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) {
      assert_true(pos[2 * (y * W + x)] == (x < 2 ? (float)x : (float)(x - 2)));
      assert_true(pos[2 * (y * W + x) + 1] == (float)y);
    }
}

/* The pair against the key's painting and its complement: twice the
 * single guide's distance where visible, the same 255 for every source
 * value where occluded (so the search's choice ignores it there). */
static void the_temporal_pair_weighs_the_guide_out_where_occluded(void **state) {
  (void)state;
  float warped[2 * 3] = {-4.0f, 17.4f, 128.5f, 254.6f, 300.0f, 9.0f};
  uint8_t occluded[2] = {0, 1}, a[6], b[6];
  ts_guide_temporal_pair(warped, occluded, 2, 3, a, b);
  static const uint8_t va[6] = {0, 17, 129, 0, 0, 0}, vb[6] = {255, 238, 126, 0, 0, 0};
  assert_memory_equal(a, va, 6);
  assert_memory_equal(b, vb, 6);
  uint8_t s[256], sc[256];
  for (int v = 0; v < 256; v++) s[v] = (uint8_t)v;
  ts_guide_complement(s, 256, sc);
  for (int v = 0; v < 256; v++) {
    assert_int_equal(sc[v], 255 - v);
    for (int k = 0; k < 6; k++) {
      int pair = abs(s[v] - a[k]) + abs(sc[v] - b[k]);
      assert_int_equal(pair, k < 3 ? 2 * abs(v - a[k]) : 255);
    }
  }
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(a_flat_frame_has_no_edges),
    cmocka_unit_test(a_step_peaks_on_its_edge_and_fades_away),
    cmocka_unit_test(the_key_position_is_each_pixels_own_place),
    cmocka_unit_test(the_position_follows_the_content_and_restarts_where_occluded),
    cmocka_unit_test(the_temporal_pair_weighs_the_guide_out_where_occluded),
};

TS_TEST_MAIN(tests)
