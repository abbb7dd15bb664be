/* test_msg.c - message bodies: every writer's output reads back equal;
 * every strict prefix of a body, and a body with a byte too many, is
 * refused; counts and sizes that don't fit the payload are refused before
 * anything is read. Plus the job spec text format. */
#include <stdlib.h>

#include "error.h"
#include "jobspec.h"
#include "mrf.h"
#include "msg.h"
#include "stylit.h"
#include "ts_test.h"

static ts_frame frame_of(const ts_wr *w, uint8_t type) {
  assert_int_equal(ts_wr_status(w), 0);
  ts_frame f = {type, 7, (uint32_t)w->len, w->buf};
  return f;
}

typedef int reader_fn(const ts_frame *f, void *out, char *err);

/* Every strict prefix and one extra byte must fail to decode. */
static void assert_exact(const ts_wr *w, uint8_t type, reader_fn *read, void *out) {
  char err[TS_ERR_LEN];
  uint8_t *buf = malloc(w->len + 1);
  memcpy(buf, w->buf, w->len);
  buf[w->len] = 0;
  for (size_t n = 0; n < w->len; n++) {
    ts_frame f = {type, 7, (uint32_t)n, buf};
    assert_true(read(&f, out, err) < 0);
  }
  ts_frame f = {type, 7, (uint32_t)w->len + 1, buf};
  assert_true(read(&f, out, err) < 0);
  free(buf);
}

static int rd_ident(const ts_frame *f, void *o, char *e) { return ts_msg_ident_read(f, o, e); }
static int rd_slice(const ts_frame *f, void *o, char *e) { return ts_msg_slice_read(f, o, e); }
static int rd_query(const ts_frame *f, void *o, char *e) { return ts_msg_query_read(f, o, e); }
static int rd_answer(const ts_frame *f, void *o, char *e) { return ts_msg_answer_read(f, o, e); }
static int rd_submit(const ts_frame *f, void *o, char *e) { return ts_msg_submit_read(f, o, e); }
static int rd_files(const ts_frame *f, void *o, char *e) { return ts_msg_files_read(f, o, e); }
static int rd_range(const ts_frame *f, void *o, char *e) { return ts_msg_range_read(f, o, e); }
static int rd_error(const ts_frame *f, void *o, char *e) { return ts_msg_error_read(f, o, e); }
static int rd_status2(const ts_frame *f, void *o, char *e) {
  uint32_t n;
  return ts_msg_status_read(f, o, 2, &n, e);
}
static int rd_pool2(const ts_frame *f, void *o, char *e) {
  uint32_t n;
  return ts_msg_pool_read(f, o, 2, &n, e);
}
static int rd_auth(const ts_frame *f, void *o, char *e) { return ts_msg_auth_read(f, o, e); }
static int rd_field(const ts_frame *f, void *o, char *e) { return ts_msg_field_read(f, o, e); }
static int rd_pass(const ts_frame *f, void *o, char *e) { return ts_msg_pass_read(f, o, e); }
static int rd_pass_answer(const ts_frame *f, void *o, char *e) { return ts_msg_pass_answer_read(f, o, e); }

static void ident_round_trip(void **state) {
  (void)state;
  ts_msg_ident in = {TS_ROLE_WORKER, TS_CAP_ALL, 12, TS_SIMD_AVX2, "texsyn-worker test"}, out;
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_ident_write(&w, &in);
  ts_frame f = frame_of(&w, 'I');
  char err[TS_ERR_LEN];
  assert_int_equal(ts_msg_ident_read(&f, &out, err), 0);
  assert_int_equal(out.role, TS_ROLE_WORKER);
  assert_int_equal(out.threads, 12);
  assert_int_equal(out.simd, TS_SIMD_AVX2);
  assert_string_equal(out.name, in.name);
  assert_exact(&w, 'I', rd_ident, &out);
  w.buf[0] = 9; /* unknown role */
  assert_int_equal(ts_msg_ident_read(&f, &out, err), TS_EPROTO);
  ts_wr_free(&w);
}

/* Rows of a whole slice: all of them at lo. */
static ts_slice_rows whole_rows(const uint8_t *rows) { return (ts_slice_rows){rows, NULL}; }

/* A slice of a labelled, masked set with a coarse source: 2 fine planes,
 * 1 coarse, three weighted parts, 3 classes. */
static ts_slice_desc slice_example(uint8_t (*fine)[64 * 10], uint8_t *coarse, uint8_t *labels, uint8_t *valid,
                                   uint8_t *counts) {
  static const int16_t fdx[] = {-1, 0, 1, 0}, fdy[] = {0, -1, 0, 1}, cdx[] = {0, 1}, cdy[] = {0, 0};
  ts_slice_desc m;
  memset(&m, 0, sizeof(m));
  m.set = 5, m.gen = 2;
  m.win.nplanes[TS_SRC_FINE] = 2, m.win.nplanes[TS_SRC_COARSE] = 1;
  m.win.noff[TS_SRC_FINE] = 4, m.win.noff[TS_SRC_COARSE] = 2;
  m.win.dx[TS_SRC_FINE] = fdx, m.win.dy[TS_SRC_FINE] = fdy, m.win.dx[TS_SRC_COARSE] = cdx, m.win.dy[TS_SRC_COARSE] = cdy;
  m.win.extent[TS_SRC_FINE] = (ts_box){-1, -1, 2, 2};
  m.win.extent[TS_SRC_COARSE] = (ts_box){0, 0, 2, 1};
  m.win.centre = 1, m.win.block = 3, m.win.nparts = 3;
  m.win.part[0] = (ts_part){TS_SRC_FINE, 0, 1, 7};
  m.win.part[1] = (ts_part){TS_SRC_FINE, 1, 1, 0xFFFFFFFFu};
  m.win.part[2] = (ts_part){TS_SRC_COARSE, 0, 1, 2};
  m.w = 64, m.h = 64, m.cw = 32, m.ch = 32;
  m.nclass = 3, m.labelled = 1, m.masked = 1;
  for (int c = 0; c < 3; c++) m.count[c] = 900, m.i0[c] = (uint32_t)c * 10, m.i1[c] = (uint32_t)c * 10 + 40;
  m.ay0 = 21, m.ay1 = 29;
  m.above[0] = 100, m.above[1] = 200, m.above[2] = 300;
  m.fy0 = 20, m.fy1 = 30, m.cy0 = 9, m.cy1 = 15;
  m.kfy0 = m.kfy1 = m.fy1, m.kcy0 = m.kcy1 = m.cy1, m.kay0 = m.kay1 = m.ay1; /* a whole slice */
  m.fine[0] = whole_rows(fine[0]), m.fine[1] = whole_rows(fine[1]), m.coarse[0] = whole_rows(coarse);
  m.labels = whole_rows(labels), m.valid = whole_rows(valid);
  m.usage = TS_SLICE_USAGE_COUNTS, m.counts = whole_rows(counts);
  return m;
}

