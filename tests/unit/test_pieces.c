/* test_pieces.c - messages in pieces and messages produced a chunk at a
 * time: the window writer keeps exactly the asked bytes; a message
 * produced with any frame limit and chunk size, fed to a reader in bytes of
 * any size, comes out whole and equal; every bad sequence of pieces is a
 * protocol error that says what was wrong. */
#include <stdlib.h>

#include "error.h"
#include "msg.h"
#include "net.h"
#include "pieces.h"
#include "ts_test.h"

/* A test message: `len` bytes of a pattern, written in uneven calls (a
 * u8, a u32, then runs of bytes) as message writers do. */
typedef struct {
  const uint8_t *bytes;
  size_t len;
} blob;

static void write_blob(ts_wr *w, const void *arg) {
  const blob *b = arg;
  size_t off = 0;
  for (size_t run = 1; off < b->len; run = run * 3 + 1) {
    size_t n = b->len - off < run ? b->len - off : run;
    ts_wr_bytes(w, b->bytes + off, n);
    off += n;
  }
}

static uint8_t *pattern(size_t len, unsigned seed) {
  uint8_t *p = malloc(len ? len : 1);
  srand(seed);
  for (size_t i = 0; i < len; i++) p[i] = (uint8_t)rand();
  return p;
}

static void window_keeps_exactly_the_asked_bytes(void **state) {
  (void)state;
  uint8_t *p = pattern(300, 1);
  blob b = {p, 300};
  assert_int_equal(ts_payload_size(write_blob, &b), 300);
  assert_int_equal(ts_payload_size(NULL, NULL), 0);
  for (uint64_t from = 0; from <= 300; from += 7)
    for (uint64_t to = from; to <= 310; to += 11) {
      ts_wr w;
      ts_wr_init(&w);
      ts_wr_bytes(&w, "ab", 2); /* what the buffer held before stays */
      ts_wr_window(&w, from, to);
      write_blob(&w, &b);
      assert_int_equal(ts_wr_window_end(&w), 300);
      uint64_t end = to < 300 ? to : 300;
      assert_int_equal(w.len, 2 + (end - from));
      assert_memory_equal(w.buf, "ab", 2);
      if (end > from) assert_memory_equal(w.buf + 2, p + from, end - from);
      ts_wr_u8(&w, 9); /* back to plain appending */
      assert_int_equal(w.buf[w.len - 1], 9);
      ts_wr_free(&w);
    }
  free(p);
}

/* Produces message (type, id, payload) for a receiver with limit
 * max_payload, chunk bytes at a time, into one stream. */
static ts_wr produce(const blob *b, uint8_t type, uint32_t id, uint32_t max_payload, size_t chunk) {
  ts_outmsg m;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_outmsg_init(&m, type, id, write_blob, b, max_payload, 1, err), 0);
  ts_wr out;
  ts_wr_init(&out);
  int rc;
  int calls = 0;
  while ((rc = ts_outmsg_produce(&m, write_blob, b, &out, chunk, err)) == 0) calls++;
  assert_int_equal(rc, 1);
  assert_true(calls <= (int)(b->len / chunk + b->len / (max_payload - TS_PIECE_HEADER) + 3));
  return out;
}

/* Feeds a stream to a reader (limit max_payload) and a reassembler, in
 * pieces of `step` bytes; returns the messages' count, checking each
 * equals (type, id, b). */
static int receive(const ts_wr *stream, uint32_t max_payload, size_t step, const blob *b, uint8_t type,
                   uint32_t id) {
  ts_frame_reader r;
  ts_pieces p;
  ts_frame_reader_init(&r, max_payload);
  ts_pieces_init(&p, 1u << 20);
  char err[TS_ERR_LEN];
  int got = 0;
  for (size_t off = 0; off < stream->len; off += step) {
    size_t n = stream->len - off < step ? stream->len - off : step;
    assert_int_equal(ts_frame_reader_feed(&r, stream->buf + off, n), 0);
    ts_frame f, msg;
    int rc;
    while ((rc = ts_frame_reader_next(&r, &f, err)) == 1) {
      assert_true(f.len <= max_payload);
      rc = ts_pieces_next(&p, &f, &msg, err);
      assert_true(rc >= 0);
      if (rc == 0) continue;
      assert_int_equal(msg.type, type);
      assert_int_equal(msg.id, id);
      assert_int_equal(msg.len, b->len);
      if (b->len > 0) assert_memory_equal(msg.payload, b->bytes, b->len);
      got++;
    }
    assert_int_equal(rc, 0);
  }
  ts_pieces_free(&p);
  ts_frame_reader_free(&r);
  return got;
}

