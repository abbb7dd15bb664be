/* test_frame.c - wire framing: whole frames from any split of the byte
 * stream, strict header checks, bounds-checked payload cursor. */
#include <stdlib.h>

#include "error.h"
#include "frame.h"
#include "ts_test.h"

/* Appends one frame (header + payload) to a buffer. */
static size_t put_frame(uint8_t *out, uint8_t type, uint32_t id, const char *payload) {
  size_t n = strlen(payload);
  ts_frame_header(out, type, id, (uint32_t)n);
  memcpy(out + TS_FRAME_HEADER, payload, n);
  return TS_FRAME_HEADER + n;
}

static void header_layout_is_little_endian(void **state) {
  (void)state;
  uint8_t h[TS_FRAME_HEADER];
  ts_frame_header(h, 'V', 0x01020304, 0x0a0b0c0d);
  const uint8_t want[TS_FRAME_HEADER] = {'T', 'S', TS_PROTO_VERSION, 'V', 0x0d, 0x0c,
                                         0x0b, 0x0a, 0x04, 0x03, 0x02, 0x01};
  assert_memory_equal(h, want, TS_FRAME_HEADER);
}

/* Three frames fed one byte at a time come out whole, in order. */
static void frames_survive_one_byte_writes(void **state) {
  (void)state;
  uint8_t stream[256];
  size_t n = put_frame(stream, 'I', 1, "hello");
  n += put_frame(stream + n, 'H', 2, "");
  n += put_frame(stream + n, 'V', 3, "0123456789abcdef");
  ts_frame_reader r;
  ts_frame_reader_init(&r, 0);
  const char *want[] = {"hello", "", "0123456789abcdef"};
  int got = 0;
  char err[TS_ERR_LEN];
  for (size_t i = 0; i < n; i++) {
    assert_int_equal(ts_frame_reader_feed(&r, stream + i, 1), 0);
    ts_frame f;
    int rc;
    while ((rc = ts_frame_reader_next(&r, &f, err)) == 1) {
      assert_int_equal(f.id, (uint32_t)got + 1);
      assert_int_equal(f.len, strlen(want[got]));
      assert_memory_equal(f.payload, want[got], f.len);
      got++;
    }
    assert_int_equal(rc, 0);
  }
  assert_int_equal(got, 3);
  ts_frame_reader_free(&r);
}

static void many_frames_in_one_read(void **state) {
  (void)state;
  uint8_t stream[64 * 20];
  size_t n = 0;
  for (int i = 0; i < 50; i++) n += put_frame(stream + n, 'V', (uint32_t)i, "abc");
  ts_frame_reader r;
  ts_frame_reader_init(&r, 0);
  assert_int_equal(ts_frame_reader_feed(&r, stream, n), 0);
  ts_frame f;
  char err[TS_ERR_LEN];
  for (int i = 0; i < 50; i++) {
    assert_int_equal(ts_frame_reader_next(&r, &f, err), 1);
    assert_int_equal(f.id, (uint32_t)i);
  }
  assert_int_equal(ts_frame_reader_next(&r, &f, err), 0);
  ts_frame_reader_free(&r);
}

static void truncated_frame_waits_for_more(void **state) {
  (void)state;
  uint8_t stream[64];
  size_t n = put_frame(stream, 'N', 9, "payload");
  ts_frame_reader r;
  ts_frame_reader_init(&r, 0);
  assert_int_equal(ts_frame_reader_feed(&r, stream, n - 1), 0);
  ts_frame f;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_frame_reader_next(&r, &f, err), 0);
  assert_int_equal(ts_frame_reader_feed(&r, stream + n - 1, 1), 0);
  assert_int_equal(ts_frame_reader_next(&r, &f, err), 1);
  assert_memory_equal(f.payload, "payload", 7);
  ts_frame_reader_free(&r);
}