static void slice_round_trip(void **state) {
  (void)state;
  static uint8_t fine[2][64 * 10], coarse[32 * 6], labels[64 * 8], valid[64 * 8], counts[4 * 64 * 10];
  for (size_t i = 0; i < sizeof(fine[0]); i++) fine[0][i] = (uint8_t)i, fine[1][i] = (uint8_t)(3 * i);
  for (size_t i = 0; i < sizeof(coarse); i++) coarse[i] = (uint8_t)(7 * i);
  for (size_t i = 0; i < sizeof(labels); i++) labels[i] = (uint8_t)(i % 3), valid[i] = (uint8_t)(i % 5 != 0);
  for (size_t i = 0; i < sizeof(counts); i++) counts[i] = (uint8_t)(i * 13);
  ts_slice_desc in = slice_example(fine, coarse, labels, valid, counts);
  static ts_slice_desc out;
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_slice_write(&w, &in);
  ts_frame f = frame_of(&w, 'N');
  char err[TS_ERR_LEN];
  assert_int_equal(ts_msg_slice_read(&f, &out, err), 0);
  assert_int_equal(out.set, 5);
  assert_int_equal(out.gen, 2);
  assert_int_equal(out.win.nparts, 3);
  assert_int_equal(out.win.part[1].weight, 0xFFFFFFFFu);
  assert_int_equal(out.win.dy[TS_SRC_FINE][1], -1);
  assert_int_equal(out.win.dx[TS_SRC_COARSE][1], 1);
  assert_int_equal(out.win.extent[TS_SRC_FINE].dx0, -1);
  assert_int_equal(out.nclass, 3);
  assert_int_equal(out.i1[2], 60);
  assert_int_equal(out.above[2], 300);
  assert_memory_equal(out.fine[1].lo, fine[1], sizeof(fine[1]));
  assert_memory_equal(out.coarse[0].lo, coarse, sizeof(coarse));
  assert_memory_equal(out.labels.lo, labels, sizeof(labels));
  assert_memory_equal(out.valid.lo, valid, sizeof(valid));
  assert_memory_equal(out.counts.lo, counts, sizeof(counts));
  assert_exact(&w, 'N', rd_slice, &out);
  size_t whole = w.len;
  ts_wr_free(&w);
  /* a re-slice keeping fine rows 22..26 (coarse 10..13, anchor rows 23..27)
   * of generation 1 sends the rows around them only */
  in.base_gen = 1;
  in.kfy0 = 22, in.kfy1 = 27, in.kcy0 = 10, in.kcy1 = 14, in.kay0 = 23, in.kay1 = 28;
  in.fine[1].hi = fine[1] + 7 * 64, in.counts.hi = counts + 7 * 4 * 64, in.coarse[0].hi = coarse + 5 * 32;
  in.labels.hi = labels + 7 * 64, in.valid.hi = valid + 7 * 64;
  in.fine[0].hi = fine[0] + 7 * 64;
  ts_wr_init(&w);
  ts_msg_slice_write(&w, &in);
  f = frame_of(&w, 'N');
  assert_int_equal(ts_msg_slice_read(&f, &out, err), 0);
  assert_int_equal(out.base_gen, 1);
  assert_int_equal(out.kcy1, 14);
  assert_int_equal(out.kay0, 23);
  assert_int_equal(whole - w.len, 5 * 64 * (2 + 4) + 4 * 32 + 5 * 64 * 2);
  assert_memory_equal(out.fine[1].lo, fine[1], 2 * 64);
  assert_memory_equal(out.fine[1].hi, fine[1] + 7 * 64, 3 * 64);
  assert_memory_equal(out.counts.hi, counts + 7 * 4 * 64, 3 * 4 * 64);
  assert_memory_equal(out.coarse[0].hi, coarse + 5 * 32, 32);
  assert_memory_equal(out.valid.lo, valid, 2 * 64);
  assert_memory_equal(out.valid.hi, valid + 7 * 64, 64);
  assert_exact(&w, 'N', rd_slice, &out);
  ts_wr_free(&w);
  /* labels as a 3 x 1 tile and fine rows from the query image: neither
   * travels, the tile and the checksum do */
  in = slice_example(fine, coarse, labels, valid, counts);
  in.labelled = TS_SLICE_LABELS_TILE, in.tile_w = 3, in.tile_h = 1;
  memcpy(in.tile, (const uint8_t[]){0, 1, 2}, 3);
  in.fine_from_image = 1, in.fine_sum = ts_slice_fine_sum(&in);
  ts_wr_init(&w);
  ts_msg_slice_write(&w, &in);
  f = frame_of(&w, 'N');
  assert_int_equal(ts_msg_slice_read(&f, &out, err), 0);
  assert_int_equal(whole - w.len, sizeof(fine) + sizeof(labels) - (2 + 3) - 8);
  assert_int_equal(out.labelled, TS_SLICE_LABELS_TILE);
  assert_int_equal(out.tile_w, 3);
  assert_int_equal(out.tile[2], 2);
  assert_int_equal(out.fine_from_image, 1);
  assert_true(out.fine_sum == in.fine_sum);
  assert_null(out.fine[0].lo);
  assert_memory_equal(out.valid.lo, valid, sizeof(valid));
  assert_exact(&w, 'N', rd_slice, &out);
  ts_wr_free(&w);
}

/* A label plane that repeats a tile is found to; one that does not is
 * not. */
static void label_tiles_are_found(void **state) {
  (void)state;
  ts_plane p;
  uint8_t tw, th, tile[TS_SLICE_MAX_TILE * TS_SLICE_MAX_TILE];
  assert_int_equal(ts_plane_alloc(&p, 37, 23), 0);
  for (int y = 0; y < 23; y++)
    for (int x = 0; x < 37; x++) p.px[y * 37 + x] = (uint8_t)((x & 1) | (y & 1) << 1);
  assert_int_equal(ts_slice_label_tile(&p, &tw, &th, tile), 1);
  assert_int_equal(tw, 2);
  assert_int_equal(th, 2);
  assert_memory_equal(tile, ((const uint8_t[]){0, 1, 2, 3}), 4);
  p.px[22 * 37 + 36] ^= 1; /* one pixel off the pattern, bottom right */
  assert_int_equal(ts_slice_label_tile(&p, &tw, &th, tile), 0);
  ts_plane_free(&p);
}

/* Geometry that would make a worker read outside the message or its
 * offsets buffer is refused. */
static void slice_geometry_is_checked(void **state) {
  (void)state;
  static uint8_t fine[2][64 * 10], coarse[32 * 6], labels[64 * 8], valid[64 * 8], counts[4 * 64 * 10];
  static uint8_t big[64 * 70 * 4]; /* the writer trusts its caller: room for every case */
  static ts_slice_desc out;
  char err[TS_ERR_LEN];
  for (int k = 0; k < 10; k++) {
    ts_slice_desc m = slice_example(fine, coarse, labels, valid, counts);
    m.fine[0] = m.fine[1] = m.coarse[0] = m.labels = m.valid = m.counts = (ts_slice_rows){big, big};
    switch (k) {
    case 0: m.fy1 = 65; break;    /* rows past the level */
    case 1: m.fy0 = 10, m.fy1 = 10; break;
    case 2: m.ay0 = 30, m.ay1 = 30; break;
    case 3: m.cy1 = 33; break;
    case 4: m.cw = 0; break;      /* a coarse source without a coarse level */
    case 5: m.w = 0; break;
    case 6: m.nclass = 0; break;
    case 7: m.labelled = 3; break;
    case 8: m.kfy0 = 21, m.kfy1 = 20; break; /* kept rows that are no range */
    case 9: m.kay0 = 28, m.kay1 = 27; break;
    }
    if (k < 8) m.kfy0 = m.kfy1 = m.fy1, m.kcy0 = m.kcy1 = m.cy1, m.kay0 = m.kay1 = m.ay1; /* whole */
    ts_wr w;
    ts_wr_init(&w);
    ts_msg_slice_write(&w, &m);
    ts_frame f = frame_of(&w, 'N');
    assert_int_equal(ts_msg_slice_read(&f, &out, err), TS_EPROTO);
    ts_wr_free(&w);
  }
}

