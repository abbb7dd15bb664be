/* test_fill.c - constrained synthesis (fill.h): the masked pyramid, query
 * images with given and unknown pixels and no torus, the puzzle queue's
 * steps, and whole fills that must not depend on threads or batches. */
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "fill.h"
#include "fill_queue.h"
#include "neigh.h"
#include "plane.h"
#include "replica.h"
#include "rng.h"
#include "search.h"
#include "ts_test.h"
#include "window.h"

/* A hole (mask 0) neither darkens nor spreads into the levels above. */
static void masked_reduce_keeps_holes_out(void **state) {
  (void)state;
  ts_plane src, mask, dst, dmask;
  assert_int_equal(ts_plane_alloc(&src, 17, 16), 0);
  assert_int_equal(ts_plane_alloc(&mask, 17, 16), 0);
  for (int y = 0; y < 16; y++)
    for (int x = 0; x < 17; x++) {
      int hole = x >= 5 && x < 11 && y >= 4 && y < 9;
      src.px[y * 17 + x] = hole ? 0 : 100;
      mask.px[y * 17 + x] = !hole;
    }
  assert_int_equal(ts_plane_reduce_masked(&src, &mask, 1, &dst), 0);
  assert_int_equal(dst.w, 9);
  assert_int_equal(dst.h, 8);
  for (int y = 0; y < dst.h; y++)
    for (int x = 0; x < dst.w; x++) { /* 100, or 0 where all 5 x 5 taps lie in the hole */
      int all_hole = 2 * x - 2 >= 5 && 2 * x + 2 < 11 && 2 * y - 2 >= 4 && 2 * y + 2 < 9;
      assert_int_equal(dst.px[y * dst.w + x], all_hole ? 0 : 100);
    }
  assert_int_equal(ts_plane_reduce_all(&mask, 1, &dmask), 0);
  for (int y = 0; y < dmask.h; y++)
    for (int x = 0; x < dmask.w; x++) {
      int touches = 2 * x + 1 >= 5 && 2 * x < 11 && 2 * y + 1 >= 4 && 2 * y < 9;
      assert_int_equal(dmask.px[y * dmask.w + x], !touches);
    }
  ts_plane_free(&src);
  ts_plane_free(&mask);
  ts_plane_free(&dst);
  ts_plane_free(&dmask);
}

/* A placement writes free (and placed) pixels only; an image without a copy
 * map refuses a block placed twice. */
static void placements_keep_fixed_and_closed_pixels(void **state) {
  (void)state;
  uint8_t fine[36], done[36], ref[16];
  for (int i = 0; i < 36; i++) fine[i] = 7, done[i] = TS_DONE_FREE;
  for (int i = 0; i < 16; i++) ref[i] = (uint8_t)(200 + i);
  done[0] = TS_DONE_FIXED;  /* (0, 0) */
  done[8] = TS_DONE_CLOSED; /* (2, 1) */
  ts_replica_desc d = {.w = 6, .h = 6, .nplanes = 1, .bounded = 1, .done = done, .block = 3, .rw = 4, .rh = 4};
  d.fine[0] = fine;
  d.ref[0] = ref;
  ts_replica r;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_replica_init(&r, &d, err), 0);
  ts_place p = {0, 1}; /* block (0, 0) from reference (1, 0) */
  ts_commit c[2];
  uint32_t nc;
  assert_int_equal(ts_replica_place(&r, &p, 1, c, &nc, err), 0);
  assert_int_equal(nc, 1);
  for (int y = 0; y < 3; y++)
    for (int x = 0; x < 3; x++) {
      int o = y * 6 + x;
      if (o == 0 || o == 8) {
        assert_int_equal(r.fine[0].px[o], 7);
        assert_int_equal(r.done[o], o == 0 ? TS_DONE_FIXED : TS_DONE_CLOSED);
      } else {
        assert_int_equal(r.fine[0].px[o], ref[y * 4 + x + 1]);
        assert_int_equal(r.done[o], TS_DONE_PLACED);
      }
    }
  p.dst = 7; /* (1, 1): placed already */
  assert_int_equal(ts_replica_place(&r, &p, 1, c, &nc, err), TS_EINVAL);
  ts_replica_free(&r);
  done[3] = 9;
  assert_int_equal(ts_replica_init(&r, &d, err), TS_EINVAL);
}

