/* test_features.c - generic feature sets: windows of any planes, offsets
 * and weighted parts; anchors with up to 256 label classes and a validity
 * plane; and slices of such sets, sent through the wire format and
 * scanned, against a brute-force search written from the definitions. */
#include <stdlib.h>

#include "anchors.h"
#include "error.h"
#include "msg.h"
#include "pool.h"
#include "replica.h"
#include "rng.h"
#include "slice.h"
#include "ts_test.h"
#include "window.h"

enum { W = 48, H = 40, CW = 24, CH = 20, NFINE = 5, NCLASS = 7 };

/* A StyLit-like window: a 3x3 square over 5 fine planes in three parts
 * (planes 0-2 weight 3, plane 3 weight 1000, plane 4 weight 0), and a
 * 2x2 coarse square over 2 planes, weight 2. */
typedef struct {
  int16_t fdx[9], fdy[9], cdx[4], cdy[4];
  ts_window_spec spec;
} example_spec;

static void example_init(example_spec *e) {
  memset(e, 0, sizeof(*e));
  for (int k = 0; k < 9; k++) e->fdx[k] = (int16_t)(k % 3 - 1), e->fdy[k] = (int16_t)(k / 3 - 1);
  for (int k = 0; k < 4; k++) e->cdx[k] = (int16_t)(k % 2), e->cdy[k] = (int16_t)(k / 2);
  ts_window_spec *s = &e->spec;
  s->nplanes[TS_SRC_FINE] = NFINE, s->nplanes[TS_SRC_COARSE] = 2;
  s->noff[TS_SRC_FINE] = 9, s->noff[TS_SRC_COARSE] = 4;
  s->dx[TS_SRC_FINE] = e->fdx, s->dy[TS_SRC_FINE] = e->fdy, s->dx[TS_SRC_COARSE] = e->cdx, s->dy[TS_SRC_COARSE] = e->cdy;
  s->extent[TS_SRC_FINE] = (ts_box){-1, -1, 2, 2};
  s->extent[TS_SRC_COARSE] = (ts_box){0, 0, 2, 2};
  s->centre = 1, s->block = 3, s->nparts = 4;
  s->part[0] = (ts_part){TS_SRC_FINE, 0, 3, 3};
  s->part[1] = (ts_part){TS_SRC_FINE, 3, 1, 1000};
  s->part[2] = (ts_part){TS_SRC_FINE, 4, 1, 0};
  s->part[3] = (ts_part){TS_SRC_COARSE, 0, 2, 2};
}

static void window_lays_out_parts(void **state) {
  (void)state;
  example_spec e;
  example_init(&e);
  ts_window w;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_window_init(&w, &e.spec, err), 0);
  /* 27 bytes -> 4 chunks, 9 -> 2, 9 -> 2, 8 -> 1 */
  assert_int_equal(w.part_end[0], 4);
  assert_int_equal(w.part_end[1], 6);
  assert_int_equal(w.part_end[2], 8);
  assert_int_equal(w.nchunks, 9);
  assert_int_equal(ts_window_unit_distance(&w), 3 * 27 + 1000 * 9 + 0 + 2 * 8);
  ts_plane fine[NFINE], coarse[2];
  ts_levelplanes lp;
  memset(&lp, 0, sizeof(lp));
  for (int p = 0; p < NFINE; p++) {
    assert_int_equal(ts_plane_alloc(&fine[p], 10, 10), 0);
    for (int i = 0; i < 100; i++) fine[p].px[i] = (uint8_t)(i + 100 * p);
    lp.fine[p] = &fine[p];
  }
  for (int p = 0; p < 2; p++) {
    assert_int_equal(ts_plane_alloc(&coarse[p], 5, 5), 0);
    for (int i = 0; i < 25; i++) coarse[p].px[i] = (uint8_t)(200 + i + 25 * p);
    lp.coarse[p] = &coarse[p];
  }
  uint8_t v[TS_L1_MAX_CHUNKS * TS_L1_CHUNK];
  ts_vec_ref(&w, &lp, 4, 5, v);
  assert_int_equal(v[0], fine[0].px[4 * 10 + 3]);  /* plane 0 at (-1, -1) */
  assert_int_equal(v[9 + 4], fine[1].px[5 * 10 + 4]); /* plane 1 at (0, 0) */
  assert_int_equal(v[27], 0);                        /* padding of part 0 */
  assert_int_equal(v[32 + 8], fine[3].px[6 * 10 + 5]); /* plane 3 at (1, 1) */
  assert_int_equal(v[64], coarse[0].px[3 * 5 + 2]);  /* centre ((4 + 1) / 2, (5 + 1) / 2) */
  assert_int_equal(v[64 + 7], coarse[1].px[4 * 5 + 3]);
  for (int p = 0; p < NFINE; p++) ts_plane_free(&fine[p]);
  for (int p = 0; p < 2; p++) ts_plane_free(&coarse[p]);
  ts_window_free(&w);
}