static void query_round_trip_with_placements(void **state) {
  (void)state;
  enum { NQ = 5 };
  uint32_t pos[NQ] = {0, 7, 70000, 0xFFFFFFFEu, 9};
  uint8_t k[NQ] = {0, 1, 200, 255, 1};
  ts_place p[2] = {{3, 4}, {0xFFFFFFFFu, 70000}};
  ts_query_batch b = {NQ, pos, 1, k, 0x123456789ull};
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_query_write(&w, 9, 3, 12, 1ull << 40, p, 2, &b, 1, 4); /* queries 1..3 */
  ts_frame f = frame_of(&w, 'V');
  ts_msg_query out;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_msg_query_read(&f, &out, err), 0);
  assert_int_equal(out.nq, 3);
  assert_int_equal(out.image, 12);
  assert_int_equal(out.seq, 1ull << 40);
  assert_int_equal(out.nplace, 2);
  assert_int_equal(out.usage_k, 0x123456789ull);
  assert_int_equal(out.flags, TS_QUERY_MASKS | TS_QUERY_CLASSES);
  for (uint32_t i = 0; i < 3; i++) assert_int_equal(ts_msg_pos_at(&out, i), pos[1 + i]);
  assert_memory_equal(out.klass, k + 1, 3);
  ts_place got;
  ts_msg_place_at(out.places, 1, &got);
  assert_int_equal(got.dst, 0xFFFFFFFFu);
  assert_int_equal(got.src, 70000);
  assert_exact(&w, 'V', rd_query, &out);
  /* 4 bytes of position and 1 of class per query, whatever the window */
  assert_int_equal(w.len, 4 + 4 + 4 + 8 + 4 + 2 * TS_PLACE_BYTES + 4 + 1 + 8 + 3 * 5);
  ts_wr_free(&w);
}

/* A count that claims more than the payload holds fails before reading. */
static void query_counts_are_bounded(void **state) {
  (void)state;
  ts_wr w;
  ts_wr_init(&w);
  ts_wr_u32(&w, 1), ts_wr_u32(&w, 1), ts_wr_u32(&w, 1), ts_wr_u64(&w, 0), ts_wr_u32(&w, 0xFFFFFFFF); /* nplace */
  ts_frame f = frame_of(&w, 'V');
  ts_msg_query out;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_msg_query_read(&f, &out, err), TS_EPROTO);
  ts_wr_free(&w);
  ts_wr_init(&w);
  ts_wr_u32(&w, 1), ts_wr_u32(&w, 1), ts_wr_u32(&w, 1), ts_wr_u64(&w, 0), ts_wr_u32(&w, 0);
  ts_wr_u32(&w, 0x7FFFFFFF), ts_wr_u8(&w, 0), ts_wr_u64(&w, 0); /* nq */
  f = frame_of(&w, 'V');
  assert_int_equal(ts_msg_query_read(&f, &out, err), TS_EPROTO);
  ts_wr_free(&w);
  ts_wr_init(&w);
  ts_wr_u32(&w, 1), ts_wr_u32(&w, 1), ts_wr_u32(&w, 1), ts_wr_u64(&w, 0), ts_wr_u32(&w, 0);
  ts_wr_u32(&w, 1), ts_wr_u8(&w, 4), ts_wr_u64(&w, 0); /* unknown flag */
  ts_wr_u32(&w, 0);
  f = frame_of(&w, 'V');
  assert_int_equal(ts_msg_query_read(&f, &out, err), TS_EPROTO);
  ts_wr_free(&w);
}

static int rd_image(const ts_frame *f, void *o, char *e) { return ts_msg_image_read(f, o, e); }

/* A whole query image, and a level change with its placements. */
static void image_round_trip(void **state) {
  (void)state;
  static uint8_t fine[2][6 * 4], coarse[2][3 * 2], done[6 * 4], ref[2][5 * 5];
  static uint32_t copy[2 * 6 * 4];
  for (int i = 0; i < 24; i++) fine[1][i] = (uint8_t)i, done[i] = (uint8_t)(i & 1), copy[2 * i] = (uint32_t)i % 5;
  ts_msg_image m = {.image = 4, .op = TS_IMAGE_LOAD, .seq = 77};
  m.d = (ts_replica_desc){.w = 6, .h = 4, .nplanes = 2, .fine = {fine[0], fine[1]}, .cw = 3, .ch = 2,
                          .coarse = {coarse[0], coarse[1]}, .done = done, .block = 3, .rw = 5, .rh = 5,
                          .ref = {ref[0], ref[1]}, .copy = copy};
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_image_write(&w, &m);
  ts_frame f = frame_of(&w, 'R');
  ts_msg_image out;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_msg_image_read(&f, &out, err), 0);
  assert_int_equal(out.seq, 77);
  assert_int_equal(out.d.block, 3);
  assert_int_equal(out.d.cw, 3);
  assert_memory_equal(out.d.fine[1], fine[1], sizeof(fine[1]));
  assert_memory_equal(out.d.done, done, sizeof(done));
  assert_int_equal(out.copy_le[8], 1); /* pixel 1's x, little-endian */
  assert_exact(&w, 'R', rd_image, &out);
  ts_wr_free(&w);
  ts_place p[1] = {{5, 6}};
  ts_msg_image n = {.image = 4, .op = TS_IMAGE_NEXT, .seq = 3, .place = p, .nplace = 1, .w = 12, .h = 8, .rw = 5,
                    .rh = 5, .nplanes = 2};
  n.d.ref[0] = ref[0];
  n.d.ref[1] = ref[1];
  ts_wr_init(&w);
  ts_msg_image_write(&w, &n);
  f = frame_of(&w, 'R');
  assert_int_equal(ts_msg_image_read(&f, &out, err), 0);
  assert_int_equal(out.nplace, 1);
  assert_int_equal(out.w, 12);
  ts_msg_place_at(out.places, 0, &p[0]);
  assert_int_equal(p[0].src, 6);
  assert_exact(&w, 'R', rd_image, &out);
  ts_wr_free(&w);
}

/* A bounded image whose pixels have every state, keeping no copy map. */
static void image_load_flags_round_trip(void **state) {
  (void)state;
  uint8_t fine[16], done[16], ref[9] = {0};
  for (int i = 0; i < 16; i++) fine[i] = (uint8_t)i, done[i] = (uint8_t)(i % 4);
  ts_msg_image m = {.image = 2, .op = TS_IMAGE_LOAD, .seq = 5};
  m.d = (ts_replica_desc){.w = 4, .h = 4, .nplanes = 1, .bounded = 1, .done = done, .block = 3, .rw = 3, .rh = 3};
  m.d.fine[0] = fine;
  m.d.ref[0] = ref;
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_image_write(&w, &m);
  ts_frame f = frame_of(&w, 'R');
  ts_msg_image out;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_msg_image_read(&f, &out, err), 0);
  assert_int_equal(out.d.bounded, 1);
  assert_null(out.copy_le);
  assert_memory_equal(out.d.done, done, sizeof(done));
  assert_exact(&w, 'R', rd_image, &out);
  ts_wr_free(&w);
}

/* Sizes that would read past the payload are refused before reading. */
static void image_sizes_are_checked(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  ts_msg_image out;
  for (int k = 0; k < 4; k++) {
    ts_wr w;
    ts_wr_init(&w);
    ts_wr_u32(&w, 1), ts_wr_u8(&w, k == 3 ? 9 : TS_IMAGE_LOAD), ts_wr_u64(&w, 0);
    ts_wr_u32(&w, k == 0 ? 0x10000 : 4), ts_wr_u32(&w, k == 0 ? 0x10000 : 4); /* w, h */
    ts_wr_u8(&w, k == 1 ? 0 : 1), ts_wr_u32(&w, 0), ts_wr_u32(&w, 0), ts_wr_u8(&w, k == 2 ? 8 : 0), ts_wr_u16(&w, 0);
    ts_wr_bytes(&w, "0123456789abcdef", 16);
    ts_frame f = frame_of(&w, 'R');
    assert_int_equal(ts_msg_image_read(&f, &out, err), TS_EPROTO);
    ts_wr_free(&w);
  }
}

