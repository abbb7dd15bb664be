/* test_neigh.c - the MRF's neighbourhood windows (Table 3.1), their
 * anchors with parity labels, and vector extraction. */
#include <stdlib.h>

#include "error.h"
#include "anchors.h"
#include "neigh.h"
#include "ts_test.h"

/* Table 3.1 of seed 002: pixel count = W_N^2 - W_B^2 + W_C^2 with W_B = 3
 * (the square shape holds the block too). */
static void full_shape_matches_table_3_1(void **state) {
  (void)state;
  const int wn[] = {5, 7, 9, 11, 13, 15};
  const int wc[] = {3, 5, 5, 7, 7, 9};
  const int total[] = {25, 65, 97, 161, 209, 297};
  for (int i = 0; i < 6; i++) {
    ts_window s;
    char err[TS_ERR_LEN];
    assert_int_equal(ts_coarse_width(wn[i]), wc[i]);
    assert_int_equal(ts_neigh_window(&s, TS_SHAPE_SQUARE, wn[i], 3, 1, 1, 1.0, err), 0);
    assert_int_equal(s.spec.noff[TS_SRC_FINE] - 9 + s.spec.noff[TS_SRC_COARSE], total[i]);
    ts_window_free(&s);
  }
}

/* L shape: (W_N-W_B)/2 rows above the whole window plus as many columns
 * left of the block; for W_B = 1 that is (W_N^2 - 1) / 2 (seed §3.4). */
static void causal_shape_counts(void **state) {
  (void)state;
  ts_window s;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_neigh_window(&s, TS_SHAPE_CAUSAL, 17, 1, 0, 1, 1.0, err), 0);
  assert_int_equal(s.spec.noff[TS_SRC_FINE], 144); /* the seed's example */
  assert_int_equal(s.spec.nparts, 1);
  ts_window_free(&s);
  assert_int_equal(ts_neigh_window(&s, TS_SHAPE_CAUSAL, 7, 3, 1, 1, 1.0, err), 0);
  assert_int_equal(s.spec.noff[TS_SRC_FINE], 20);
  assert_int_equal(s.spec.noff[TS_SRC_COARSE], 25);
  assert_int_equal(s.part_end[0], 3);
  assert_int_equal(s.nchunks, 7);
  for (int k = 0; k < 20; k++) /* nothing at or after the block */
    assert_true(s.spec.dy[0][k] < 0 || (s.spec.dy[0][k] < 3 && s.spec.dx[0][k] < 0));
  /* equal weighting by area: 16*25 : 16*20 reduced */
  assert_int_equal((uint64_t)s.spec.part[0].weight * 20, (uint64_t)s.spec.part[1].weight * 25);
  /* the square's extents, so both shapes share their anchors */
  assert_int_equal(s.spec.extent[TS_SRC_FINE].dy1, 5);
  ts_window_free(&s);
}

static void shape_rejects_bad_sizes(void **state) {
  (void)state;
  ts_window s;
  char err[TS_ERR_LEN] = "";
  assert_int_equal(ts_neigh_window(&s, TS_SHAPE_CAUSAL, 7, 4, 1, 1, 1.0, err), TS_EINVAL);
  assert_non_null(strstr(err, "odd"));
  assert_int_equal(ts_neigh_window(&s, TS_SHAPE_CAUSAL, 3, 3, 1, 1, 1.0, err), TS_EINVAL);
  assert_int_equal(ts_neigh_window(&s, TS_SHAPE_CAUSAL, 7, 3, 1, 9, 1.0, err), TS_EINVAL);
}

/* Parity as a label plane: every anchor's index names it back, its class
 * is its parity, the window fits, and the order is row-major in a class -
 * the order the engine had before labels existed. */
