/* test_tile_grid.c - the tiled scene's grid, phases, order and seeds
 * (tile_grid.h), checked against their definitions written out in plain
 * loops: the tiles cover the scene once; tiles of one phase share no edge;
 * every area outside its core is finished, in the wavefront order, when the
 * tile starts, and every edge between two tiles lies in the later one's
 * area; the order keeps three rows alive; seeds differ by tile and job. */
#include <stdlib.h>

#include "tile_grid.h"
#include "ts_test.h"

/* The scenes tried: sizes around multiples of the tile, smaller than one,
 * remainders under and over half a tile. */
static const int sizes[][2] = {{1, 1}, {63, 64}, {64, 64}, {65, 200}, {95, 96}, {96, 97}, {256, 256}, {300, 1000}, {1000, 300}};
#define TILE 64
#define HALO 16

static void tiles_cover_the_scene_once(void **state) {
  (void)state;
  for (size_t s = 0; s < sizeof(sizes) / sizeof(sizes[0]); s++) {
    ts_tile_grid g;
    assert_int_equal(ts_tile_grid_init(&g, sizes[s][0], sizes[s][1], TILE, HALO), 0);
    int w = sizes[s][0], h = sizes[s][1];
    unsigned char *hit = calloc((size_t)w * (size_t)h, 1);
    for (int ty = 0; ty < g.ny; ty++)
      for (int tx = 0; tx < g.nx; tx++) {
        ts_tile_rect r = ts_tile_core(&g, tx, ty);
        assert_int_equal(r.x0 % TILE, 0); /* origins on the grid */
        assert_int_equal(r.y0 % TILE, 0);
        /* No sliver: at least half a tile, or the whole (small) scene. */
        assert_true(2 * (r.x1 - r.x0) >= TILE || r.x1 - r.x0 == w);
        assert_true(r.x1 - r.x0 < TILE + TILE / 2 || g.nx == 1);
        for (int y = r.y0; y < r.y1; y++)
          for (int x = r.x0; x < r.x1; x++) hit[(size_t)y * (size_t)w + (size_t)x]++;
      }
    for (size_t i = 0; i < (size_t)w * (size_t)h; i++) assert_int_equal(hit[i], 1);
    free(hit);
  }
}

static void remainders_under_half_a_tile_are_merged(void **state) {
  (void)state;
  ts_tile_grid g;
  assert_int_equal(ts_tile_grid_init(&g, 95, 96, 64, 16), 0); /* 31 left: merged; 32 left: a tile */
  assert_int_equal(g.nx, 1);
  assert_int_equal(g.ny, 2);
  assert_int_equal(ts_tile_grid_init(&g, 10, 10, 64, 16), 0);
  assert_int_equal(ts_tile_count(&g), 1);
  assert_int_not_equal(ts_tile_grid_init(&g, 0, 10, 64, 16), 0);
}

static int edge_shared(ts_tile_rect a, ts_tile_rect b) {
  int vert = (a.x1 == b.x0 || b.x1 == a.x0) && a.y0 < b.y1 && b.y0 < a.y1;
  int horz = (a.y1 == b.y0 || b.y1 == a.y0) && a.x0 < b.x1 && b.x0 < a.x1;
  return vert || horz;
}

static void tiles_of_one_phase_share_no_edge(void **state) {
  (void)state;
  ts_tile_grid g;
  assert_int_equal(ts_tile_grid_init(&g, 300, 1000, TILE, HALO), 0);
  for (int a = 0; a < ts_tile_count(&g); a++)
    for (int b = 0; b < ts_tile_count(&g); b++) {
      int ax = a % g.nx, ay = a / g.nx, bx = b % g.nx, by = b / g.nx;
      if (a != b && ts_tile_phase(ax, ay) == ts_tile_phase(bx, by))
        assert_false(edge_shared(ts_tile_core(&g, ax, ay), ts_tile_core(&g, bx, by)));
    }
}

/* Runs the order, checking per tile that every pixel of its area outside
 * its core is finished, that every edge it shares with a finished tile is
 * inside its area, and that it reads no row three or more away. */