/* Bounded: no offset wraps, and none outside counts; a fixed pixel inside
 * the block counts, a placed one does not. */
static void bounded_queries_do_not_wrap(void **state) {
  (void)state;
  ts_window w;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_neigh_window(&w, TS_SHAPE_FREE, 5, 1, 0, 1, 1.0, err), 0);
  ts_plane p;
  assert_int_equal(ts_plane_alloc(&p, 8, 8), 0);
  for (int i = 0; i < 64; i++) p.px[i] = (uint8_t)(i + 1);
  ts_levelplanes lp = {.fine = {&p}};
  uint8_t v[TS_L1_MAX_CHUNKS * TS_L1_CHUNK], m[TS_L1_MAX_CHUNKS * TS_L1_CHUNK];
  ts_vec_query(&w, &lp, 0, 0, 0, v);
  assert_int_equal(v[0], 0);      /* (-2, -2) */
  assert_int_equal(v[12], 1);     /* (0, 0) */
  assert_int_equal(v[24], 8 * 2 + 3); /* (2, 2) */
  ts_vec_query(&w, &lp, 1, 0, 0, v);
  assert_int_equal(v[0], 64 - 8 - 1); /* (6, 6) on the torus */
  uint8_t done[64];
  memset(done, TS_DONE_PLACED, sizeof(done));
  done[0] = TS_DONE_FIXED;
  ts_vec_mask(&w, done, 8, 8, 0, 0, 0, m);
  for (int k = 0; k < 25; k++) {
    int dx = k % 5 - 2, dy = k / 5 - 2;
    int want = dx == 0 && dy == 0 ? 1 : dx >= 0 && dy >= 0;
    assert_int_equal(m[k] != 0, want);
  }
  done[0] = TS_DONE_PLACED;
  ts_vec_mask(&w, done, 8, 8, 0, 0, 0, m);
  assert_int_equal(m[12], 0);
  ts_plane_free(&p);
  ts_window_free(&w);
}

/* Blocks of a step lie outside each other's windows; every block of the
 * class is taken once; the first step takes the best known. */
static void queue_steps_are_independent_and_complete(void **state) {
  (void)state;
  enum { W = 61, H = 47 };
  uint8_t st[W * H], done[W * H];
  ts_rng rng;
  ts_rng_seed(&rng, 5, 0);
  for (int i = 0; i < W * H; i++) {
    int x = i % W, y = i / W;
    st[i] = (x - 30) * (x - 30) + (y - 20) * (y - 20) < 300 ? 1 : (ts_rng_below(&rng, 9) == 0 ? 2 : 0);
    done[i] = st[i] == 0 ? TS_DONE_FIXED : st[i] == 1 ? TS_DONE_FREE : TS_DONE_CLOSED;
  }
  ts_fill_params p;
  ts_fill_params_default(&p);
  ts_fill_queue q;
  assert_int_equal(ts_fill_queue_init(&q, done, st, 1, W, H, &p), 0);
  uint64_t want = ts_fill_class_blocks(st, W, H, 1, p.wb), taken = 0;
  assert_int_equal(q.queued, want);
  uint8_t *seen = calloc(q.nblocks, 1);
  int first = 1;
  while (!ts_fill_queue_empty(&q)) {
    const uint32_t *b;
    uint32_t n;
    assert_int_equal(ts_fill_queue_step(&q, 1, &b, &n), 1);
    assert_true(n > 0);
    int top = 0;
    for (uint32_t i = 0; i < q.nblocks; i++)
      if (q.prev[i] != -2 && q.count[i] > top) top = q.count[i];
    for (uint32_t i = 0; i < n; i++) {
      if (first) assert_true(q.count[b[i]] >= top - p.wn);
      for (uint32_t j = i + 1; j < n; j++) {
        int dx = abs((int)(b[i] % (uint32_t)q.bw) - (int)(b[j] % (uint32_t)q.bw));
        int dy = abs((int)(b[i] / (uint32_t)q.bw) - (int)(b[j] / (uint32_t)q.bw));
        assert_true(dx > q.r || dy > q.r);
      }
    }
    first = 0;
    for (uint32_t i = 0; i < n; i++) {
      int x, y;
      ts_fill_queue_block_xy(&q, b[i], &x, &y);
      for (int yy = y; yy < y + p.wb && yy < H; yy++)
        for (int xx = x; xx < x + p.wb && xx < W; xx++)
          if (done[yy * W + xx] == TS_DONE_FREE) done[yy * W + xx] = TS_DONE_PLACED;
      assert_int_equal(seen[b[i]], 0);
      seen[b[i]] = 1;
      taken++;
      ts_fill_queue_placed(&q, b[i], done);
    }
  }
  assert_int_equal(taken, want);
  for (int i = 0; i < W * H; i++) assert_int_not_equal(done[i], TS_DONE_FREE);
  free(seen);
  ts_fill_queue_free(&q);
}