static void any_limit_chunk_and_split_round_trips(void **state) {
  (void)state;
  const size_t lens[] = {0, 1, 1000, 1007, 5000, 70000};
  const uint32_t limits[] = {18, 100, 1024, 1000000};
  const size_t chunks[] = {1, 97, 4096};
  for (size_t l = 0; l < sizeof(lens) / sizeof(lens[0]); l++)
    for (size_t k = 0; k < sizeof(limits) / sizeof(limits[0]); k++)
      for (size_t c = 0; c < sizeof(chunks) / sizeof(chunks[0]); c++) {
        uint8_t *p = pattern(lens[l], (unsigned)(l + 7 * k + 31 * c));
        blob b = {p, lens[l]};
        ts_wr s = produce(&b, 'N', 0x01020304, limits[k], chunks[c]);
        size_t frames = lens[l] <= limits[k] ? 1 : (lens[l] + limits[k] - TS_PIECE_HEADER - 1) /
                                                       (limits[k] - TS_PIECE_HEADER);
        size_t header = lens[l] <= limits[k] ? 0 : TS_PIECE_HEADER;
        assert_int_equal(s.len, lens[l] + frames * (TS_FRAME_HEADER + header));
        assert_int_equal(receive(&s, limits[k], 1 + (l + c) % 13 * 97, &b, 'N', 0x01020304), 1);
        ts_wr_free(&s);
        free(p);
      }
}

/* Whole messages before and after one in pieces are passed through. */
static void whole_frames_around_a_message_in_pieces(void **state) {
  (void)state;
  uint8_t *p = pattern(3000, 3);
  blob big = {p, 3000}, small = {p, 10};
  ts_wr s = produce(&small, 'V', 1, 1024, 4096);
  ts_wr mid = produce(&big, 'N', 2, 1024, 500);
  ts_wr tail = produce(&small, 'V', 3, 1024, 4096);
  ts_wr_bytes(&s, mid.buf, mid.len);
  ts_wr_bytes(&s, tail.buf, tail.len);
  ts_frame_reader r;
  ts_pieces pc;
  ts_frame_reader_init(&r, 1024);
  ts_pieces_init(&pc, 1u << 20);
  assert_int_equal(ts_frame_reader_feed(&r, s.buf, s.len), 0);
  char err[TS_ERR_LEN];
  ts_frame f, m;
  const uint32_t want[] = {1, 2, 3}, counts[] = {0, 3, 0};
  int got = 0;
  while (ts_frame_reader_next(&r, &f, err) == 1)
    if (ts_pieces_next(&pc, &f, &m, err) == 1) {
      assert_int_equal(m.id, want[got]);
      assert_int_equal(pc.count, counts[got]);
      assert_int_equal(m.len, m.id == 2 ? 3000 : 10);
      assert_memory_equal(m.payload, p, m.len);
      got++;
    }
  assert_int_equal(got, 3);
  ts_pieces_free(&pc);
  ts_frame_reader_free(&r);
  ts_wr_free(&s);
  ts_wr_free(&mid);
  ts_wr_free(&tail);
  free(p);
}

/* A writer whose message changes between chunks is caught, not sent. */
static size_t g_changing_len;
static void write_changing(ts_wr *w, const void *arg) {
  (void)arg;
  uint8_t z[64] = {0};
  ts_wr_bytes(w, z, g_changing_len);
  g_changing_len++;
}

static void a_message_that_changes_is_an_error(void **state) {
  (void)state;
  g_changing_len = 40;
  ts_outmsg m;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_outmsg_init(&m, 'N', 1, write_changing, NULL, 1024, 1, err), 0);
  ts_wr out;
  ts_wr_init(&out);
  assert_int_equal(ts_outmsg_produce(&m, write_changing, NULL, &out, 16, err), TS_EINVAL);
  assert_non_null(strstr(err, "changed while it was sent"));
  assert_int_equal(ts_outmsg_init(&m, 'N', 1, write_changing, NULL, TS_PIECE_HEADER, 1, err), TS_EINVAL);
  ts_wr_free(&out);
}

/* One 'M' frame: piece header and n data bytes. */
static void put_piece(ts_wr *s, uint32_t id, uint8_t type, uint64_t total, uint64_t offset, size_t n) {
  uint8_t h[TS_FRAME_HEADER];
  ts_frame_header(h, 'M', id, (uint32_t)(TS_PIECE_HEADER + n));
  ts_wr_bytes(s, h, sizeof(h));
  ts_wr_u8(s, type);
  ts_wr_u64(s, total);
  ts_wr_u64(s, offset);
  for (size_t i = 0; i < n; i++) ts_wr_u8(s, (uint8_t)i);
}

/* Feeds a stream; returns the first error (or 0) and its text in err. */
static int first_error(const ts_wr *s, uint64_t max_message, char *err) {
  ts_frame_reader r;
  ts_pieces p;
  ts_frame_reader_init(&r, 1024);
  ts_pieces_init(&p, max_message);
  assert_int_equal(ts_frame_reader_feed(&r, s->buf, s->len), 0);
  ts_frame f, m;
  int rc = 0;
  while (rc >= 0 && ts_frame_reader_next(&r, &f, err) == 1) rc = ts_pieces_next(&p, &f, &m, err);
  ts_pieces_free(&p);
  ts_frame_reader_free(&r);
  return rc < 0 ? rc : 0;
}