static void window_refuses_bad_specs(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  for (int k = 0; k < 7; k++) {
    example_spec e;
    example_init(&e);
    const char *want = NULL;
    switch (k) {
    case 0: e.spec.nplanes[TS_SRC_FINE] = 33, want = "33 fine planes"; break;
    case 1: e.fdx[4] = 2, want = "offset (2, 0) lies outside"; break;
    case 2: e.spec.part[1].plane0 = 5, want = "part 1"; break;
    case 3: e.spec.nparts = 0, want = "0 weighted parts"; break;
    case 4: e.spec.nplanes[TS_SRC_FINE] = 0, want = "at least one fine plane"; break;
    case 5: e.spec.block = 0, want = "block side 0"; break;
    case 6: /* the most planes there may be, in one part: accepted */
      e.spec.nplanes[TS_SRC_FINE] = 32, e.spec.part[0] = (ts_part){TS_SRC_FINE, 0, 32, 1}, e.spec.nparts = 1;
      break;
    }
    ts_window w;
    err[0] = '\0';
    int rc = ts_window_init(&w, &e.spec, err);
    if (want == NULL) {
      if (rc != 0) fail_msg("case %d: %s", k, err);
      ts_window_free(&w);
      continue;
    }
    assert_int_equal(rc, TS_EINVAL);
    if (strstr(err, want) == NULL) fail_msg("case %d: %s", k, err);
  }
}

static void fill_labels(ts_plane *labels, ts_plane *mask, uint64_t seed) {
  ts_rng rng;
  ts_rng_seed(&rng, seed, 1);
  assert_int_equal(ts_plane_alloc(labels, W, H), 0);
  assert_int_equal(ts_plane_alloc(mask, W, H), 0);
  for (int i = 0; i < W * H; i++) {
    labels->px[i] = (uint8_t)ts_rng_below(&rng, NCLASS);
    mask->px[i] = 1;
  }
  for (int y = 10; y < 16; y++) /* a hole the windows must avoid */
    for (int x = 20; x < 31; x++) mask->px[y * W + x] = 0;
}

/* 256 classes, every label value used: indices name their anchors back,
 * classes come in order, row-major within a class. */
static void anchors_order_with_256_classes(void **state) {
  (void)state;
  example_spec e;
  example_init(&e);
  ts_window w;
  ts_anchors a;
  ts_plane labels;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_window_init(&w, &e.spec, err), 0);
  assert_int_equal(ts_plane_alloc(&labels, W, H), 0);
  for (int i = 0; i < W * H; i++) labels.px[i] = (uint8_t)(i * 37 + i / W);
  assert_int_equal(ts_anchors_init(&a, &w, W, H, CW, CH, &labels, 256, NULL, err), 0);
  uint32_t seen = 0;
  int64_t last[256];
  for (int c = 0; c < 256; c++) last[c] = -1;
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) {
      int64_t j = ts_anchors_index(&a, x, y);
      if (j < 0) continue;
      int c = labels.px[y * W + x], px, py;
      assert_int_equal(ts_anchors_class(&a, (uint32_t)j), c);
      assert_true(j > last[c]); /* row-major within the class */
      assert_true((uint32_t)j >= a.base[c] && (uint32_t)j < a.base[c] + a.count[c]);
      last[c] = j;
      ts_anchors_pos(&a, (uint32_t)j, &px, &py);
      assert_int_equal(px, x);
      assert_int_equal(py, y);
      seen++;
    }
  assert_int_equal(seen, a.total);
  assert_int_equal(a.total, (uint32_t)(a.nx * a.ny));
  ts_anchors_free(&a);
  /* a label past the classes is an error naming it */
  assert_int_equal(ts_anchors_init(&a, &w, W, H, CW, CH, &labels, 100, NULL, err), TS_EINVAL);
  assert_non_null(strstr(err, "classes"));
  ts_plane_free(&labels);
  ts_window_free(&w);
}

