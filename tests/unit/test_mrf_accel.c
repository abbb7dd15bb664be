/* test_mrf_accel.c - the copy-map shortcut's candidate detection
 * (mrf_accel.h) on hand-made copy maps: coherent regions give candidates,
 * the kernel keeps a buffer to transitions, clamped or broken predictions
 * and sources of another parity are refused, enabling keeps a sample
 * measured, and constancy counts what kept its source. */
#include <stdlib.h>

#include "anchors.h"
#include "error.h"
#include "mrf_accel.h"
#include "neigh.h"
#include "ts_test.h"

/* A pw x ph copy map whose columns x < split copy from offset (ax, ay)
 * and the others from (bx, by). */
static uint32_t *two_regions(int pw, int ph, int split, int ax, int ay, int bx, int by) {
  uint32_t *m = malloc(sizeof(uint32_t) * 2 * (size_t)pw * (size_t)ph);
  for (int y = 0; y < ph; y++)
    for (int x = 0; x < pw; x++) {
      size_t o = (size_t)y * (size_t)pw + (size_t)x;
      m[2 * o] = (uint32_t)(x + (x < split ? ax : bx));
      m[2 * o + 1] = (uint32_t)(y + (x < split ? ay : by));
    }
  return m;
}

/* The anchors of a w x h reference level (7x7 window, W_B 3, coarse part
 * one level up), with or without parity classes. */
typedef struct {
  ts_window win;
  ts_anchors grid;
  ts_plane labels;
} level_ref;

static void level_ref_init(level_ref *r, int w, int h, int parity) {
  char err[TS_ERR_LEN];
  assert_int_equal(ts_neigh_window(&r->win, TS_SHAPE_CAUSAL, 7, 3, 1, 1, 1.0, err), 0);
  assert_int_equal(ts_plane_alloc(&r->labels, w, h), 0);
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) r->labels.px[(size_t)y * (size_t)w + (size_t)x] = (uint8_t)((x & 1) | (y & 1) << 1);
  assert_int_equal(ts_anchors_init(&r->grid, &r->win, w, h, w / 2, h / 2, parity ? &r->labels : NULL,
                                   parity ? 4 : 1, NULL, err),
                   0);
}

static void level_ref_free(level_ref *r) {
  ts_anchors_free(&r->grid);
  ts_window_free(&r->win);
  ts_plane_free(&r->labels);
}

/* One offset everywhere: with a 1x1 kernel every block is a candidate
 * (its sources, position + twice the offset, all lie inside the 96x96
 * reference), predicted at position + twice the offset. A 5x5 kernel also
 * leaves out the blocks within its reach of the torus seam, where the
 * source does not wrap with the canvas. */
static void uniform_map_makes_every_valid_block_a_candidate(void **state) {
  (void)state;
  level_ref r;
  level_ref_init(&r, 96, 96, 0);
  uint32_t *prev = two_regions(16, 16, 16, 5, 7, 0, 0);
  ts_accel_map m;
  assert_int_equal(ts_accel_map_build(&m, prev, 16, 16, 32, 32, 3, 1, 96, 96, &r.grid, 0), 0);
  assert_int_equal(m.rows, 11);
  assert_int_equal(m.cols, 11);
  assert_int_equal(m.candidates, 121);
  int sx, sy;
  assert_true(ts_accel_block(&m, 6, 3, TS_ACCEL_MEASURE, &sx, &sy));
  assert_int_equal(sx, 6 + 10);
  assert_int_equal(sy, 3 + 14);
  assert_false(ts_accel_block(&m, 6, 3, TS_ACCEL_COPY, &sx, &sy));
  ts_accel_map_free(&m);
  /* Coherent coarse pixels: 2..13 each way; the blocks over them start at
   * 6, 9, ..., 24: 7 x 7. */
  assert_int_equal(ts_accel_map_build(&m, prev, 16, 16, 32, 32, 3, 5, 96, 96, &r.grid, 0), 0);
  assert_int_equal(m.candidates, 49);
  ts_accel_map_free(&m);
  free(prev);
  level_ref_free(&r);
}

/* Two regions side by side: blocks within the kernel's reach of the
 * border are left to the search; a wider kernel leaves a wider band. */
static void kernel_keeps_a_buffer_to_transitions(void **state) {
  (void)state;
  level_ref r;
  level_ref_init(&r, 128, 128, 0);
  /* Coarse columns 0..7 from offset (4, 4), 8..15 from (20, 6): on the
   * torus the map also breaks between column 15 and column 0. */
  uint32_t *prev = two_regions(16, 16, 8, 4, 4, 20, 6);
  uint32_t count[3];
  for (int i = 0; i < 3; i++) {
    int n = 2 * i + 1;
    ts_accel_map m;
    assert_int_equal(ts_accel_map_build(&m, prev, 16, 16, 32, 32, 3, n, 128, 128, &r.grid, 0), 0);
    count[i] = m.candidates;
    int sx, sy;
    /* Fine columns 15..17 straddle the border (coarse 7 | 8): never. */
    assert_false(ts_accel_block(&m, 15, 15, TS_ACCEL_MEASURE, &sx, &sy));
    /* Fine column 6 (coarse 3): deep inside the left region for n <= 5. */
    assert_true(ts_accel_block(&m, 6, 15, TS_ACCEL_MEASURE, &sx, &sy));
    assert_int_equal(sx, 6 + 8);
    /* Fine column 12 (coarse 6..7) lies next to the border: n = 1 only. */
    assert_int_equal(ts_accel_block(&m, 12, 15, TS_ACCEL_MEASURE, &sx, &sy), n == 1);
    ts_accel_map_free(&m);
  }
  assert_true(count[0] > count[1] && count[1] > count[2] && count[2] > 0);
  free(prev);
  level_ref_free(&r);
}