static void answer_round_trip(void **state) {
  (void)state;
  ts_l1_best b[3] = {{5, 100, 0}, {UINT64_MAX, UINT32_MAX, 0}, {1ull << 40, 7, 0}};
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_answer_write(&w, 4, 2, 12345, 678, b, 3);
  ts_frame f = frame_of(&w, 'V');
  ts_msg_answer a;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_msg_answer_read(&f, &a, err), 0);
  assert_int_equal(a.nq, 3);
  assert_int_equal(a.scan_nanos, 12345);
  for (uint32_t i = 0; i < 3; i++) {
    ts_l1_best r;
    ts_msg_result_at(&a, i, &r);
    assert_int_equal(r.dist, b[i].dist);
    assert_int_equal(r.index, b[i].index);
  }
  assert_exact(&w, 'V', rd_answer, &a);
  ts_wr_free(&w);
}

static void job_plane_round_trips(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  ts_wr w;
  /* submit */
  const char spec[] = "size=64x64\nseed=3\n";
  const uint8_t ref[] = {1, 2, 3, 4};
  ts_msg_submit s = {spec, sizeof(spec) - 1, "brick.png", ref, sizeof(ref)}, so;
  ts_wr_init(&w);
  ts_msg_submit_write(&w, &s);
  ts_frame f = frame_of(&w, 'S');
  assert_int_equal(ts_msg_submit_read(&f, &so, err), 0);
  assert_int_equal(so.spec_len, s.spec_len);
  assert_string_equal(so.ref_name, "brick.png");
  assert_memory_equal(so.ref, ref, sizeof(ref));
  assert_exact(&w, 'S', rd_submit, &so);
  ts_wr_free(&w);
  /* status */
  ts_job_status st[2] = {{3, TS_JOB_RUNNING, 2, 5, 420, 1500, 3, ""}, {4, TS_JOB_FAILED, 0, 5, 0, 0, 0, "bad"}};
  ts_job_status sto[2];
  uint32_t n;
  ts_wr_init(&w);
  ts_msg_status_write(&w, st, 2);
  f = frame_of(&w, 'W');
  assert_int_equal(ts_msg_status_read(&f, sto, 2, &n, err), 0);
  assert_int_equal(n, 2);
  assert_int_equal(sto[0].permille, 420);
  assert_string_equal(sto[1].text, "bad");
  assert_int_equal(ts_msg_status_read(&f, sto, 1, &n, err), TS_EPROTO); /* more than the caller holds */
  ts_wr_free(&w);
  /* files */
  ts_msg_files fl = {3, {"out.png", "report.json", "out.tif"}, {4, 3, 5ull << 30}, {ref, (const uint8_t *)spec, NULL},
                     {4, 3, 0}}, flo;
  ts_wr_init(&w);
  ts_msg_files_write(&w, &fl);
  f = frame_of(&w, 'F');
  assert_int_equal(ts_msg_files_read(&f, &flo, err), 0);
  assert_string_equal(flo.name[1], "report.json");
  assert_memory_equal(flo.data[1], spec, 3);
  assert_true(flo.size[2] == 5ull << 30 && flo.data[2] == NULL && flo.len[2] == 0); /* taken in ranges */
  assert_exact(&w, 'F', rd_files, &flo);
  ts_wr_free(&w);
  /* a small file not inline, or a large one partly inline: refused */
  fl.size[1] = 10;
  ts_wr_init(&w);
  ts_msg_files_write(&w, &fl);
  f = frame_of(&w, 'F');
  assert_int_equal(ts_msg_files_read(&f, &flo, err), TS_EPROTO);
  ts_wr_free(&w);
  /* range */
  ts_msg_range rg = {7, "out.tif", 5ull << 30, TS_RANGE_MAX}, rgo;
  ts_wr_init(&w);
  ts_msg_range_write(&w, &rg);
  f = frame_of(&w, 'B');
  assert_int_equal(ts_msg_range_read(&f, &rgo, err), 0);
  assert_true(rgo.id == 7 && rgo.offset == 5ull << 30 && rgo.len == TS_RANGE_MAX);
  assert_string_equal(rgo.name, "out.tif");
  assert_exact(&w, 'B', rd_range, &rgo);
  ts_wr_free(&w);
  rg.len = TS_RANGE_MAX + 1;
  ts_wr_init(&w);
  ts_msg_range_write(&w, &rg);
  f = frame_of(&w, 'B');
  assert_int_equal(ts_msg_range_read(&f, &rgo, err), TS_EPROTO);
  ts_wr_free(&w);
  /* error */
  ts_msg_error e;
  ts_wr_init(&w);
  ts_msg_error_write(&w, TS_ENOENT, "no job 9");
  f = frame_of(&w, 'E');
  assert_int_equal(ts_msg_error_read(&f, &e, err), 0);
  assert_int_equal(e.code, TS_ENOENT);
  assert_string_equal(e.text, "no job 9");
  assert_exact(&w, 'E', rd_error, &e);
  ts_wr_free(&w);
}

/* A job record's operator fields (engine, owner, output, times, held) and
 * a worker's name and time of death travel whole, every byte needed; a
 * held job that is not queued, an unknown flag, a dead worker without a
 * time or a live one with one are refused. */
static void operator_records(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  ts_job_status st[2] = {{.id = 7, .state = TS_JOB_QUEUED, .eta_ms = UINT32_MAX, .flags = TS_JOB_HELD,
                          .submitted_ms = 1764400000123ull, .engine = "stylize", .owner = "alice@vm",
                          .output = "wall.png"},
                         {.id = 8, .state = TS_JOB_DONE, .permille = 1000, .submitted_ms = 1, .started_ms = 2,
                          .ended_ms = 1764400009999ull, .engine = "mrf", .owner = "?@h", .output = "out.png"}};
  ts_job_status sto[2];
  uint32_t n;
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_status_write(&w, st, 2);
  ts_frame f = frame_of(&w, 'W');
  assert_int_equal(ts_msg_status_read(&f, sto, 2, &n, err), 0);
  assert_int_equal(n, 2);
  assert_int_equal(sto[0].flags, TS_JOB_HELD);
  assert_true(sto[0].submitted_ms == 1764400000123ull && sto[0].started_ms == 0 && sto[0].ended_ms == 0);
  assert_string_equal(sto[0].engine, "stylize");
  assert_string_equal(sto[0].owner, "alice@vm");
  assert_string_equal(sto[0].output, "wall.png");
  assert_true(sto[1].started_ms == 2 && sto[1].ended_ms == 1764400009999ull);
  assert_exact(&w, 'W', rd_status2, sto);
  ts_wr_free(&w);
  for (int bad = 0; bad < 2; bad++) {
    ts_job_status b = st[bad];
    b.flags = bad == 0 ? 0x2 : TS_JOB_HELD; /* an unknown flag; a finished job held */
    ts_wr_init(&w);
    ts_msg_status_write(&w, &b, 1);
    f = frame_of(&w, 'W');
    assert_int_equal(ts_msg_status_read(&f, sto, 2, &n, err), TS_EPROTO);
    assert_non_null(strstr(err, "job flags"));
    ts_wr_free(&w);
  }
  ts_worker_info wi[2] = {{.addr = "127.0.0.1:7071", .threads = 2, .state = TS_WORKER_READY, .share = 500,
                           .name = "rack1-a"},
                          {.addr = "127.0.0.1:7072", .state = TS_WORKER_FAILED, .name = "",
                           .died_ms = 1764400001000ull}};
  ts_worker_info wo[2];
  ts_wr_init(&w);
  ts_msg_pool_write(&w, wi, 2);
  f = frame_of(&w, 'P');
  assert_int_equal(ts_msg_pool_read(&f, wo, 2, &n, err), 0);
  assert_int_equal(n, 2);
  assert_string_equal(wo[0].name, "rack1-a");
  assert_true(wo[0].died_ms == 0 && wo[1].died_ms == 1764400001000ull);
  assert_string_equal(wo[1].name, "");
  assert_exact(&w, 'P', rd_pool2, wo);
  ts_wr_free(&w);
  for (int bad = 0; bad < 2; bad++) {
    ts_worker_info b = wi[bad];
    b.died_ms = bad == 0 ? 5 : 0; /* alive with a death; dead without one */
    ts_wr_init(&w);
    ts_msg_pool_write(&w, &b, 1);
    f = frame_of(&w, 'P');
    assert_int_equal(ts_msg_pool_read(&f, wo, 2, &n, err), TS_EPROTO);
    assert_non_null(strstr(err, "worker death time"));
    ts_wr_free(&w);
  }
}

