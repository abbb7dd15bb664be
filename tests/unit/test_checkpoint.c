/* test_checkpoint.c - checkpoint bytes: a round trip keeps everything, at a
 * level's end and inside a level, and every kind of damage (truncation, a
 * flipped bit, another job's tag, a lying header, a step out of range, the
 * previous format) is refused with a reason instead of being trusted. */
#include <stdlib.h>

#include "checkpoint.h"
#include "error.h"
#include "ts_test.h"

#define W 5
#define H 3
#define CW 3 /* the level above */
#define CH 2
#define RW 6 /* the level's reference */
#define RH 4
#define LEVELS 4

/* Header offsets of format 2 (checkpoint.c). */
enum {
  OFF_VERSION = 4, OFF_INTERVAL = 24, OFF_LEVEL = 32, OFF_STEP = 36, OFF_STEPS = 44, OFF_WIDTH = 52,
  OFF_PLANES = 60, OFF_NSTATS = 64, OFF_CW = 68, OFF_RW = 76
};

static uint8_t *pattern(size_t n, int seed) {
  uint8_t *p = malloc(n);
  for (size_t i = 0; i < n; i++) p[i] = (uint8_t)(17 * i + (size_t)seed);
  return p;
}

/* Level 2 of 4: finished (step == steps), or inside it at step 17 of 40. */
static ts_mrf_checkpoint sample(int inside) {
  ts_mrf_checkpoint ck = {.level = 2, .step = inside ? 17 : 40, .steps = 40, .saved_at = 1.7e9 + 0.125,
                          .interval = 0.2, .width = W, .height = H, .nplanes = 2};
  for (int k = 0; k < 2; k++) ck.planes[k] = pattern(W * H, k);
  ck.copy = malloc(sizeof(uint32_t) * 2 * W * H);
  for (int i = 0; i < 2 * W * H; i++) ck.copy[i] = (uint32_t)(i * 3);
  if (inside) {
    ck.done = calloc(W * H, 1);
    ck.done[4] = 1;
    ck.coarse_width = CW;
    ck.coarse_height = CH;
    for (int k = 0; k < 2; k++) ck.coarse[k] = pattern(CW * CH, 5 + k);
    ck.ref_width = RW;
    ck.ref_height = RH;
    ck.usage = calloc(RW * RH, sizeof(uint32_t));
    ck.usage[7] = 9;
  }
  ck.stats[2].seconds = 0.25;
  ck.stats[2].pairs = 123456789012ull;
  ck.stats[2].steps = ck.step;
  ck.stats[3].out_w = 7;
  return ck;
}

static uint8_t *encode(const ts_mrf_checkpoint *ck, size_t *len) {
  uint8_t *buf;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_checkpoint_encode(ck, LEVELS, 99, &buf, len, err), 0);
  return buf;
}

static void assert_same(const ts_mrf_checkpoint *a, const ts_mrf_checkpoint *b) {
  assert_int_equal(a->level, b->level);
  assert_int_equal(a->step, b->step);
  assert_int_equal(a->steps, b->steps);
  assert_true(a->saved_at == b->saved_at && a->interval == b->interval);
  assert_int_equal(a->width, b->width);
  assert_int_equal(a->height, b->height);
  assert_int_equal(a->nplanes, b->nplanes);
  for (int k = 0; k < a->nplanes; k++) assert_memory_equal(a->planes[k], b->planes[k], W * H);
  assert_null(b->planes[2]);
  assert_memory_equal(a->copy, b->copy, sizeof(uint32_t) * 2 * W * H);
  assert_true(a->stats[2].seconds == b->stats[2].seconds);
  assert_int_equal(a->stats[2].pairs, b->stats[2].pairs);
  assert_int_equal(a->stats[3].out_w, b->stats[3].out_w);
  assert_int_equal(a->coarse_width, b->coarse_width);
  assert_int_equal(a->ref_width, b->ref_width);
  if (a->done == NULL) {
    assert_null(b->done);
    assert_null(b->usage);
    assert_null(b->coarse[0]);
    return;
  }
  assert_memory_equal(a->done, b->done, W * H);
  for (int k = 0; k < a->nplanes; k++) assert_memory_equal(a->coarse[k], b->coarse[k], CW * CH);
  assert_memory_equal(a->usage, b->usage, sizeof(uint32_t) * RW * RH);
}