static void the_order_reads_only_finished_tiles(void **state) {
  (void)state;
  for (size_t s = 0; s < sizeof(sizes) / sizeof(sizes[0]); s++) {
    ts_tile_grid g;
    assert_int_equal(ts_tile_grid_init(&g, sizes[s][0], sizes[s][1], TILE, HALO), 0);
    int w = g.w, h = g.h;
    unsigned char *done = calloc((size_t)w * (size_t)h, 1), *tile_done = calloc((size_t)ts_tile_count(&g), 1);
    ts_tile_step *steps = malloc(sizeof(*steps) * 2 * (size_t)g.ny);
    int n = ts_tile_schedule(&g, steps), ran = 0;
    assert_int_equal(n, 2 * g.ny);
    for (int k = 0; k < n; k++)
      for (int tx = steps[k].xpar; tx < g.nx; tx += 2) {
        int ty = steps[k].row;
        ts_tile_rect c = ts_tile_core(&g, tx, ty), a = ts_tile_area(&g, tx, ty);
        assert_true(a.x0 <= c.x0 && a.y0 <= c.y0 && a.x1 >= c.x1 && a.y1 >= c.y1);
        assert_true(c.y0 - a.y0 <= HALO && a.x1 - c.x1 <= HALO);
        for (int y = a.y0; y < a.y1; y++)
          for (int x = a.x0; x < a.x1; x++) {
            int in_core = x >= c.x0 && x < c.x1 && y >= c.y0 && y < c.y1;
            assert_int_equal(done[(size_t)y * (size_t)w + (size_t)x], !in_core);
          }
        /* Every finished neighbour's edge: the halo crosses it. */
        for (int j = 0; j < ts_tile_count(&g); j++) {
          ts_tile_rect o = ts_tile_core(&g, j % g.nx, j / g.nx);
          if (!tile_done[j] || !edge_shared(c, o)) continue;
          int crosses = (o.x1 == c.x0 && a.x0 < c.x0) || (o.x0 == c.x1 && a.x1 > c.x1) ||
                        (o.y1 == c.y0 && a.y0 < c.y0) || (o.y0 == c.y1 && a.y1 > c.y1);
          assert_true(crosses || HALO == 0);
        }
        for (int y = c.y0; y < c.y1; y++)
          for (int x = c.x0; x < c.x1; x++) done[(size_t)y * (size_t)w + (size_t)x] = 1;
        tile_done[ts_tile_index(&g, tx, ty)] = 1;
        ran++;
      }
    assert_int_equal(ran, ts_tile_count(&g));
    /* Rows alive - from their first step to the last step that reads them
     * (odd rows read the rows around) - are three at most at any step. */
    int *first = malloc(sizeof(int) * (size_t)g.ny), *last = malloc(sizeof(int) * (size_t)g.ny);
    for (int r = 0; r < g.ny; r++) first[r] = n, last[r] = -1;
    for (int k = 0; k < n; k++)
      for (int r = steps[k].row - (steps[k].row & 1); r <= steps[k].row + (steps[k].row & 1); r++) {
        if (r < 0 || r >= g.ny) continue;
        if (first[r] > k) first[r] = k;
        last[r] = k;
      }
    for (int k = 0; k < n; k++) {
      int alive = 0;
      for (int r = 0; r < g.ny; r++) alive += first[r] <= k && k <= last[r];
      assert_true(alive <= 3);
    }
    free(first);
    free(last);
    free(done);
    free(tile_done);
    free(steps);
  }
}

static void seeds_differ_by_tile_and_job(void **state) {
  (void)state;
  uint64_t seen[64];
  for (uint32_t i = 0; i < 32; i++) {
    seen[i] = ts_tile_seed(1, i);
    seen[32 + i] = ts_tile_seed(2, i);
  }
  for (int a = 0; a < 64; a++)
    for (int b = 0; b < a; b++) assert_true(seen[a] != seen[b]);
  assert_true(ts_tile_seed(1, 0) == ts_tile_seed(1, 0)); /* a function of its arguments */
}

/* (wn/2 + 1) * 2^(levels-1), raised in steps of 2^(levels-1) until one
 * short of a multiple of wb. */
static void the_default_halo_reaches_the_coarsest_neighbourhood(void **state) {
  (void)state;
  assert_int_equal(ts_tile_default_halo(3, 7, 3), 20); /* 16, 20 */
  assert_int_equal(ts_tile_default_halo(1, 5, 3), 5);  /* 3, 4, 5 */
  assert_int_equal(ts_tile_default_halo(4, 9, 3), 56); /* 40, 48, 56 */
  assert_int_equal(ts_tile_default_halo(4, 9, 1), 40);
  for (int l = 1; l <= 6; l++)
    for (int wb = 1; wb <= 15; wb += 2) {
      int h = ts_tile_default_halo(l, wb + 2, wb);
      assert_int_equal(h % (1 << (l - 1)), 0);
      assert_int_equal(h % wb, wb - 1 == 0 ? 0 : wb - 1);
      assert_true(h >= ((wb + 2) / 2 + 1) << (l - 1));
    }
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(tiles_cover_the_scene_once),
    cmocka_unit_test(remainders_under_half_a_tile_are_merged),
    cmocka_unit_test(tiles_of_one_phase_share_no_edge),
    cmocka_unit_test(the_order_reads_only_finished_tiles),
    cmocka_unit_test(seeds_differ_by_tile_and_job),
    cmocka_unit_test(the_default_halo_reaches_the_coarsest_neighbourhood),
};

TS_TEST_MAIN(tests)