/* The result's name on the client rides in the spec (name=), shown by
 * texsyn status: it survives format and parse; what could not be shown on
 * one line is refused, and ts_jobspec_set_name keeps a path's last part,
 * other bytes as '?'. */
static void jobspec_name(void **state) {
  (void)state;
  char err[TS_ERR_LEN], text[TS_SPEC_MAX];
  ts_jobspec s, back;
  const char *spec = "engine=mrf\nsize=8x8\nname=castle wall.png\n";
  assert_int_equal(ts_jobspec_parse(spec, strlen(spec), &s, err), 0);
  assert_string_equal(s.name, "castle wall.png");
  int n = ts_jobspec_format(&s, text, sizeof(text));
  assert_true(n > 0);
  assert_non_null(strstr(text, "name=castle wall.png\n"));
  assert_int_equal(ts_jobspec_parse(text, (size_t)n, &back, err), 0);
  assert_string_equal(back.name, "castle wall.png");
  const char *bad[] = {"size=8x8\nname=\n", "size=8x8\nname=a\tb\n", "size=8x8\nname=\xc3\xa9.png\n"};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++)
    assert_int_equal(ts_jobspec_parse(bad[i], strlen(bad[i]), &s, err), TS_EINVAL);
  ts_jobspec_default(&s, NULL);
  ts_jobspec_set_name(&s, "/tmp/out/caf\xc3\xa9.png");
  assert_string_equal(s.name, "caf??.png");
  n = ts_jobspec_format(&s, text, sizeof(text));
  assert_true(n > 0);
  assert_non_null(strstr(text, "name=caf??.png\n"));
}

/* A video frame's sequence keys (jobspec.h) survive format and parse; a
 * spec with some of them, or with a frame outside its chain, is refused
 * naming what is wrong. */
static void jobspec_sequence(void **state) {
  (void)state;
  char err[TS_ERR_LEN], text[TS_SPEC_MAX];
  ts_jobspec s, back;
  ts_jobspec_default(&s, ts_engine_find("stylize"));
  s.seq = (ts_jobspec_seq){.id = "0123456789abcdef", .name = "out_%04d.png", .first = 1, .last = 48, .jobs = 68,
                           .key = 24, .end = 2, .frame = 20};
  int n = ts_jobspec_format(&s, text, sizeof(text));
  assert_true(n > 0);
  assert_non_null(strstr(text, "sequence=0123456789abcdef\nsequence_name=out_%04d.png\nsequence_frames=1..48\n"
                               "sequence_jobs=68\nsequence_chain=24..2\nsequence_frame=20\n"));
  assert_int_equal(ts_jobspec_parse(text, (size_t)n, &back, err), 0);
  assert_string_equal(back.seq.id, s.seq.id);
  assert_string_equal(back.seq.name, s.seq.name);
  assert_true(back.seq.first == 1 && back.seq.last == 48 && back.seq.jobs == 68);
  assert_true(back.seq.key == 24 && back.seq.end == 2 && back.seq.frame == 20);
  ts_jobspec_default(&s, ts_engine_find("stylize"));
  n = ts_jobspec_format(&s, text, sizeof(text));
  assert_null(strstr(text, "sequence"));
  const char *seq = "engine=stylize\nsequence=0123456789abcdef\nsequence_name=o\nsequence_frames=1..8\n"
                    "sequence_jobs=7\nsequence_chain=4..8\n";
  char spec[512];
  snprintf(spec, sizeof(spec), "%s", seq); /* no sequence_frame */
  assert_int_equal(ts_jobspec_parse(spec, strlen(spec), &s, err), TS_EINVAL);
  assert_non_null(strstr(err, "sequence_frame is missing"));
  const char *outside[] = {"sequence_frame=4\n", "sequence_frame=3\n", "sequence_frame=9\n"};
  for (size_t i = 0; i < sizeof(outside) / sizeof(outside[0]); i++) {
    snprintf(spec, sizeof(spec), "%s%s", seq, outside[i]);
    assert_int_equal(ts_jobspec_parse(spec, strlen(spec), &s, err), TS_EINVAL);
    assert_non_null(strstr(err, "do not fit sequence_frames=1..8"));
  }
  snprintf(spec, sizeof(spec), "%ssequence_frame=5\n", seq);
  assert_int_equal(ts_jobspec_parse(spec, strlen(spec), &s, err), 0);
  const char *bad[] = {"sequence=0123456789ABCDEF\n", "sequence=0123\n", "sequence_frames=8..1\n",
                       "sequence_frames=1..\n", "sequence_chain=4..4\n", "sequence_jobs=0\n", "sequence_name=\n",
                       "sequence_frame=-1\n", "sequence_frame=1000000\n"};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    snprintf(spec, sizeof(spec), "engine=stylize\n%s", bad[i]);
    assert_int_equal(ts_jobspec_parse(spec, strlen(spec), &s, err), TS_EINVAL);
    assert_non_null(strstr(err, "bad value"));
  }
}

static void strings_refuse_nul_and_overflow(void **state) {
  (void)state;
  ts_wr w;
  ts_wr_init(&w);
  ts_wr_u16(&w, 3);
  ts_wr_bytes(&w, "a\0b", 3);
  ts_rd r;
  char buf[16];
  ts_rd_init(&r, w.buf, w.len);
  ts_rd_str(&r, buf, sizeof(buf));
  assert_true(r.failed);
  ts_wr_free(&w);
  ts_wr_init(&w);
  ts_wr_str(&w, "0123456789abcdef0123");
  ts_rd_init(&r, w.buf, w.len);
  ts_rd_str(&r, buf, sizeof(buf)); /* 20 bytes into 16 */
  assert_true(r.failed);
  ts_wr_free(&w);
}

/* Output k of the spec's engine by its spec key. */
static int out_of(const ts_jobspec *s, const char *key) {
  int k = ts_engine_output_index(s->engine, key);
  assert_true(k >= 0);
  return k;
}