/* Only anchors whose fine extent avoids the hole are vectors. */
static void validity_from_mask_avoids_holes(void **state) {
  (void)state;
  example_spec e;
  example_init(&e);
  ts_window w;
  ts_anchors a;
  ts_plane labels, mask, valid;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_window_init(&w, &e.spec, err), 0);
  fill_labels(&labels, &mask, 3);
  assert_int_equal(ts_anchors_valid_from_mask(&mask, &e.spec.extent[TS_SRC_FINE], &valid), 0);
  assert_int_equal(ts_anchors_init(&a, &w, W, H, CW, CH, &labels, NCLASS, &valid, err), 0);
  uint32_t n = 0;
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) {
      int clear = 1;
      for (int k = 0; k < 9; k++) {
        int px = x + e.fdx[k], py = y + e.fdy[k];
        if (px < 0 || py < 0 || px >= W || py >= H || mask.px[py * W + px] == 0) clear = 0;
      }
      int in_box = x >= a.x0 && y >= a.y0 && x < a.x0 + a.nx && y < a.y0 + a.ny;
      assert_int_equal(ts_anchors_index(&a, x, y) >= 0, clear && in_box);
      n += clear && in_box;
    }
  assert_int_equal(n, a.total);
  assert_true(a.total < (uint32_t)(a.nx * a.ny));
  ts_anchors_free(&a);
  ts_plane_free(&labels);
  ts_plane_free(&mask);
  ts_plane_free(&valid);
  ts_window_free(&w);
}

/* ---- slices of a labelled, masked set against brute force ---- */

typedef struct {
  example_spec e;
  ts_window w;
  ts_anchors a;
  ts_plane fine[NFINE], coarse[2], labels, mask, valid;
  ts_levelplanes lp;
} feature_set;

static void set_up(feature_set *f, uint64_t seed) {
  char err[TS_ERR_LEN];
  example_init(&f->e);
  assert_int_equal(ts_window_init(&f->w, &f->e.spec, err), 0);
  fill_labels(&f->labels, &f->mask, seed);
  assert_int_equal(ts_anchors_valid_from_mask(&f->mask, &f->e.spec.extent[TS_SRC_FINE], &f->valid), 0);
  assert_int_equal(ts_anchors_init(&f->a, &f->w, W, H, CW, CH, &f->labels, NCLASS, &f->valid, err), 0);
  ts_rng rng;
  ts_rng_seed(&rng, seed, 2);
  memset(&f->lp, 0, sizeof(f->lp));
  for (int p = 0; p < NFINE; p++) {
    assert_int_equal(ts_plane_alloc(&f->fine[p], W, H), 0);
    for (int i = 0; i < W * H; i++) f->fine[p].px[i] = (uint8_t)ts_rng_below(&rng, 256);
    f->lp.fine[p] = &f->fine[p];
  }
  for (int p = 0; p < 2; p++) {
    assert_int_equal(ts_plane_alloc(&f->coarse[p], CW, CH), 0);
    for (int i = 0; i < CW * CH; i++) f->coarse[p].px[i] = (uint8_t)ts_rng_below(&rng, 256);
    f->lp.coarse[p] = &f->coarse[p];
  }
}

static void tear_down(feature_set *f) {
  for (int p = 0; p < NFINE; p++) ts_plane_free(&f->fine[p]);
  for (int p = 0; p < 2; p++) ts_plane_free(&f->coarse[p]);
  ts_plane_free(&f->labels);
  ts_plane_free(&f->mask);
  ts_plane_free(&f->valid);
  ts_anchors_free(&f->a);
  ts_window_free(&f->w);
}

/* The best match by definition: every anchor of the class, its vector, the
 * parts' weights byte by byte; ties to the lowest index. */