/* A prediction clamped at the reference's edge is no block copy, and a
 * source whose window leaves the reference is no vector. */
static void sources_outside_the_reference_are_refused(void **state) {
  (void)state;
  level_ref r;
  level_ref_init(&r, 40, 40, 0);
  /* Offset 10: sources x + 20 of a 32-wide level reach 51 > 39. */
  uint32_t *prev = two_regions(16, 16, 16, 10, 0, 0, 0);
  ts_accel_map m;
  assert_int_equal(ts_accel_map_build(&m, prev, 16, 16, 32, 32, 3, 1, 40, 40, &r.grid, 0), 0);
  int sx, sy;
  assert_true(ts_accel_block(&m, 0, 6, TS_ACCEL_MEASURE, &sx, &sy)); /* source 20..22: inside */
  assert_false(ts_accel_block(&m, 18, 6, TS_ACCEL_MEASURE, &sx, &sy)); /* source 38: window beyond 39 */
  assert_false(ts_accel_block(&m, 30, 6, TS_ACCEL_MEASURE, &sx, &sy)); /* clamped to 39 */
  ts_accel_map_free(&m);
  free(prev);
  level_ref_free(&r);
}

/* With parity control a block copies only a source of its own parity, on
 * even- and odd-sized levels alike. */
static void parity_must_match(void **state) {
  (void)state;
  level_ref r;
  level_ref_init(&r, 96, 96, 1);
  uint32_t *prev = two_regions(16, 16, 16, 5, 5, 0, 0);
  ts_accel_map m;
  assert_int_equal(ts_accel_map_build(&m, prev, 16, 16, 32, 32, 3, 3, 96, 96, &r.grid, 1), 0);
  assert_true(m.candidates > 0); /* even offsets (2 x 5): same parity */
  ts_accel_map_free(&m);
  /* A 31-wide level of a 16-wide one: coarse x = x * 16 / 31. */
  assert_int_equal(ts_accel_map_build(&m, prev, 16, 16, 31, 31, 3, 3, 96, 96, &r.grid, 1), 0);
  for (int by = 0; by < 31; by += 3)
    for (int bx = 0; bx < 31; bx += 3) {
      int sx, sy;
      if (ts_accel_block(&m, bx, by, TS_ACCEL_MEASURE, &sx, &sy)) {
        assert_int_equal(sx & 1, bx & 1);
        assert_int_equal(sy & 1, by & 1);
      }
    }
  ts_accel_map_free(&m);
  free(prev);
  level_ref_free(&r);
}

/* Enabling copies all but every `every`-th candidate; constancy counts
 * the measured ones whose top-left pixel holds the predicted source. */
static void enable_keeps_a_sample_and_constancy_counts_it(void **state) {
  (void)state;
  level_ref r;
  level_ref_init(&r, 96, 96, 0);
  uint32_t *prev = two_regions(16, 16, 16, 5, 7, 0, 0);
  ts_accel_map m;
  assert_int_equal(ts_accel_map_build(&m, prev, 16, 16, 32, 32, 3, 1, 96, 96, &r.grid, 0), 0);
  uint32_t *copy = calloc(2 * 32 * 32, sizeof(uint32_t));
  for (int y = 0; y < 32; y++)
    for (int x = 0; x < 32; x++) {
      copy[2 * (y * 32 + x)] = (uint32_t)(x + 10);
      copy[2 * (y * 32 + x) + 1] = (uint32_t)(y + 14);
    }
  copy[2 * (3 * 32 + 3)] = 0; /* block (3, 3) moved */
  uint64_t measured, kept;
  ts_accel_constancy(&m, copy, 32, &measured, &kept);
  assert_int_equal(measured, 121);
  assert_int_equal(kept, 120);
  ts_accel_map_enable(&m, 8);
  int copied = 0, sampled = 0, sx, sy;
  for (int by = 0; by < 32; by += 3)
    for (int bx = 0; bx < 32; bx += 3) {
      copied += ts_accel_block(&m, bx, by, TS_ACCEL_COPY, &sx, &sy);
      sampled += ts_accel_block(&m, bx, by, TS_ACCEL_MEASURE, &sx, &sy);
    }
  assert_int_equal(sampled, 16); /* candidates 0, 8, ..., 120 */
  assert_int_equal(copied, 121 - 16);
  assert_true(ts_accel_block(&m, 0, 0, TS_ACCEL_MEASURE, &sx, &sy));
  ts_accel_constancy(&m, copy, 32, &measured, &kept);
  assert_int_equal(measured, 16);
  free(copy);
  ts_accel_map_free(&m);
  free(prev);
  level_ref_free(&r);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(uniform_map_makes_every_valid_block_a_candidate),
    cmocka_unit_test(kernel_keeps_a_buffer_to_transitions),
    cmocka_unit_test(sources_outside_the_reference_are_refused),
    cmocka_unit_test(parity_must_match),
    cmocka_unit_test(enable_keeps_a_sample_and_constancy_counts_it),
};

TS_TEST_MAIN(tests)
