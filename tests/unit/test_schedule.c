/* test_schedule.c - block scheduling: every schedule is conflict-free, covers
 * the canvas exactly once, and the wavefront keeps the causal order. */
#include <stdlib.h>

#include "schedule.h"
#include "ts_test.h"

/* Every pixel covered by exactly one block. */
static void assert_covers(const ts_schedule *s) {
  int n = s->width * s->height;
  uint8_t *hit = calloc((size_t)n, 1);
  for (uint32_t i = 0; i < s->nblocks; i++) {
    const ts_block *b = &s->blocks[i];
    for (int y = b->y; y < b->y + b->h; y++)
      for (int x = b->x; x < b->x + b->w; x++) hit[y * s->width + x]++;
  }
  for (int i = 0; i < n; i++) assert_int_equal(hit[i], 1);
  free(hit);
}

static void wavefront_sizes_are_conflict_free(void **state) {
  (void)state;
  const int sizes[][2] = {{1024, 1024}, {64, 64}, {65, 31}, {7, 7}, {9, 30}, {57, 19},
                          {100, 3},     {3, 100}, {19, 10}, {33, 33}, {512, 17}};
  const int params[][2] = {{7, 3}, {5, 3}, {9, 3}, {11, 3}, {7, 1}, {9, 5}, {15, 3}};
  for (size_t i = 0; i < sizeof(sizes) / sizeof(sizes[0]); i++)
    for (size_t j = 0; j < sizeof(params) / sizeof(params[0]); j++) {
      int w = sizes[i][0], h = sizes[i][1], wn = params[j][0], wb = params[j][1];
      if (w * h > 70000 && (wn != 7 || wb != 3)) continue; /* keep it quick */
      ts_schedule s;
      assert_int_equal(ts_schedule_wavefront(&s, w, h, wb, wn), 0);
      assert_int_equal(ts_schedule_conflicts(&s), 0);
      assert_covers(&s);
      ts_schedule_free(&s);
    }
}

/* The seed's Table 3.3 canvas: 1024/3 does not divide, the last column and
 * row are 1 pixel wide; skew 2 gives about cols + 2 * rows steps. */
static void wavefront_1024_is_wide(void **state) {
  (void)state;
  ts_schedule s;
  assert_int_equal(ts_schedule_wavefront(&s, 1024, 1024, 3, 7), 0);
  assert_int_equal(s.rows, 342);
  assert_int_equal(s.cols, 342);
  assert_int_equal(s.skew, 2);
  assert_int_equal(s.nsteps, 341 + 2 * 341 + 1);
  assert_true(s.nblocks / s.nsteps > 100);
  assert_int_equal(s.blocks[s.nblocks - 1].w, 1);
  ts_schedule_free(&s);
}

/* In the wavefront, every block of the causal window that precedes a block
 * in row-major order (without wrapping) is in an earlier step. */
static void wavefront_keeps_causal_order(void **state) {
  (void)state;
  ts_schedule s;
  assert_int_equal(ts_schedule_wavefront(&s, 90, 60, 3, 11), 0);
  uint32_t *step = malloc(sizeof(uint32_t) * s.rows * s.cols);
  for (uint32_t t = 0; t < s.nsteps; t++)
    for (uint32_t i = s.step_start[t]; i < s.step_start[t + 1]; i++)
      step[(s.blocks[i].y / 3) * s.cols + s.blocks[i].x / 3] = t;
  int k = (s.halo + 2) / 3; /* block rows/cols the window reaches */
  for (int r = 0; r < s.rows; r++)
    for (int c = 0; c < s.cols; c++) {
      uint32_t me = step[r * s.cols + c];
      for (int dr = -k; dr <= 0; dr++)
        for (int dc = -k; dc <= k; dc++) {
          if (dr == 0 && dc >= 0) continue;
          int rr = r + dr, cc = c + dc;
          if (rr < 0 || cc < 0 || cc >= s.cols) continue;
          assert_true(step[rr * s.cols + cc] < me);
        }
    }
  free(step);
  ts_schedule_free(&s);
}

/* A sweep visits every block once in m*m colours where the sizes are
 * divisible by m blocks, a few more where the torus wraps otherwise; no two
 * blocks of a colour ever see each other. */
static void sweep_colours_cover_canvas(void **state) {
  (void)state;
  ts_schedule s;
  assert_int_equal(ts_schedule_sweep(&s, 96, 60, 3, 7, 0), 0); /* 32 x 20 blocks, m = 2 */
  assert_int_equal(s.nsteps, 4);
  assert_int_equal(ts_schedule_conflicts(&s), 0);
  assert_covers(&s);
  ts_schedule_free(&s);
  assert_int_equal(ts_schedule_sweep(&s, 90, 60, 3, 7, 3), 0); /* 30 x 20, band 3 */
  assert_int_equal(s.nblocks, 30 * 20 - 24 * 14);
  assert_int_equal(ts_schedule_conflicts(&s), 0);
  for (uint32_t i = 0; i < s.nblocks; i++) {
    int r = s.blocks[i].y / 3, c = s.blocks[i].x / 3;
    assert_true(r < 3 || r >= 17 || c < 3 || c >= 27);
  }
  ts_schedule_free(&s);
}

/* Where the torus wraps with a block count not divisible by m or a clipped
 * last block (256 = 85 * 3 + 1: block 84 reaches block 0 across a 1-pixel
 * block), the first and last blocks must still differ in colour. */
static void sweep_is_conflict_free_across_the_wrap(void **state) {
  (void)state;
  static const int sizes[][4] = {{256, 256, 3, 7}, {100, 31, 3, 11}, {255, 254, 3, 7}, {97, 61, 5, 9},
                                 {50, 38, 3, 7},   {64, 7, 3, 7},    {11, 11, 3, 9},   {1024, 1000, 3, 7}};
  for (size_t i = 0; i < sizeof(sizes) / sizeof(sizes[0]); i++)
    for (int band = 0; band <= 3; band += 3) {
      ts_schedule s;
      assert_int_equal(ts_schedule_sweep(&s, sizes[i][0], sizes[i][1], sizes[i][2], sizes[i][3], band), 0);
      assert_int_equal(ts_schedule_conflicts(&s), 0);
      if (band == 0) assert_covers(&s);
      ts_schedule_free(&s);
    }
}

static void schedule_rejects_bad_geometry(void **state) {
  (void)state;
  ts_schedule s;
  assert_int_not_equal(ts_schedule_wavefront(&s, 0, 10, 3, 7), 0);
  assert_int_not_equal(ts_schedule_wavefront(&s, 10, 10, 0, 7), 0);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(wavefront_sizes_are_conflict_free),
    cmocka_unit_test(wavefront_1024_is_wide),
    cmocka_unit_test(wavefront_keeps_causal_order),
    cmocka_unit_test(sweep_colours_cover_canvas),
    cmocka_unit_test(sweep_is_conflict_free_across_the_wrap),
    cmocka_unit_test(schedule_rejects_bad_geometry),
};

TS_TEST_MAIN(tests)