/* A smooth random texture, w x h. */
static void texture(uint8_t *px, int w, int h, uint64_t seed) {
  ts_rng rng;
  ts_rng_seed(&rng, seed, 0);
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++)
      px[y * w + x] = (uint8_t)(((x / 4 + y / 3) % 5) * 40 + ts_rng_below(&rng, 30));
}

enum { FW = 96, FH = 88 };
typedef struct {
  uint8_t img[FW * FH], st[FW * FH], usable[FW * FH];
  ts_fill_class cls;
  ts_fill_input in;
} hole_job;

/* A texture with a hole in the middle and one touching the left edge. */
static void hole_job_init(hole_job *j) {
  texture(j->img, FW, FH, 3);
  for (int i = 0; i < FW * FH; i++) {
    int x = i % FW, y = i / FW;
    j->st[i] = (x >= 25 && x < 45 && y >= 20 && y < 37) || (x < 6 && y >= 40 && y < 52);
    j->usable[i] = !j->st[i];
  }
  memset(&j->cls, 0, sizeof(j->cls));
  j->cls.nsources = 1;
  j->cls.src[0] = (ts_fill_source){.w = FW, .h = FH, .planes = {j->img}, .usable = j->usable};
  j->in = (ts_fill_input){.w = FW, .h = FH, .nplanes = 1, .planes = {j->img}, .state = j->st, .nclass = 1, .cls = &j->cls};
}

static void fill_with(const hole_job *j, int threads, uint32_t max_batch, int order, ts_fill_result *res) {
  ts_fill_params p;
  ts_fill_params_default(&p);
  p.levels = 3;
  p.wn = 7;
  p.max_batch = max_batch;
  p.order = order;
  ts_search *s;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_search_local_create(&s, threads, NULL, err), 0);
  ts_search_local_set_inline(s, 0);
  int rc = ts_fill_synthesize(&p, &j->in, s, NULL, res, err);
  if (rc != 0) fprintf(stderr, "%s\n", err);
  assert_int_equal(rc, 0);
  ts_search_destroy(s);
}

/* Given pixels keep their values, holes are filled from usable pixels,
 * and neither threads nor batch sizes change a byte. */