static void round_trip_keeps_everything(void **state) {
  (void)state;
  for (int inside = 0; inside < 2; inside++) {
    ts_mrf_checkpoint ck = sample(inside), back;
    size_t len;
    uint8_t *buf = encode(&ck, &len);
    char err[TS_ERR_LEN];
    assert_int_equal(ts_checkpoint_decode(buf, len, 99, 1000, &back, err), 0);
    assert_same(&ck, &back);
    ts_checkpoint_free(&back);
    ts_checkpoint_free(&ck);
    free(buf);
  }
}

/* Inside the coarsest level there is no level above: no coarse canvas. */
static void inside_the_coarsest_level(void **state) {
  (void)state;
  ts_mrf_checkpoint ck = sample(1), back;
  ck.level = LEVELS - 1;
  for (int k = 0; k < 2; k++) {
    free(ck.coarse[k]);
    ck.coarse[k] = NULL;
  }
  ck.coarse_width = ck.coarse_height = 0;
  ck.stats[LEVELS - 1].steps = ck.step;
  size_t len;
  uint8_t *buf = encode(&ck, &len);
  char err[TS_ERR_LEN];
  assert_int_equal(ts_checkpoint_decode(buf, len, 99, 1000, &back, err), 0);
  assert_int_equal(back.level, LEVELS - 1);
  assert_null(back.coarse[0]);
  assert_memory_equal(back.usage, ck.usage, sizeof(uint32_t) * RW * RH);
  ts_checkpoint_free(&back);
  ts_checkpoint_free(&ck);
  free(buf);
}

static void refuse(const uint8_t *buf, size_t len, uint64_t tag, uint64_t max_pixels, const char *reason) {
  ts_mrf_checkpoint ck;
  char err[TS_ERR_LEN] = "";
  assert_int_equal(ts_checkpoint_decode(buf, len, tag, max_pixels, &ck, err), TS_EPROTO);
  if (strstr(err, reason) == NULL) fail_msg("expected '%s' in '%s'", reason, err);
  assert_null(ck.copy);
  assert_null(ck.done);
}

static void fix_checksum(uint8_t *buf, size_t len) {
  uint64_t h = 0xcbf29ce484222325ull; /* FNV-1a 64, as the format says */
  for (size_t i = 0; i < len - 8; i++) h = (h ^ buf[i]) * 0x100000001b3ull;
  for (int i = 0; i < 8; i++) buf[len - 8 + i] = (uint8_t)(h >> (8 * i));
}

/* Rewrites a 32-bit field and the checksum, as a lying file would. */
static void patch(uint8_t *buf, size_t len, size_t off, uint32_t v) {
  for (int i = 0; i < 4; i++) buf[off + i] = (uint8_t)(v >> (8 * i));
  fix_checksum(buf, len);
}

typedef struct {
  size_t off;
  uint32_t v;
  const char *reason;
} lie;

static void refuse_lies(const uint8_t *buf, size_t len, const lie *lies, size_t n) {
  uint8_t *copy = malloc(len);
  for (size_t i = 0; i < n; i++) {
    memcpy(copy, buf, len);
    patch(copy, len, lies[i].off, lies[i].v);
    refuse(copy, len, 99, 1u << 30, lies[i].reason);
  }
  free(copy);
}

