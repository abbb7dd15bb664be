/* test_checkpoint.c - checkpoint bytes: a round trip keeps everything, and
 * every kind of damage (truncation, a flipped bit, another job's tag, a
 * lying header) is refused with a reason instead of being trusted. */
#include <stdlib.h>

#include "checkpoint.h"
#include "error.h"
#include "ts_test.h"

#define W 5
#define H 3

static ts_mrf_checkpoint sample(void) {
  ts_mrf_checkpoint ck = {.level = 2, .width = W, .height = H, .nplanes = 2};
  for (int k = 0; k < 2; k++) {
    ck.planes[k] = malloc(W * H);
    for (int i = 0; i < W * H; i++) ck.planes[k][i] = (uint8_t)(17 * i + k);
  }
  ck.copy = malloc(sizeof(uint32_t) * 2 * W * H);
  for (int i = 0; i < 2 * W * H; i++) ck.copy[i] = (uint32_t)(i * 3);
  ck.stats[2].seconds = 0.25;
  ck.stats[2].pairs = 123456789012ull;
  ck.stats[3].out_w = 7;
  return ck;
}

static uint8_t *encode(const ts_mrf_checkpoint *ck, size_t *len) {
  uint8_t *buf;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_checkpoint_encode(ck, 4, 99, &buf, len, err), 0);
  return buf;
}

static void round_trip_keeps_everything(void **state) {
  (void)state;
  ts_mrf_checkpoint ck = sample(), back;
  size_t len;
  uint8_t *buf = encode(&ck, &len);
  char err[TS_ERR_LEN];
  assert_int_equal(ts_checkpoint_decode(buf, len, 99, 1000, &back, err), 0);
  assert_int_equal(back.level, 2);
  assert_int_equal(back.width, W);
  assert_int_equal(back.height, H);
  assert_int_equal(back.nplanes, 2);
  for (int k = 0; k < 2; k++) assert_memory_equal(back.planes[k], ck.planes[k], W * H);
  assert_null(back.planes[2]);
  assert_memory_equal(back.copy, ck.copy, sizeof(uint32_t) * 2 * W * H);
  assert_true(back.stats[2].seconds == 0.25);
  assert_int_equal(back.stats[2].pairs, 123456789012ull);
  assert_int_equal(back.stats[3].out_w, 7);
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
}

/* Rewrites a header field and the checksum, as a lying file would. */
static void patch(uint8_t *buf, size_t len, size_t off, uint32_t v) {
  for (int i = 0; i < 4; i++) buf[off + i] = (uint8_t)(v >> (8 * i));
  uint64_t h = 0xcbf29ce484222325ull; /* FNV-1a 64, as the format says */
  for (size_t i = 0; i < len - 8; i++) h = (h ^ buf[i]) * 0x100000001b3ull;
  for (int i = 0; i < 8; i++) buf[len - 8 + i] = (uint8_t)(h >> (8 * i));
}

static void damage_is_refused(void **state) {
  (void)state;
  ts_mrf_checkpoint ck = sample();
  size_t len;
  uint8_t *buf = encode(&ck, &len);
  refuse(buf, 0, 99, 1000, "truncated");
  refuse(buf, len - 1, 99, 1000, "truncated");
  for (size_t bit = 0; bit < len * 8; bit += 37) {
    buf[bit / 8] ^= (uint8_t)(1u << (bit % 8));
    refuse(buf, len, 99, 1000, "damaged");
    buf[bit / 8] ^= (uint8_t)(1u << (bit % 8));
  }
  refuse(buf, len, 98, 1000, "another job");
  refuse(buf, len, 99, 10, "outside 1..10 pixels");
  uint8_t *copy = malloc(len);
  struct { size_t off; uint32_t v; const char *reason; } lies[] = {
      {0, 0x12345678, "not a texsyn checkpoint"},
      {4, 2, "format 2"},
      {16, 0, "level 0"},
      {16, 11, "level 11"},
      {20, 1u << 31, "outside"},
      {24, 0, "outside"},
      {28, 5, "5 planes"},
      {32, 0, "0 levels"},
      {20, W + 1, "length does not match"},
  };
  for (size_t i = 0; i < sizeof(lies) / sizeof(lies[0]); i++) {
    memcpy(copy, buf, len);
    patch(copy, len, lies[i].off, lies[i].v);
    refuse(copy, len, 99, 1u << 30, lies[i].reason);
  }
  free(copy);
  ts_checkpoint_free(&ck);
  free(buf);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(round_trip_keeps_everything),
    cmocka_unit_test(damage_is_refused),
};

TS_TEST_MAIN(tests)