static void fill_is_the_same_whatever_the_threads_and_batches(void **state) {
  (void)state;
  hole_job *j = malloc(sizeof(*j));
  hole_job_init(j);
  for (int order = TS_FILL_PUZZLE; order <= TS_FILL_THRESHOLD; order++) {
    ts_fill_result a, b;
    fill_with(j, 1, 0, order, &a);
    fill_with(j, 2, 3, order, &b);
    assert_memory_equal(a.planes[0], b.planes[0], FW * FH);
    assert_memory_equal(a.copy, b.copy, sizeof(uint32_t) * 2 * FW * FH);
    for (int i = 0; i < FW * FH; i++) {
      if (!j->st[i]) {
        assert_int_equal(a.planes[0][i], j->img[i]);
        assert_int_equal(a.source[i], TS_FILL_NO_SOURCE);
        continue;
      }
      int sx = (int)a.copy[2 * i], sy = (int)a.copy[2 * i + 1];
      assert_int_equal(a.source[i], 0);
      assert_true(j->usable[sy * FW + sx]);
      assert_int_equal(a.planes[0][i], j->img[sy * FW + sx]);
    }
    ts_fill_result_free(&a);
    ts_fill_result_free(&b);
  }
  free(j);
}

/* With nothing given, the coarsest level starts from a seeded block. */
static void areas_without_context_are_seeded(void **state) {
  (void)state;
  hole_job *j = malloc(sizeof(*j));
  hole_job_init(j);
  memset(j->st, 1, sizeof(j->st));
  static uint8_t ref[40 * 40];
  texture(ref, 40, 40, 9);
  j->cls.src[0] = (ts_fill_source){.w = 40, .h = 40, .planes = {ref}};
  ts_fill_result r;
  fill_with(j, 2, 0, TS_FILL_PUZZLE, &r);
  assert_int_equal(r.level[2].seeds, 1);
  for (int i = 0; i < FW * FH; i++) assert_int_equal(r.planes[0][i], ref[r.copy[2 * i + 1] * 40 + r.copy[2 * i]]);
  ts_fill_result_free(&r);
  free(j);
}

/* ---- the seam cut (fill_seams.h) ---- */

#define SW 12
#define SH 4
#define RW 40
#define SU0 6 /* the seam: columns < SU0 copy from (LX + x, LY + y), the rest from (RX + x, RY + y) */
#define LX 3
#define LY 5
#define RX 20
#define RY 22

typedef struct {
  uint8_t ref[RW * RW], img[SW * SH], cls[SW * SH], movable[SW * SH];
  uint32_t copy[2 * SW * SH];
  ts_seam_ref sref[2]; /* two classes with the same reference */
  int y0, h0;
} seam_job;

/* A seam whose copies agree at columns SU0 and SU0 + 1 and nowhere else
 * near: the left copy gone on one pixel past the edge is the join of least
 * cost (0), so the cut moves there, or stays when the left side's copy may
 * not go on (shift < 0: the right copy would have to go back instead). */
static void seam_job_init(seam_job *j, int left_movable) {
  ts_rng rng;
  ts_rng_seed(&rng, 77, 0);
  for (int i = 0; i < RW * RW; i++) j->ref[i] = (uint8_t)ts_rng_below(&rng, 256);
  for (int y = 0; y < SH; y++)
    for (int d = 0; d <= 1; d++) j->ref[(LY + y) * RW + LX + SU0 + d] = j->ref[(RY + y) * RW + RX + SU0 + d];
  for (int y = 0; y < SH; y++)
    for (int x = 0; x < SW; x++) {
      int i = y * SW + x, left = x < SU0;
      j->copy[2 * i] = (uint32_t)(left ? LX + x : RX + x);
      j->copy[2 * i + 1] = (uint32_t)(left ? LY + y : RY + y);
      j->img[i] = j->ref[j->copy[2 * i + 1] * RW + j->copy[2 * i]];
      j->cls[i] = 1;
      j->movable[i] = !left || left_movable;
    }
  j->y0 = 0;
  j->h0 = RW;
  j->sref[0] = j->sref[1] = (ts_seam_ref){RW, RW, {j->ref}, NULL, 1, &j->y0, &j->h0};
}