static ts_l1_best brute_best(const feature_set *f, const uint8_t *q, int klass) {
  ts_l1_best best = {UINT64_MAX, UINT32_MAX, 0};
  uint8_t v[TS_L1_MAX_CHUNKS * TS_L1_CHUNK];
  for (uint32_t j = f->a.base[klass]; j < f->a.base[klass] + f->a.count[klass]; j++) {
    int x, y, part = 0;
    ts_anchors_pos(&f->a, j, &x, &y);
    ts_vec_ref(&f->w, &f->lp, x, y, v);
    uint64_t d = 0;
    for (uint32_t k = 0; k < ts_window_bytes(&f->w); k++) {
      while (k >= f->w.part_end[part] * TS_L1_CHUNK) part++;
      d += (uint64_t)(q[k] > v[k] ? q[k] - v[k] : v[k] - q[k]) * f->w.spec.part[part].weight;
    }
    if (d < best.dist) best.dist = d, best.index = j;
  }
  return best;
}

/* The set's labels as a 7 x 3 tile, its anchors made again from them. */
static void tile_labels(feature_set *f) {
  char err[TS_ERR_LEN];
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) f->labels.px[y * W + x] = (uint8_t)((x % 7 + 2 * (y % 3)) % NCLASS);
  ts_anchors_free(&f->a);
  assert_int_equal(ts_anchors_init(&f->a, &f->w, W, H, CW, CH, &f->labels, NCLASS, &f->valid, err), 0);
}

/* A query image whose reference planes are the set's fine planes, as a
 * worker holding the MRF's canvas has them. */
static void image_of_set(ts_replica *r, const feature_set *f) {
  static uint32_t copy[2 * 4 * 4]; /* every pixel copied from (0, 0) */
  ts_replica_desc d = {.w = 4, .h = 4, .nplanes = NFINE, .block = 2, .rw = W, .rh = H, .copy = copy};
  for (int p = 0; p < NFINE; p++) d.ref[p] = f->fine[p].px;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_replica_init(r, &d, err), 0);
}

/* Slice k of 3 of the set, through the wire format, loaded as a worker
 * would: with shortcuts, labels travel as a tile and fine rows not at
 * all, the worker taking them from its query image. */
static ts_slice *slice_through_wire(const feature_set *f, int k, int shortcuts, const ts_replica *image, ts_pool *pool,
                                    size_t *bytes) {
  uint32_t i0[TS_MAX_CLASSES], i1[TS_MAX_CLASSES];
  for (int c = 0; c < NCLASS; c++) {
    i0[c] = f->a.count[c] * (uint32_t)k / 3;
    i1[c] = f->a.count[c] * (uint32_t)(k + 1) / 3;
  }
  ts_refset rs = {0, &f->w, &f->a, &f->lp, &f->labels, &f->valid, 0, NULL};
  static ts_slice_desc m, back;
  char err[TS_ERR_LEN];
  ts_slice_describe(&m, &rs, NULL, 1, 1, 0, i0, i1, NULL);
  assert_true(m.ay1 - m.ay0 < f->a.ny); /* a slice holds only its rows */
  if (shortcuts) {
    assert_int_equal(ts_slice_label_tile(&f->labels, &m.tile_w, &m.tile_h, m.tile), 1);
    assert_int_equal(m.tile_w * m.tile_h, 21);
    m.labelled = TS_SLICE_LABELS_TILE;
    m.fine_from_image = 1;
    m.fine_sum = ts_slice_fine_sum(&m);
  }
  ts_wr wr;
  ts_wr_init(&wr);
  ts_msg_slice_write(&wr, &m);
  assert_int_equal(ts_wr_status(&wr), 0);
  *bytes = wr.len;
  ts_frame fr = {'N', 1, (uint32_t)wr.len, wr.buf};
  assert_int_equal(ts_msg_slice_read(&fr, &back, err), 0);
  if (shortcuts && ts_replica_slice_rows(image, &back, err) != 0) fail_msg("slice %d: %s", k, err);
  ts_slice *sl;
  if (ts_slice_load(&sl, &back, NULL, pool, err) != 0) fail_msg("slice %d: %s", k, err);
  ts_wr_free(&wr);
  return sl;
}