static void jobspec_round_trip(void **state) {
  (void)state;
  ts_jobspec a, b;
  ts_jobspec_default(&a, ts_engine_find("mrf"));
  ts_mrf_params *p = (ts_mrf_params *)a.params.bytes;
  p->width = 300, p->height = 200, p->levels = 4, p->parity = 1, p->usage_weight = 0.1;
  p->coarse_weight = 1.0 / 3.0, p->seed = UINT64_MAX;
  snprintf(a.wants.want[out_of(&a, "copy_map_raw")], TS_EXT_LEN, "1");
  snprintf(a.wants.want[out_of(&a, "report")], TS_EXT_LEN, "1");
  snprintf(a.wants.want[out_of(&a, "output")], TS_EXT_LEN, "tif");
  snprintf(a.wants.want[out_of(&a, "usage_map")], TS_EXT_LEN, "exr");
  char text[TS_SPEC_MAX], err[TS_ERR_LEN];
  int n = ts_jobspec_format(&a, text, sizeof(text));
  assert_true(n > 0);
  assert_non_null(strstr(text, "engine=mrf\n"));
  assert_int_equal(ts_jobspec_parse(text, (size_t)n, &b, err), 0);
  const ts_mrf_params *q = (const ts_mrf_params *)b.params.bytes;
  assert_ptr_equal(b.engine, a.engine);
  assert_int_equal(q->width, 300);
  assert_true(q->usage_weight == 0.1);
  assert_true(q->coarse_weight == 1.0 / 3.0); /* 17 digits round-trip */
  assert_int_equal(q->seed, UINT64_MAX);
  assert_string_equal(b.wants.want[out_of(&b, "output")], "tif");
  assert_string_equal(b.wants.want[out_of(&b, "usage_map")], "exr");
  assert_string_equal(b.wants.want[out_of(&b, "copy_map")], "");
  assert_string_equal(b.wants.want[out_of(&b, "copy_map_raw")], "1");
}

/* A stylize spec: per-guide weights (a default one written as the value
 * it stands for), its inputs named after its guides. */
static void stylize_spec_round_trip(void **state) {
  (void)state;
  ts_jobspec a, b;
  ts_jobspec_default(&a, ts_engine_find("stylize"));
  ts_stylit_params *p = (ts_stylit_params *)a.params.bytes;
  p->guides = 3, p->patch = 7, p->iters = 2, p->uniformity = 2.5, p->seed = 9, p->style_weight = 0.25;
  p->weight[0] = 0.5, p->weight[2] = 1.0 / 3.0;
  snprintf(a.wants.want[out_of(&a, "nnf")], TS_EXT_LEN, "raw");
  char text[TS_SPEC_MAX], again[TS_SPEC_MAX], err[TS_ERR_LEN];
  int n = ts_jobspec_format(&a, text, sizeof(text));
  assert_true(n > 0);
  assert_non_null(strstr(text, "engine=stylize\n"));
  assert_non_null(strstr(text, "weight_1=0.33333333333333331\n")); /* the default, 1 / guides */
  assert_int_equal(ts_jobspec_parse(text, (size_t)n, &b, err), 0);
  const ts_stylit_params *q = (const ts_stylit_params *)b.params.bytes;
  assert_int_equal(q->guides, 3);
  assert_int_equal(q->patch, 7);
  assert_true(q->uniformity == 2.5 && q->style_weight == 0.25);
  assert_true(ts_stylit_weight(q, 0) == 0.5 && ts_stylit_weight(q, 2) == 1.0 / 3.0);
  assert_string_equal(b.wants.want[out_of(&b, "nnf")], "raw");
  assert_int_equal(ts_jobspec_format(&b, again, sizeof(again)), n);
  assert_memory_equal(again, text, (size_t)n);
  ts_engine_inputs in;
  b.engine->inputs(&b.params, &in);
  assert_int_equal(in.n, 7);
  assert_string_equal(in.name[0], "style");
  assert_string_equal(in.name[5], "guide_src_2");
  assert_string_equal(in.name[6], "guide_tgt_2");
  /* A weight of a guide the job does not have would be lost on a restart. */
  const char *extra = "engine=stylize\nguides=1\nweight_1=2\noutput=png\n";
  assert_int_equal(ts_jobspec_parse(extra, strlen(extra), &b, err), TS_EINVAL);
  assert_non_null(strstr(err, "weight_1 given for a job of 1 guide"));
}

/* An energy spec: the scene's keys (as stylize writes them) and the step;
 * its result, output 0, a flag output that is always wanted; its inputs
 * the scene's and then the image. */
static void energy_spec_round_trip(void **state) {
  (void)state;
  ts_jobspec a, b;
  ts_jobspec_default(&a, ts_engine_find("energy"));
  ts_stylit_energy_params *p = (ts_stylit_energy_params *)a.params.bytes;
  assert_int_equal(p->step, 1);
  p->scene.guides = 2, p->scene.patch = 7, p->scene.style_weight = 0.5, p->scene.weight[1] = 1.0 / 3.0;
  p->step = 4;
  char text[TS_SPEC_MAX], again[TS_SPEC_MAX], err[TS_ERR_LEN];
  int n = ts_jobspec_format(&a, text, sizeof(text));
  assert_true(n > 0);
  assert_non_null(strstr(text, "engine=energy\n"));
  assert_non_null(strstr(text, "sample=4\n"));
  assert_non_null(strstr(text, "weight_0=0.5\n")); /* the default, 1 / guides */
  assert_non_null(strstr(text, "output=1\n"));
  assert_null(strstr(text, "iters=")); /* stylize's own keys are not energy's */
  assert_int_equal(ts_jobspec_parse(text, (size_t)n, &b, err), 0);
  const ts_stylit_energy_params *q = (const ts_stylit_energy_params *)b.params.bytes;
  assert_int_equal(q->step, 4);
  assert_int_equal(q->scene.guides, 2);
  assert_int_equal(q->scene.patch, 7);
  assert_true(q->scene.style_weight == 0.5 && ts_stylit_weight(&q->scene, 1) == 1.0 / 3.0);
  assert_int_equal(ts_jobspec_format(&b, again, sizeof(again)), n);
  assert_memory_equal(again, text, (size_t)n);
  ts_engine_inputs in;
  b.engine->inputs(&b.params, &in);
  assert_int_equal(in.n, 6);
  assert_string_equal(in.name[4], "guide_tgt_1");
  assert_string_equal(in.name[5], "image");
  const char *no_result = "engine=energy\nguides=1\noutput=0\n", *stylize_key = "engine=energy\niters=3\n";
  assert_int_equal(ts_jobspec_parse(no_result, strlen(no_result), &b, err), TS_EINVAL);
  assert_non_null(strstr(err, "output=1 is required"));
  assert_int_equal(ts_jobspec_parse(stylize_key, strlen(stylize_key), &b, err), TS_EINVAL);
  assert_non_null(strstr(err, "unknown key 'iters'"));
}

/* Further inputs travel as a tail after the first; without them the
 * message is the one-input message byte for byte. */
static void submit_with_more_inputs(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  const char spec[] = "engine=stylize\nguides=1\n";
  const uint8_t style[] = {1, 2, 3}, src[] = {4, 5}, tgt[] = {6};
  ts_msg_submit s = {spec, sizeof(spec) - 1, "style.png", style, sizeof(style), 2}, *so = malloc(sizeof(*so));
  s.more[0] = (ts_msg_input){"guide_src_0", "a.png", src, sizeof(src)};
  s.more[1] = (ts_msg_input){"guide_tgt_0", "b.exr", tgt, sizeof(tgt)};
  ts_wr w, one;
  ts_wr_init(&w);
  ts_msg_submit_write(&w, &s);
  ts_frame f = frame_of(&w, 'S');
  assert_int_equal(ts_msg_submit_read(&f, so, err), 0);
  assert_int_equal(so->nmore, 2);
  assert_string_equal(so->more[1].key, "guide_tgt_0");
  assert_string_equal(so->more[1].name, "b.exr");
  assert_memory_equal(so->more[0].data, src, sizeof(src));
  /* Cut anywhere but at the tail's start, or with a byte more: refused. */
  ts_wr_init(&one);
  s.nmore = 0;
  ts_msg_submit_write(&one, &s);
  for (size_t cut = 0; cut < w.len; cut++) {
    ts_frame c = {'S', 7, (uint32_t)cut, w.buf};
    assert_int_equal(ts_msg_submit_read(&c, so, err) == 0, cut == one.len);
  }
  assert_int_equal(memcmp(one.buf, w.buf, one.len), 0);
  /* A key that could steer a spool path, or one given twice: refused. */
  s.nmore = 2;
  const char *bad[] = {"../x", "Guide", ""};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    ts_wr b;
    ts_wr_init(&b);
    snprintf(s.more[0].key, sizeof(s.more[0].key), "%s", bad[i]);
    ts_msg_submit_write(&b, &s);
    f = frame_of(&b, 'S');
    assert_int_equal(ts_msg_submit_read(&f, so, err), TS_EPROTO);
    ts_wr_free(&b);
  }
  snprintf(s.more[0].key, sizeof(s.more[0].key), "guide_tgt_0");
  ts_wr_free(&w);
  ts_wr_init(&w);
  ts_msg_submit_write(&w, &s);
  f = frame_of(&w, 'S');
  assert_int_equal(ts_msg_submit_read(&f, so, err), TS_EPROTO);
  assert_non_null(strstr(err, "twice"));
  ts_wr_free(&w);
  ts_wr_free(&one);
  free(so);
}