static void parity_anchors_roundtrip(void **state) {
  (void)state;
  ts_plane labels;
  assert_int_equal(ts_plane_alloc(&labels, 41, 37), 0);
  for (int y = 0; y < 37; y++)
    for (int x = 0; x < 41; x++) labels.px[y * 41 + x] = (uint8_t)((x & 1) | (y & 1) << 1);
  for (int parity = 0; parity <= 1; parity++) {
    ts_window s;
    ts_anchors g;
    char err[TS_ERR_LEN];
    assert_int_equal(ts_neigh_window(&s, TS_SHAPE_CAUSAL, 7, 3, 1, 1, 1.0, err), 0);
    assert_int_equal(ts_anchors_init(&g, &s, 41, 37, 20, 18, parity ? &labels : NULL, parity ? 4 : 1, NULL, err), 0);
    uint32_t seen = 0;
    for (int y = 0; y < 37; y++)
      for (int x = 0; x < 41; x++) {
        int64_t j = ts_anchors_index(&g, x, y);
        if (j < 0) continue;
        seen++;
        int px, py;
        assert_int_equal(ts_anchors_class(&g, (uint32_t)j), parity ? ((x & 1) | (y & 1) << 1) : 0);
        ts_anchors_pos(&g, (uint32_t)j, &px, &py);
        assert_int_equal(px, x);
        assert_int_equal(py, y);
        /* the whole window and the coarse window are inside */
        assert_true(x - 2 >= 0 && x + 3 + 2 <= 41 && y - 2 >= 0 && y + 5 <= 37);
        int cx = (x + 1) / 2, cy = (y + 1) / 2;
        assert_true(cx - 2 >= 0 && cx + 2 < 20 && cy - 2 >= 0 && cy + 2 < 18);
      }
    assert_int_equal(seen, g.total);
    /* row-major order inside a class */
    int px0, py0, px1, py1;
    ts_anchors_pos(&g, 0, &px0, &py0);
    ts_anchors_pos(&g, 1, &px1, &py1);
    assert_int_equal(py0, py1);
    assert_int_equal(px1 - px0, parity ? 2 : 1);
    ts_anchors_free(&g);
    ts_window_free(&s);
  }
  ts_plane_free(&labels);
}

static void anchors_too_small_reference(void **state) {
  (void)state;
  ts_window s;
  ts_anchors g;
  char err[TS_ERR_LEN] = "";
  assert_int_equal(ts_neigh_window(&s, TS_SHAPE_CAUSAL, 7, 3, 0, 1, 1.0, err), 0);
  assert_int_equal(ts_anchors_init(&g, &s, 6, 20, 0, 0, NULL, 1, NULL, err), TS_EINVAL);
  assert_non_null(strstr(err, "6x20"));
  ts_window_free(&s);
}

static void query_reads_torus_and_matches_reference(void **state) {
  (void)state;
  ts_plane fine, coarse;
  assert_int_equal(ts_plane_alloc(&fine, 16, 12), 0);
  assert_int_equal(ts_plane_alloc(&coarse, 8, 6), 0);
  for (int i = 0; i < 16 * 12; i++) fine.px[i] = (uint8_t)(i * 13 + 1);
  for (int i = 0; i < 8 * 6; i++) coarse.px[i] = (uint8_t)(i * 29 + 5);
  ts_window s;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_neigh_window(&s, TS_SHAPE_SQUARE, 7, 3, 1, 1, 1.0, err), 0);
  ts_levelplanes lp = {{&fine}, {&coarse}};
  uint8_t a[TS_L1_MAX_CHUNKS * 8], b[TS_L1_MAX_CHUNKS * 8];
  /* Inside, a query equals the reference vector of the same position. */
  ts_vec_query(&s, &lp, 1, 5, 4, a);
  ts_vec_ref(&s, &lp, 5, 4, b);
  assert_memory_equal(a, b, ts_window_bytes(&s));
  /* At (0, 0) the window wraps: first fine pixel is (-2, -2) = (14, 10). */
  ts_vec_query(&s, &lp, 1, 0, 0, a);
  assert_int_equal(a[0], fine.px[10 * 16 + 14]);
  /* padding is zero */
  for (uint32_t k = (uint32_t)s.spec.noff[0]; k < s.part_end[0] * 8; k++) assert_int_equal(a[k], 0);
  ts_window_free(&s);
  ts_plane_free(&fine);
  ts_plane_free(&coarse);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(full_shape_matches_table_3_1),
    cmocka_unit_test(causal_shape_counts),
    cmocka_unit_test(shape_rejects_bad_sizes),
    cmocka_unit_test(parity_anchors_roundtrip),
    cmocka_unit_test(anchors_too_small_reference),
    cmocka_unit_test(query_reads_torus_and_matches_reference),
};

TS_TEST_MAIN(tests)