/* Cuts every class into three ranges, sends each slice through the wire
 * format, loads it as a worker would and scans queries of every class:
 * the merged answers are the brute-force ones. */
static void sliced_set_matches_brute_force(int shortcuts) {
  feature_set f;
  set_up(&f, 11);
  ts_replica image;
  if (shortcuts) {
    tile_labels(&f);
    image_of_set(&image, &f);
  }
  enum { NQ = 40 };
  uint32_t vb = ts_window_bytes(&f.w);
  uint8_t *q = malloc((size_t)NQ * vb), klass[NQ];
  ts_rng rng;
  ts_rng_seed(&rng, 5, 3);
  for (int i = 0; i < NQ; i++) {
    klass[i] = (uint8_t)(i % NCLASS);
    ts_vec_query(&f.w, &f.lp, 1, (int)ts_rng_below(&rng, W), (int)ts_rng_below(&rng, H), q + (size_t)i * vb);
    q[(size_t)i * vb] ^= 0x5A; /* not an exact copy of a reference vector */
  }
  ts_l1_best merged[NQ], part[NQ];
  ts_l1_best_reset(merged, NQ);
  const ts_l1_impl *simd;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_l1_select(&simd, err), 0);
  ts_pool *pool; /* three threads build each slice's vectors, by bands of rows */
  assert_int_equal(ts_pool_create(&pool, 3), 0);
  for (int k = 0; k < 3; k++) {
    size_t bytes, whole;
    ts_slice *sl = slice_through_wire(&f, k, shortcuts, &image, pool, &bytes);
    ts_vec_batch b = {NQ, q, NULL, klass, 0};
    uint64_t pairs;
    assert_int_equal(ts_slice_scan(sl, NULL, 1, simd, &b, part, &pairs, err), 0);
    for (int i = 0; i < NQ; i++)
      if (part[i].index != UINT32_MAX) ts_l1_best_merge(&merged[i], &part[i], 1);
    ts_slice_free(sl);
    if (shortcuts) { /* a fine plane's rows and the label rows did not travel */
      ts_slice_free(slice_through_wire(&f, k, 0, NULL, pool, &whole));
      assert_true(whole > bytes + (NFINE + 1) * 4 * W);
    }
  }
  ts_pool_destroy(pool);
  for (int i = 0; i < NQ; i++) {
    ts_l1_best want = brute_best(&f, q + (size_t)i * vb, klass[i]);
    assert_int_equal(merged[i].index, want.index);
    assert_int_equal(merged[i].dist, want.dist);
    assert_int_equal(ts_anchors_class(&f.a, merged[i].index), klass[i]);
  }
  if (shortcuts) ts_replica_free(&image);
  free(q);
  tear_down(&f);
}

static void sliced_labelled_set_matches_brute_force(void **state) {
  (void)state;
  sliced_set_matches_brute_force(0);
}

static void sliced_set_without_rows_or_labels_matches_brute_force(void **state) {
  (void)state;
  sliced_set_matches_brute_force(1);
}

/* A worker refuses to take fine rows from an image of another level (its
 * reference differs) or of another size. */
static void rows_from_another_image_are_refused(void **state) {
  (void)state;
  feature_set f;
  set_up(&f, 13);
  ts_replica image;
  image_of_set(&image, &f);
  ts_refset rs = {0, &f.w, &f.a, &f.lp, &f.labels, &f.valid, 0, NULL};
  static const uint32_t i0[TS_MAX_CLASSES] = {0};
  static ts_slice_desc m;
  char err[TS_ERR_LEN];
  ts_slice_describe(&m, &rs, NULL, 1, 1, 0, i0, f.a.count, NULL);
  m.fine_from_image = 1;
  m.fine_sum = ts_slice_fine_sum(&m);
  image.ref[2].px[W * (m.fy0 + 1) + 3] ^= 1; /* one byte of another level */
  assert_int_equal(ts_replica_slice_rows(&image, &m, err), TS_EINVAL);
  assert_non_null(strstr(err, "other reference rows"));
  m.w = W - 1;
  assert_int_equal(ts_replica_slice_rows(&image, &m, err), TS_EINVAL);
  assert_non_null(strstr(err, "reference is 5 of 48x40"));
  assert_int_equal(ts_replica_slice_rows(NULL, &m, err), TS_EINVAL);
  ts_replica_free(&image);
  tear_down(&f);
}