static void bad_headers_are_errors(void **state) {
  (void)state;
  char err[TS_ERR_LEN] = "";
  ts_frame f;
  uint8_t h[TS_FRAME_HEADER];
  struct { int byte; uint8_t value; int code; const char *needle; } cases[] = {
      {0, 'X', TS_EPROTO, "magic"},
      {2, TS_PROTO_VERSION + 1, TS_EPROTO, "version"},
      {7, 0xff, TS_ETOOBIG, "exceeds the limit"}, /* length ~4 GiB */
  };
  for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
    ts_frame_header(h, 'V', 1, 4);
    h[cases[i].byte] = cases[i].value;
    ts_frame_reader r;
    ts_frame_reader_init(&r, 1024);
    assert_int_equal(ts_frame_reader_feed(&r, h, sizeof(h)), 0);
    assert_int_equal(ts_frame_reader_next(&r, &f, err), cases[i].code);
    assert_non_null(strstr(err, cases[i].needle));
    ts_frame_reader_free(&r);
  }
}

static void payload_limit_is_inclusive(void **state) {
  (void)state;
  ts_frame_reader r;
  ts_frame_reader_init(&r, 8);
  uint8_t stream[64];
  size_t n = put_frame(stream, 'V', 1, "12345678");
  n += put_frame(stream + n, 'V', 2, "123456789");
  assert_int_equal(ts_frame_reader_feed(&r, stream, n), 0);
  ts_frame f;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_frame_reader_next(&r, &f, err), 1);
  assert_int_equal(ts_frame_reader_next(&r, &f, err), TS_ETOOBIG);
  ts_frame_reader_free(&r);
}

static void cursor_is_bounds_checked_and_sticky(void **state) {
  (void)state;
  const uint8_t p[] = {1, 2, 0, 3, 0, 0, 0, 9};
  ts_rd r;
  ts_rd_init(&r, p, sizeof(p));
  assert_int_equal(ts_rd_u8(&r), 1);
  assert_int_equal(ts_rd_u16(&r), 2);
  assert_int_equal(ts_rd_u32(&r), 3);
  assert_int_equal(ts_rd_done(&r, 1), TS_EPROTO); /* one byte left */
  assert_int_equal(ts_rd_done(&r, 0), 0);
  assert_int_equal(ts_rd_u16(&r), 0); /* past the end */
  assert_int_equal(ts_rd_u8(&r), 0);  /* sticky, even though a byte is left */
  assert_null(ts_rd_bytes(&r, 0));
  assert_int_equal(ts_rd_done(&r, 0), TS_EPROTO);
  ts_rd_init(&r, p, sizeof(p));
  assert_null(ts_rd_bytes(&r, SIZE_MAX)); /* no overflow in the check */
  assert_int_equal(ts_rd_done(&r, 0), TS_EPROTO);
}

static void writer_roundtrips_through_cursor(void **state) {
  (void)state;
  ts_wr w;
  ts_wr_init(&w);
  for (uint32_t i = 0; i < 1000; i++) {
    ts_wr_u8(&w, (uint8_t)i);
    ts_wr_u16(&w, (uint16_t)(i * 7));
    ts_wr_u32(&w, i * 100003u);
    ts_wr_u64(&w, (uint64_t)i << 40 | i);
  }
  ts_wr_bytes(&w, "tail", 4);
  assert_int_equal(ts_wr_status(&w), 0);
  ts_rd r;
  ts_rd_init(&r, w.buf, w.len);
  for (uint32_t i = 0; i < 1000; i++) {
    assert_int_equal(ts_rd_u8(&r), (uint8_t)i);
    assert_int_equal(ts_rd_u16(&r), (uint16_t)(i * 7));
    assert_int_equal(ts_rd_u32(&r), i * 100003u);
    assert_true(ts_rd_u64(&r) == ((uint64_t)i << 40 | i));
  }
  assert_memory_equal(ts_rd_bytes(&r, 4), "tail", 4);
  assert_int_equal(ts_rd_done(&r, 1), 0);
  ts_wr_free(&w);
}