/* A spec spooled before engines had names is an mrf job; an unknown
 * engine is refused by name. */
static void jobspec_engine_key(void **state) {
  (void)state;
  ts_jobspec s;
  char err[TS_ERR_LEN];
  const char *old = "size=8x8\noutput=png\n";
  assert_int_equal(ts_jobspec_parse(old, strlen(old), &s, err), 0);
  assert_string_equal(s.engine->name, "mrf");
  const char *later = "size=8x8\noutput=png\nengine=mrf\n";
  assert_int_equal(ts_jobspec_parse(later, strlen(later), &s, err), 0);
  const char *unknown = "engine=paint\nsize=8x8\n";
  assert_int_equal(ts_jobspec_parse(unknown, strlen(unknown), &s, err), TS_EINVAL);
  assert_non_null(strstr(err, "unknown engine 'paint'"));
  const char *twice = "engine=mrf\nengine=paint\nsize=8x8\n";
  assert_int_equal(ts_jobspec_parse(twice, strlen(twice), &s, err), TS_EINVAL);
}

static void jobspec_refuses_bad_lines(void **state) {
  (void)state;
  const char *bad[] = {"colour=red\n", "size=10\n", "levels=five\n", "output=../../etc/x\n",
                       "output=png/x\n", "seed=-1\n", "novalue\n", "parity=2\n", "output=\n"};
  ts_jobspec s;
  char err[TS_ERR_LEN];
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++)
    assert_int_equal(ts_jobspec_parse(bad[i], strlen(bad[i]), &s, err), TS_EINVAL);
  assert_int_equal(ts_jobspec_parse("size=8x8\nbogus=1\n", 17, &s, err), TS_EINVAL);
  assert_non_null(strstr(err, "line 2"));
  /* Found by fuzz_jobspec: without a size the spec formatted as size=0x0,
   * which no parse takes back (a spooled job lost on restart). */
  assert_int_equal(ts_jobspec_parse("output=png\n", 11, &s, err), TS_EINVAL);
  assert_non_null(strstr(err, "size=WxH is required"));
  /* A format texsyn does not write is refused at the spec, so a raw wire
   * client's job fails at submit, not after it ran; .raw only for the NNF. */
  const char *unwritable[] = {"size=8x8\noutput=xyz\n", "size=8x8\noutput=gif\n", "size=8x8\ncopy_map=raw\n",
                              "engine=stylize\nnnf=bmp\n"};
  for (size_t i = 0; i < sizeof(unwritable) / sizeof(unwritable[0]); i++) {
    assert_int_equal(ts_jobspec_parse(unwritable[i], strlen(unwritable[i]), &s, err), TS_EINVAL);
    assert_non_null(strstr(err, "bad value"));
  }
  const char *fine[] = {"size=8x8\noutput=TIFF\ncopy_map=exr\n", "engine=stylize\nnnf=raw\n"};
  for (size_t i = 0; i < sizeof(fine) / sizeof(fine[0]); i++)
    assert_int_equal(ts_jobspec_parse(fine[i], strlen(fine[i]), &s, err), 0);
  assert_int_equal(ts_ext_same_format("jpg", "JPEG"), 1);
  assert_int_equal(ts_ext_same_format("tif", "tiff"), 1);
  assert_int_equal(ts_ext_same_format("png", "tif"), 0);
  assert_int_equal(ts_ext_same_format("raw", "png"), 0);
  assert_int_equal(ts_ext_same_format("raw", "RAW"), 1);
  assert_int_equal(ts_ext_valid("png"), 1);
  assert_int_equal(ts_ext_valid(""), 0);
  assert_int_equal(ts_ext_valid("p.g"), 0);
  assert_int_equal(ts_ext_valid("abcdefghijklmnop"), 0);
}

/* Each step has one exact size (33, 65, 33 bytes); unknown steps and the
 * size of another step are refused. */
static void auth_steps_round_trip_and_are_exact(void **state) {
  (void)state;
  /* Challenge and response name a key: u8 kind, u16 length, "alice". */
  const size_t key = 1 + 2 + 5;
  const size_t sizes[] = {0, 1 + TS_AUTH_NONCE + key, 1 + TS_AUTH_NONCE + key + TS_AUTH_MAC, 1 + TS_AUTH_MAC};
  char err[TS_ERR_LEN];
  for (uint8_t step = TS_AUTH_CHALLENGE; step <= TS_AUTH_PROOF; step++) {
    ts_msg_auth in, out;
    memset(&in, 0, sizeof(in));
    in.step = step;
    in.key_kind = 3;
    snprintf(in.key_name, sizeof(in.key_name), "alice");
    for (int i = 0; i < TS_AUTH_NONCE; i++) in.nonce[i] = (uint8_t)(i + 1);
    for (int i = 0; i < TS_AUTH_MAC; i++) in.mac[i] = (uint8_t)(0xA0 + i);
    ts_wr w;
    ts_wr_init(&w);
    ts_msg_auth_write(&w, &in);
    assert_int_equal(w.len, sizes[step]);
    ts_frame f = frame_of(&w, 'A');
    assert_int_equal(ts_msg_auth_read(&f, &out, err), 0);
    assert_int_equal(out.step, step);
    if (step != TS_AUTH_PROOF) {
      assert_memory_equal(out.nonce, in.nonce, TS_AUTH_NONCE);
      assert_int_equal(out.key_kind, 3);
      assert_string_equal(out.key_name, "alice");
    }
    if (step != TS_AUTH_CHALLENGE) assert_memory_equal(out.mac, in.mac, TS_AUTH_MAC);
    assert_exact(&w, 'A', rd_auth, &out);
    ts_wr_free(&w);
  }
  uint8_t buf[1 + TS_AUTH_NONCE + 3 + TS_AUTH_MAC] = {0};
  const uint8_t bad_steps[] = {0, 4, 0xFF};
  for (size_t i = 0; i < sizeof(bad_steps); i++) {
    buf[0] = bad_steps[i];
    ts_frame f = {'A', 0, 1 + TS_AUTH_NONCE + 3, buf};
    ts_msg_auth out;
    assert_int_equal(ts_msg_auth_read(&f, &out, err), TS_EPROTO);
  }
  /* A response must name its key; a kind past page, or a name with a
   * byte a log line or an owner field must not hold, is refused. */
  const struct {
    uint8_t step, kind;
    const char *name;
  } bad[] = {{TS_AUTH_RESPONSE, 0, ""}, {TS_AUTH_RESPONSE, 3, ""}, {TS_AUTH_RESPONSE, 5, "a"},
             {TS_AUTH_CHALLENGE, 9, ""}, {TS_AUTH_RESPONSE, 3, "a\nb"}, {TS_AUTH_RESPONSE, 3, "a b"}};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    ts_msg_auth in, out;
    memset(&in, 0, sizeof(in));
    in.step = bad[i].step;
    in.key_kind = bad[i].kind;
    snprintf(in.key_name, sizeof(in.key_name), "%s", bad[i].name);
    ts_wr w;
    ts_wr_init(&w);
    ts_msg_auth_write(&w, &in);
    ts_frame f = frame_of(&w, 'A');
    assert_int_equal(ts_msg_auth_read(&f, &out, err), TS_EPROTO);
    ts_wr_free(&w);
  }
}