/* A worker's anchors, built from a band of rows and the counts above it,
 * index those rows as the full set does. */
static void anchors_from_rows_agree_with_the_whole(void **state) {
  (void)state;
  feature_set f;
  set_up(&f, 17);
  char err[TS_ERR_LEN];
  int ay0 = f.a.y0 + 7, ay1 = f.a.y0 + 19;
  uint32_t above[TS_MAX_CLASSES];
  for (int c = 0; c < NCLASS; c++) above[c] = ts_anchors_above(&f.a, c, ay0);
  ts_anchors part;
  assert_int_equal(ts_anchors_init_rows(&part, &f.w, W, H, CW, CH, NCLASS, f.a.count, ay0, ay1,
                                        f.labels.px + (size_t)ay0 * W, f.valid.px + (size_t)ay0 * W, above, err),
                   0);
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) {
      int64_t want = y >= ay0 && y < ay1 ? ts_anchors_index(&f.a, x, y) : -1;
      assert_int_equal(ts_anchors_index(&part, x, y), want);
    }
  ts_anchors_free(&part);
  /* counts above that leave no room for the rows' anchors are refused */
  above[3] = f.a.count[3];
  assert_int_equal(ts_anchors_init_rows(&part, &f.w, W, H, CW, CH, NCLASS, f.a.count, ay0, ay1,
                                        f.labels.px + (size_t)ay0 * W, f.valid.px + (size_t)ay0 * W, above, err),
                   TS_EINVAL);
  assert_non_null(strstr(err, "class 3"));
  ts_anchors_free(&part);
  tear_down(&f);
}

/* m through the wire and loaded on base: the slice, or NULL with *rc
 * and err saying why; *bytes = the message's size. */
static ts_slice *send_slice(const ts_slice_desc *m, const ts_slice *base, size_t *bytes, int *rc, char *err) {
  ts_wr wr;
  ts_wr_init(&wr);
  ts_msg_slice_write(&wr, m);
  assert_int_equal(ts_wr_status(&wr), 0);
  *bytes = wr.len;
  static ts_slice_desc back;
  ts_frame fr = {'N', 1, (uint32_t)wr.len, wr.buf};
  assert_int_equal(ts_msg_slice_read(&fr, &back, err), 0);
  ts_slice *sl = NULL;
  *rc = ts_slice_load(&sl, &back, base, NULL, err);
  ts_wr_free(&wr);
  return sl;
}

/* n random 3x3 copies, counted in u and (if not NULL) in a slice. */
static void count_copies(ts_usage *u, ts_slice *sl, ts_rng *rng, int n) {
  char err[TS_ERR_LEN];
  for (int i = 0; i < n; i++) {
    ts_commit c = {(int32_t)ts_rng_below(rng, W - 3), (int32_t)ts_rng_below(rng, H - 3), 3, 3, 1};
    ts_usage_commit(u, c.x, c.y, c.w, c.h, c.delta);
    if (sl != NULL) assert_int_equal(ts_slice_commit(sl, &c, 1, err), 0);
  }
}

/* A re-slice that keeps the rows (and vectors, and usage counters) the
 * worker's previous slice holds sends only the rest, and scans exactly as
 * a slice sent whole; a base that is not the one named is refused. */