static void refuse_damage(const uint8_t *buf, size_t len) {
  uint8_t *copy = malloc(len);
  memcpy(copy, buf, len);
  refuse(copy, 0, 99, 1000, "truncated");
  refuse(copy, len - 1, 99, 1000, "truncated");
  refuse(copy, len / 2, 99, 1000, "truncated");
  for (size_t bit = 0; bit < len * 8; bit += 37) {
    copy[bit / 8] ^= (uint8_t)(1u << (bit % 8));
    refuse(copy, len, 99, 1000, "damaged");
    copy[bit / 8] ^= (uint8_t)(1u << (bit % 8));
  }
  refuse(copy, len, 98, 1000, "another job");
  refuse(copy, len, 99, 10, "outside 1..10 pixels");
  free(copy);
}

static void damage_is_refused(void **state) {
  (void)state;
  for (int inside = 0; inside < 2; inside++) {
    ts_mrf_checkpoint ck = sample(inside);
    size_t len;
    uint8_t *buf = encode(&ck, &len);
    refuse_damage(buf, len);
    const lie common[] = {
        {0, 0x12345678, "not a texsyn checkpoint"},
        {OFF_VERSION, 3, "format 3"},
        {OFF_LEVEL, 11, "level 11"},
        {OFF_STEP, 41, "step 41 of 40"},
        {OFF_STEPS, 0, "step"},
        {OFF_INTERVAL + 4, 0x7ff80000, "interval nan"},
        {OFF_WIDTH, 1u << 31, "outside"},
        {OFF_WIDTH, 0, "outside"},
        {OFF_PLANES, 5, "5 planes"},
        {OFF_NSTATS, 0, "0 levels"},
        {OFF_WIDTH, W + 1, "length does not match"},
    };
    refuse_lies(buf, len, common, sizeof(common) / sizeof(common[0]));
    free(buf);
    ts_checkpoint_free(&ck);
  }
}

/* The sizes that only a checkpoint inside a level has must agree with the
 * rest: none at a level's end, a level above unless it is the coarsest. */
static void lying_inside_sizes_are_refused(void **state) {
  (void)state;
  ts_mrf_checkpoint end = sample(0), in = sample(1);
  size_t len_end, len_in;
  uint8_t *buf_end = encode(&end, &len_end), *buf_in = encode(&in, &len_in);
  const lie at_end[] = {
      {OFF_LEVEL, 0, "after level 0"},
      {OFF_RW, RW, "sizes of one inside it"},
      {OFF_CW, CW, "sizes of one inside it"},
  };
  refuse_lies(buf_end, len_end, at_end, sizeof(at_end) / sizeof(at_end[0]));
  const lie inside[] = {
      {OFF_STEP, 40, "sizes of one inside it"}, /* claims the level is finished */
      {OFF_RW, 0, "reference 0x4"},
      {OFF_RW, 1u << 31, "outside"},
      {OFF_CW, 0, "coarse canvas 0x2"},
      {OFF_CW, CW + 1, "length does not match"},
      {OFF_RW, RW + 1, "length does not match"},
      {OFF_NSTATS, 1, "coarsest level with a 3x2 level above"},
  };
  refuse_lies(buf_in, len_in, inside, sizeof(inside) / sizeof(inside[0]));
  free(buf_end);
  free(buf_in);
  ts_checkpoint_free(&end);
  ts_checkpoint_free(&in);
}

/* A spool written by a build before checkpoints inside levels (format 1,
 * a 36-byte header) is refused by its version, whatever its length: the
 * job then starts over. */
static void format_1_is_refused(void **state) {
  (void)state;
  uint8_t v1[36 + 8] = {'T', 'S', 'C', 'K', 1, 0, 0, 0};
  fix_checksum(v1, sizeof(v1));
  refuse(v1, sizeof(v1), 99, 1000, "checkpoint format 1, this build reads 2");
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(round_trip_keeps_everything),
    cmocka_unit_test(inside_the_coarsest_level),
    cmocka_unit_test(damage_is_refused),
    cmocka_unit_test(lying_inside_sizes_are_refused),
    cmocka_unit_test(format_1_is_refused),
};

TS_TEST_MAIN(tests)