static void cut(seam_job *j, int reach, uint64_t *moved) {
  ts_seam_image im = {SW, SH, 1, {j->img}, j->copy, j->cls, j->movable, j->sref, reach};
  assert_int_equal(ts_fill_cut_seams(&im, moved), 0);
  for (int i = 0; i < SW * SH; i++) /* every pixel still the copy its map says */
    assert_int_equal(j->img[i], j->ref[j->copy[2 * i + 1] * RW + j->copy[2 * i]]);
}

static void seam_cut_moves_to_the_join_of_least_cost(void **state) {
  (void)state;
  seam_job *j = malloc(sizeof(*j));
  for (int left_movable = 0; left_movable <= 1; left_movable++) {
    seam_job_init(j, left_movable);
    uint64_t moved;
    cut(j, 2, &moved);
    assert_int_equal(moved, SH);
    for (int y = 0; y < SH; y++)
      for (int x = 0; x < SW; x++) { /* column SU0 now goes on from the left */
        int i = y * SW + x, left = x <= SU0;
        assert_int_equal(j->copy[2 * i], (uint32_t)(left ? LX + x : RX + x));
        assert_int_equal(j->copy[2 * i + 1], (uint32_t)(left ? LY + y : RY + y));
      }
  }
  free(j);
}

/* Pixels the cut may not change keep their copies; reach 0 changes none. */
static void seam_cut_keeps_what_may_not_move(void **state) {
  (void)state;
  seam_job *j = malloc(sizeof(*j));
  seam_job_init(j, 1);
  memset(j->movable + SU0, 0, SW - SU0); /* row 0's right side given */
  for (int y = 1; y < SH; y++) j->cls[y * SW + SU0] = 2; /* another class: no seam, nothing to take */
  uint32_t before[2 * SW * SH];
  memcpy(before, j->copy, sizeof(before));
  uint64_t moved;
  ts_seam_image im = {SW, SH, 1, {j->img}, j->copy, j->cls, j->movable, j->sref, 0};
  assert_int_equal(ts_fill_cut_seams(&im, &moved), 0);
  assert_int_equal(moved, 0);
  assert_memory_equal(before, j->copy, sizeof(before));
  cut(j, 2, &moved);
  for (int x = SU0; x < SW; x++) { /* given, and the other class's */
    assert_int_equal(j->copy[2 * x], before[2 * x]);
    for (int y = 1; y < SH; y++) assert_int_equal(j->copy[2 * (y * SW + SU0)], before[2 * (y * SW + SU0)]);
  }
  free(j);
}

/* Every problem at once, in words a user can act on. */
static void check_names_every_problem(void **state) {
  (void)state;
  hole_job *j = malloc(sizeof(*j));
  hole_job_init(j);
  ts_fill_params p;
  ts_fill_params_default(&p);
  p.wn = 8;
  p.threshold = 0;
  char msg[1024];
  assert_int_equal(ts_fill_check(&p, &j->in, NULL, msg, sizeof(msg)), TS_EINVAL);
  assert_non_null(strstr(msg, "--wn 8"));
  assert_non_null(strstr(msg, "--threshold 0"));
  p.wn = 9;
  p.threshold = 0.25;
  p.levels = 6;
  const char *names[] = {"forest"};
  assert_int_equal(ts_fill_check(&p, &j->in, names, msg, sizeof(msg)), TS_EINVAL);
  assert_non_null(strstr(msg, "class forest"));
  assert_non_null(strstr(msg, "fewer --levels"));
  free(j);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(masked_reduce_keeps_holes_out),
    cmocka_unit_test(placements_keep_fixed_and_closed_pixels),
    cmocka_unit_test(bounded_queries_do_not_wrap),
    cmocka_unit_test(queue_steps_are_independent_and_complete),
    cmocka_unit_test(fill_is_the_same_whatever_the_threads_and_batches),
    cmocka_unit_test(areas_without_context_are_seeded),
    cmocka_unit_test(check_names_every_problem),
    cmocka_unit_test(seam_cut_moves_to_the_join_of_least_cost),
    cmocka_unit_test(seam_cut_keeps_what_may_not_move),
};

TS_TEST_MAIN(tests)