static void reslice_moves_only_what_changed(void **state) {
  (void)state;
  feature_set f;
  set_up(&f, 23);
  ts_usage u;
  assert_int_equal(ts_usage_init(&u, &f.a, 3, 0), 0);
  ts_rng rng;
  ts_rng_seed(&rng, 23, 4);
  count_copies(&u, NULL, &rng, 150);
  ts_refset rs = {0, &f.w, &f.a, &f.lp, &f.labels, &f.valid, 1, &u};
  uint32_t i0[TS_MAX_CLASSES], i1[TS_MAX_CLASSES], j0[TS_MAX_CLASSES], j1[TS_MAX_CLASSES];
  for (int c = 0; c < NCLASS; c++) {
    i0[c] = 0, i1[c] = f.a.count[c] / 2;             /* generation 1: the first half */
    j0[c] = f.a.count[c] / 4, j1[c] = f.a.count[c] * 3 / 4; /* generation 2: the middle */
  }
  char err[TS_ERR_LEN];
  int rc;
  size_t whole, delta, first;
  static ts_slice_desc m1, m2, mw;
  ts_slice_describe(&m1, &rs, &u, 1, 1, 0, i0, i1, NULL);
  ts_slice *s1 = send_slice(&m1, NULL, &first, &rc, err);
  assert_non_null(s1);
  count_copies(&u, s1, &rng, 150); /* placements the worker counted since */
  ts_slice_held held = ts_slice_held_by(&m1);
  ts_slice_describe(&m2, &rs, &u, 1, 2, 0, j0, j1, &held);
  ts_slice_describe(&mw, &rs, &u, 1, 2, 0, j0, j1, NULL);
  assert_int_equal(m2.base_gen, 1);
  assert_true(m2.kfy1 > m2.kfy0 && m2.kay1 > m2.kay0 && m2.kcy1 > m2.kcy0);
  ts_slice *s2 = send_slice(&m2, s1, &delta, &rc, err);
  if (s2 == NULL) fail_msg("delta slice: %s", err);
  ts_slice *sw = send_slice(&mw, NULL, &whole, &rc, err);
  assert_non_null(sw);
  /* the rows both read stayed on the worker: 5 fine planes + 4 bytes of
   * counters + label and validity bytes per fine row kept, and more */
  assert_true(whole - delta >= (size_t)(m2.kfy1 - m2.kfy0) * W * (NFINE + 4));
  assert_int_equal(ts_slice_vectors(s2), ts_slice_vectors(sw));
  enum { NQ = 64 };
  uint32_t vb = ts_window_bytes(&f.w);
  uint8_t *q = malloc((size_t)NQ * vb), klass[NQ];
  for (int i = 0; i < NQ; i++) {
    klass[i] = (uint8_t)(i % NCLASS);
    ts_vec_query(&f.w, &f.lp, 1, (int)ts_rng_below(&rng, W), (int)ts_rng_below(&rng, H), q + (size_t)i * vb);
  }
  const ts_l1_impl *simd;
  assert_int_equal(ts_l1_select(&simd, err), 0);
  ts_l1_best a[NQ], b[NQ];
  uint64_t pairs;
  ts_vec_batch batch = {NQ, q, NULL, klass, ts_usage_factor(&u, 4.0, ts_window_unit_distance(&f.w))};
  assert_int_equal(ts_slice_scan(s2, NULL, 1, simd, &batch, a, &pairs, err), 0);
  assert_int_equal(ts_slice_scan(sw, NULL, 1, simd, &batch, b, &pairs, err), 0);
  for (int i = 0; i < NQ; i++) {
    assert_int_equal(a[i].index, b[i].index);
    assert_int_equal(a[i].dist, b[i].dist);
  }
  /* a delta needs the very slice it names */
  ts_slice *none = send_slice(&m2, NULL, &delta, &rc, err);
  assert_null(none);
  assert_int_equal(rc, TS_EINVAL);
  assert_non_null(strstr(err, "does not hold"));
  assert_null(send_slice(&m2, sw, &delta, &rc, err)); /* generation 2, not 1 */
  assert_int_equal(rc, TS_EINVAL);
  free(q);
  ts_slice_free(s1);
  ts_slice_free(s2);
  ts_slice_free(sw);
  ts_usage_free(&u);
  tear_down(&f);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(window_lays_out_parts),
    cmocka_unit_test(window_refuses_bad_specs),
    cmocka_unit_test(anchors_order_with_256_classes),
    cmocka_unit_test(validity_from_mask_avoids_holes),
    cmocka_unit_test(sliced_labelled_set_matches_brute_force),
    cmocka_unit_test(sliced_set_without_rows_or_labels_matches_brute_force),
    cmocka_unit_test(rows_from_another_image_are_refused),
    cmocka_unit_test(anchors_from_rows_agree_with_the_whole),
    cmocka_unit_test(reslice_moves_only_what_changed),
};

TS_TEST_MAIN(tests)