static void bad_sequences_are_protocol_errors(void **state) {
  (void)state;
  struct {
    const char *name;
    int code;
    const char *says;
  } cases[] = {
      {"refused", TS_EPROTO, "does not take"},
      {"first not at 0", TS_EPROTO, "not 0"},
      {"over the limit", TS_ETOOBIG, "exceeds the limit"},
      {"out of order", TS_EPROTO, "come in order"},
      {"other id", TS_EPROTO, "inside 'N' id 5"},
      {"other type", TS_EPROTO, "inside 'N' id 5"},
      {"other total", TS_EPROTO, "inside 'N' id 5"},
      {"interleaved frame", TS_EPROTO, "a 'H' frame after 10 of the 30 bytes"},
      {"past the end", TS_EPROTO, "runs past the end"},
      {"no data", TS_EPROTO, "shorter than its 17-byte header"},
      {"short header", TS_EPROTO, "shorter than its 17-byte header"},
      {"piece of a piece", TS_EPROTO, "a piece of a piece"},
  };
  for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
    ts_wr s;
    ts_wr_init(&s);
    uint64_t max_message = 1000;
    if (i != 1 && i != 2 && i != 9 && i != 10 && i != 11) put_piece(&s, 5, 'N', 30, 0, 10);
    switch (i) {
    case 0: max_message = 0; break;
    case 1: put_piece(&s, 5, 'N', 30, 10, 10); break;
    case 2: put_piece(&s, 5, 'N', 1001, 0, 10); break;
    case 3: put_piece(&s, 5, 'N', 30, 20, 10); break;
    case 4: put_piece(&s, 6, 'N', 30, 10, 10); break;
    case 5: put_piece(&s, 5, 'V', 30, 10, 10); break;
    case 6: put_piece(&s, 5, 'N', 31, 10, 10); break;
    case 7: {
      uint8_t h[TS_FRAME_HEADER];
      ts_frame_header(h, 'H', 9, 0);
      ts_wr_bytes(&s, h, sizeof(h));
      break;
    }
    case 8: put_piece(&s, 5, 'N', 30, 10, 21); break;
    case 9: put_piece(&s, 5, 'N', 30, 0, 0); break;
    case 10: {
      uint8_t h[TS_FRAME_HEADER];
      ts_frame_header(h, 'M', 5, 9);
      ts_wr_bytes(&s, h, sizeof(h));
      ts_wr_u8(&s, 'N');
      ts_wr_u64(&s, 30);
      break;
    }
    case 11: put_piece(&s, 5, 'M', 30, 0, 10); break;
    }
    char err[TS_ERR_LEN] = "";
    int rc = first_error(&s, max_message, err);
    if (rc != cases[i].code || strstr(err, cases[i].says) == NULL)
      fail_msg("%s: got %d \"%s\", want %d \"...%s...\"", cases[i].name, rc, err, cases[i].code, cases[i].says);
    ts_wr_free(&s);
  }
}

/* A connection hands out reassembled messages, and only once pieces are
 * enabled on it. */
static void connection_reassembles_when_enabled(void **state) {
  (void)state;
  uint8_t *p = pattern(5000, 9);
  blob b = {p, 5000};
  ts_wr s = produce(&b, 'N', 77, 1024, 333);
  for (int enabled = 0; enabled < 2; enabled++) {
    int sv[2];
    assert_int_equal(socketpair(AF_UNIX, SOCK_STREAM, 0, sv), 0);
    ts_conn c;
    ts_conn_init(&c, sv[0], 1024, "test");
    if (enabled) ts_conn_accept_pieces(&c, 1u << 20);
    assert_int_equal(write(sv[1], s.buf, s.len), (ssize_t)s.len);
    ts_frame f;
    char err[TS_ERR_LEN];
    int rc = ts_conn_recv(&c, &f, 2000, err);
    if (enabled) {
      assert_int_equal(rc, 1);
      assert_int_equal(f.type, 'N');
      assert_int_equal(f.id, 77);
      assert_int_equal(f.len, 5000);
      assert_memory_equal(f.payload, p, 5000);
      assert_int_equal(c.pieces.count, 5);
    } else {
      assert_int_equal(rc, TS_EPROTO);
      assert_non_null(strstr(err, "does not take"));
    }
    ts_conn_close(&c);
    close(sv[1]);
  }
  ts_wr_free(&s);
  free(p);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(window_keeps_exactly_the_asked_bytes),
    cmocka_unit_test(any_limit_chunk_and_split_round_trips),
    cmocka_unit_test(whole_frames_around_a_message_in_pieces),
    cmocka_unit_test(a_message_that_changes_is_an_error),
    cmocka_unit_test(bad_sequences_are_protocol_errors),
    cmocka_unit_test(connection_reassembles_when_enabled),
};

TS_TEST_MAIN(tests)