/* What ts_frame_reader_next must give for the bytes at `h` (`left` of
 * them, a reader limited to 32-byte payloads), by the header rules of proto/PROTOCOL.md: 1 for a
 * whole frame, 0 to wait for more, or the error of the first bad field,
 * whose message must hold `*why`. */
static int header_outcome(const uint8_t *h, size_t left, const char **why) {
  *why = NULL;
  if (left < TS_FRAME_HEADER) return 0;
  if (h[0] != 'T' || h[1] != 'S') return *why = "not a texsyn frame (bad magic", TS_EPROTO;
  if (h[2] != TS_PROTO_VERSION) return *why = "the peer speaks texsyn protocol version", TS_EPROTO;
  uint32_t len = (uint32_t)h[4] | (uint32_t)h[5] << 8 | (uint32_t)h[6] << 16 | (uint32_t)h[7] << 24;
  if (len > 32) return *why = "exceeds the limit of 32", TS_ETOOBIG;
  return left - TS_FRAME_HEADER < len ? 0 : 1;
}

/* Random garbage never crashes the reader, and every call gives the one
 * outcome the bytes at its place call for: a whole frame (type, id and
 * payload as sent, inside what was fed), a wait for more, or the error of
 * the first bad header field. A quarter of the inputs carry a valid
 * header with a small length, so every outcome occurs (counted). */
static void garbage_gets_the_outcome_its_header_calls_for(void **state) {
  (void)state;
  srand(5);
  int seen[4] = {0}; /* frames, waits, protocol errors, too big */
  for (int t = 0; t < 2000; t++) {
    uint8_t junk[64];
    for (size_t i = 0; i < sizeof(junk); i++) junk[i] = (uint8_t)rand();
    if (t % 2 == 0) { junk[0] = 'T'; junk[1] = 'S'; junk[2] = TS_PROTO_VERSION; }
    if (t % 4 == 0) { junk[4] = (uint8_t)(rand() % 40); junk[5] = junk[6] = junk[7] = 0; }
    size_t n = (size_t)(rand() % 64);
    ts_frame_reader r;
    ts_frame_reader_init(&r, 32);
    assert_int_equal(ts_frame_reader_feed(&r, junk, n), 0);
    for (size_t at = 0;;) {
      const uint8_t *h = junk + at;
      const char *why;
      int want = header_outcome(h, n - at, &why);
      ts_frame f;
      char err[TS_ERR_LEN] = "";
      assert_int_equal(ts_frame_reader_next(&r, &f, err), want);
      seen[want == 1 ? 0 : want == 0 ? 1 : want == TS_EPROTO ? 2 : 3]++;
      if (want != 1) {
        if (why != NULL && strstr(err, why) == NULL) fail_msg("want \"%s\" in \"%s\"", why, err);
        break;
      }
      assert_int_equal(f.type, h[3]);
      assert_int_equal(f.len, h[4]);
      assert_int_equal(f.id, (uint32_t)h[8] | (uint32_t)h[9] << 8 | (uint32_t)h[10] << 16 | (uint32_t)h[11] << 24);
      assert_memory_equal(f.payload, h + TS_FRAME_HEADER, f.len);
      at += TS_FRAME_HEADER + f.len;
    }
    ts_frame_reader_free(&r);
  }
  print_message("frames %d, waits %d, protocol errors %d, too big %d\n", seen[0], seen[1], seen[2], seen[3]);
  for (int k = 0; k < 4; k++) assert_true(seen[k] > 0);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(header_layout_is_little_endian),
    cmocka_unit_test(frames_survive_one_byte_writes),
    cmocka_unit_test(many_frames_in_one_read),
    cmocka_unit_test(truncated_frame_waits_for_more),
    cmocka_unit_test(bad_headers_are_errors),
    cmocka_unit_test(payload_limit_is_inclusive),
    cmocka_unit_test(cursor_is_bounds_checked_and_sticky),
    cmocka_unit_test(writer_roundtrips_through_cursor),
    cmocka_unit_test(garbage_gets_the_outcome_its_header_calls_for),
};

TS_TEST_MAIN(tests)