/* The worker's limits ride at the end of its 'C' reply, only when the
 * coordinator speaks pieces: 16 bytes without them, 28 with, nothing else. */
static void calib_reply_limits_are_optional_and_checked(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  ts_msg_calib in = {123, 456, 0, 0}, out;
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_calib_write(&w, &in);
  assert_int_equal(w.len, 16);
  ts_frame f = frame_of(&w, 'C');
  assert_int_equal(ts_msg_calib_read(&f, &out, err), 0);
  assert_true(out.pairs == 123 && out.nanos == 456 && out.max_payload == 0 && out.max_message == 0);
  ts_wr_free(&w);
  in.max_payload = 1024;
  in.max_message = 5ull << 30;
  ts_wr_init(&w);
  ts_msg_calib_write(&w, &in);
  assert_int_equal(w.len, 28);
  f = frame_of(&w, 'C');
  assert_int_equal(ts_msg_calib_read(&f, &out, err), 0);
  assert_true(out.max_payload == 1024 && out.max_message == 5ull << 30);
  for (uint32_t n = 17; n < 28; n++) { /* any other trailing length */
    f.len = n;
    assert_int_equal(ts_msg_calib_read(&f, &out, err), TS_EPROTO);
  }
  f.len = 28;
  w.buf[16] = 0xFF; /* a frame limit of 1023 */
  w.buf[17] = 0x03;
  assert_int_equal(ts_msg_calib_read(&f, &out, err), TS_EPROTO);
  assert_non_null(strstr(err, "under 1024"));
  ts_wr_free(&w);
}

/* 'G': a 3x3 window over two planes of 9 x 7. */
static void field_round_trip(void **state) {
  (void)state;
  int16_t dx[9], dy[9];
  for (int i = 0; i < 9; i++) {
    dx[i] = (int16_t)(i % 3);
    dy[i] = (int16_t)(i / 3);
  }
  uint8_t a[63], b[63];
  for (int i = 0; i < 63; i++) {
    a[i] = (uint8_t)i;
    b[i] = (uint8_t)(200 - i);
  }
  ts_msg_field *m = calloc(2, sizeof(*m));
  m->set = 42;
  m->win = (ts_window_spec){.nplanes = {2, 0}, .noff = {9, 0}, .dx = {dx, NULL}, .dy = {dy, NULL},
                            .extent = {{0, 0, 3, 3}}, .block = 3, .nparts = 1};
  m->win.part[0] = (ts_part){TS_SRC_FINE, 0, 2, 77};
  m->w = 9;
  m->h = 7;
  m->nplanes = 2;
  m->plane[0] = a;
  m->plane[1] = b;
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_field_write(&w, m);
  ts_frame f = frame_of(&w, 'G');
  char err[TS_ERR_LEN];
  ts_msg_field *o = m + 1;
  assert_int_equal(ts_msg_field_read(&f, o, err), 0);
  assert_int_equal(o->set, 42);
  assert_int_equal(o->w, 9);
  assert_int_equal(o->h, 7);
  assert_int_equal(o->win.part[0].weight, 77);
  assert_int_equal(o->win.dx[TS_SRC_FINE][4], 1);
  assert_memory_equal(o->plane[1], b, 63);
  assert_exact(&w, 'G', rd_field, o);
  ts_wr_free(&w);
  m->nplanes = 1; /* planes other than the window's */
  ts_wr_init(&w);
  ts_msg_field_write(&w, m);
  f = frame_of(&w, 'G');
  assert_int_equal(ts_msg_field_read(&f, o, err), TS_EPROTO);
  assert_non_null(strstr(err, "plane count"));
  ts_wr_free(&w);
  free(m);
}

/* 'T' and its answer: a 70 x 66 field is 2 x 2 tiles; tiles 1 and 3
 * answer 6 x 64 + 6 x 2 entries. */
static void pass_round_trip(void **state) {
  (void)state;
  enum { TW = 70, TH = 66 };
  uint32_t *field = malloc(sizeof(uint32_t) * 2 * TW * TH), *back = malloc(sizeof(uint32_t) * 2 * TW * TH);
  for (uint32_t i = 0; i < 2 * TW * TH; i++) field[i] = (i * 7919u) % 65536u;
  uint32_t tiles[2] = {1, 3};
  ts_msg_pass m = {5, 6, 99, TW, TH, 1ull << 33, 0x1234567890ull, 17, 2, tiles, field, NULL, NULL}, o;
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_pass_write(&w, &m);
  ts_frame f = frame_of(&w, 'T');
  char err[TS_ERR_LEN];
  assert_int_equal(ts_msg_pass_read(&f, &o, err), 0);
  assert_int_equal(o.seq, 99);
  assert_int_equal(o.usage_k, 1ull << 33);
  assert_int_equal(o.seed, 0x1234567890ull);
  assert_int_equal(o.ntiles, 2);
  assert_int_equal(ts_msg_pass_tile(&o, 1), 3);
  ts_msg_pass_field(&o, back);
  assert_memory_equal(back, field, sizeof(uint32_t) * 2 * TW * TH);
  assert_exact(&w, 'T', rd_pass, &o);
  ts_wr_free(&w);
  ts_wr_init(&w);
  ts_msg_pass_answer_write(&w, 5, 17, 1000, tiles, 2, TW, TH, field);
  f = frame_of(&w, 'T');
  ts_msg_pass_answer a;
  assert_int_equal(ts_msg_pass_answer_read(&f, &a, err), 0);
  assert_int_equal(a.nentries, 6 * 64 + 6 * 2);
  /* tile 1 starts at (64, 0) */
  assert_int_equal(a.entries[0] | a.entries[1] << 8, field[2 * 64]);
  assert_exact(&w, 'T', rd_pass_answer, &a);
  ts_wr_free(&w);
  free(field);
  free(back);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(field_round_trip),
    cmocka_unit_test(pass_round_trip),
    cmocka_unit_test(ident_round_trip),
    cmocka_unit_test(auth_steps_round_trip_and_are_exact),
    cmocka_unit_test(slice_round_trip),
    cmocka_unit_test(label_tiles_are_found),
    cmocka_unit_test(slice_geometry_is_checked),
    cmocka_unit_test(query_round_trip_with_placements),
    cmocka_unit_test(image_round_trip),
    cmocka_unit_test(image_load_flags_round_trip),
    cmocka_unit_test(image_sizes_are_checked),
    cmocka_unit_test(query_counts_are_bounded),
    cmocka_unit_test(answer_round_trip),
    cmocka_unit_test(calib_reply_limits_are_optional_and_checked),
    cmocka_unit_test(job_plane_round_trips),
    cmocka_unit_test(strings_refuse_nul_and_overflow),
    cmocka_unit_test(operator_records),
    cmocka_unit_test(jobspec_name),
    cmocka_unit_test(jobspec_sequence),
    cmocka_unit_test(jobspec_round_trip),
    cmocka_unit_test(stylize_spec_round_trip),
    cmocka_unit_test(energy_spec_round_trip),
    cmocka_unit_test(submit_with_more_inputs),
    cmocka_unit_test(jobspec_engine_key),
    cmocka_unit_test(jobspec_refuses_bad_lines),
};

TS_TEST_MAIN(tests)
