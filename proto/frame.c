/* frame.c - see frame.h. */
#include "frame.h"

#include <stdlib.h>
#include <string.h>

#include "error.h"

static void put_le(uint8_t *p, uint64_t v, int n) {
  for (int i = 0; i < n; i++) p[i] = (uint8_t)(v >> (8 * i));
}

static uint64_t get_le(const uint8_t *p, int n) {
  uint64_t v = 0;
  for (int i = 0; i < n; i++) v |= (uint64_t)p[i] << (8 * i);
  return v;
}

void ts_frame_header(uint8_t out[TS_FRAME_HEADER], uint8_t type, uint32_t id, uint32_t len) {
  out[0] = 'T';
  out[1] = 'S';
  out[2] = TS_PROTO_VERSION;
  out[3] = type;
  put_le(out + 4, len, 4);
  put_le(out + 8, id, 4);
}

/* ---- reader ------------------------------------------------------------ */

void ts_frame_reader_init(ts_frame_reader *r, uint32_t max_payload) {
  memset(r, 0, sizeof(*r));
  r->max_payload = max_payload ? max_payload : TS_FRAME_DEFAULT_MAX;
}

void ts_frame_reader_free(ts_frame_reader *r) {
  free(r->buf);
  memset(r, 0, sizeof(*r));
}

/* Drops the frame handed out last, so its bytes can be reused. */
static void drop_consumed(ts_frame_reader *r) {
  if (r->consumed == 0) return;
  memmove(r->buf, r->buf + r->consumed, r->len - r->consumed);
  r->len -= r->consumed;
  r->consumed = 0;
}

int ts_frame_reader_feed(ts_frame_reader *r, const void *data, size_t len) {
  drop_consumed(r);
  if (len == 0) return 0;
  if (len > SIZE_MAX - r->len) return TS_ENOMEM;
  if (r->len + len > r->cap) {
    size_t cap = r->cap ? r->cap : 4096;
    while (cap < r->len + len) cap *= 2;
    uint8_t *b = realloc(r->buf, cap);
    if (b == NULL) return TS_ENOMEM;
    r->buf = b;
    r->cap = cap;
  }
  memcpy(r->buf + r->len, data, len);
  r->len += len;
  return 0;
}

int ts_frame_reader_next(ts_frame_reader *r, ts_frame *f, char *err) {
  drop_consumed(r);
  if (r->len < TS_FRAME_HEADER) return 0;
  const uint8_t *h = r->buf;
  if (h[0] != 'T' || h[1] != 'S')
    return ts_error(err, TS_EPROTO, "not a texsyn frame (bad magic 0x%02x%02x)", h[0], h[1]);
  if (h[2] != TS_PROTO_VERSION)
    return ts_error(err, TS_EPROTO, "protocol version %u, this build speaks %u", h[2], TS_PROTO_VERSION);
  uint32_t len = (uint32_t)get_le(h + 4, 4);
  if (len > r->max_payload)
    return ts_error(err, TS_ETOOBIG, "frame '%c' of %u bytes exceeds the limit of %u", h[3] >= 32 && h[3] < 127 ? h[3] : '?',
                    len, r->max_payload);
  if (r->len - TS_FRAME_HEADER < len) return 0;
  f->type = h[3];
  f->len = len;
  f->id = (uint32_t)get_le(h + 8, 4);
  f->payload = r->buf + TS_FRAME_HEADER;
  r->consumed = TS_FRAME_HEADER + (size_t)len;
  return 1;
}

/* ---- cursor ------------------------------------------------------------ */

void ts_rd_init(ts_rd *r, const void *p, size_t len) {
  r->p = p;
  r->len = len;
  r->off = 0;
  r->failed = 0;
}

const uint8_t *ts_rd_bytes(ts_rd *r, size_t n) {
  if (r->failed || n > r->len - r->off) {
    r->failed = 1;
    return NULL;
  }
  const uint8_t *p = r->p + r->off;
  r->off += n;
  return p;
}

static uint64_t rd_le(ts_rd *r, int n) {
  const uint8_t *p = ts_rd_bytes(r, (size_t)n);
  return p ? get_le(p, n) : 0;
}

uint8_t ts_rd_u8(ts_rd *r) { return (uint8_t)rd_le(r, 1); }
uint16_t ts_rd_u16(ts_rd *r) { return (uint16_t)rd_le(r, 2); }
uint32_t ts_rd_u32(ts_rd *r) { return (uint32_t)rd_le(r, 4); }
uint64_t ts_rd_u64(ts_rd *r) { return rd_le(r, 8); }

int ts_rd_done(const ts_rd *r, int exact) {
  return r->failed || (exact && r->off != r->len) ? TS_EPROTO : 0;
}

/* ---- writer ------------------------------------------------------------ */

void ts_wr_init(ts_wr *w) { memset(w, 0, sizeof(*w)); }

void ts_wr_free(ts_wr *w) {
  free(w->buf);
  memset(w, 0, sizeof(*w));
}

void ts_wr_bytes(ts_wr *w, const void *p, size_t n) {
  if (w->failed) return;
  if (n > SIZE_MAX / 2 - w->len) {
    w->failed = 1;
    return;
  }
  if (w->len + n > w->cap) {
    size_t cap = w->cap ? w->cap : 256;
    while (cap < w->len + n) cap *= 2;
    uint8_t *b = realloc(w->buf, cap);
    if (b == NULL) {
      w->failed = 1;
      return;
    }
    w->buf = b;
    w->cap = cap;
  }
  if (n > 0) memcpy(w->buf + w->len, p, n);
  w->len += n;
}

static void wr_le(ts_wr *w, uint64_t v, int n) {
  uint8_t b[8];
  put_le(b, v, n);
  ts_wr_bytes(w, b, (size_t)n);
}

void ts_wr_u8(ts_wr *w, uint8_t v) { wr_le(w, v, 1); }
void ts_wr_u16(ts_wr *w, uint16_t v) { wr_le(w, v, 2); }
void ts_wr_u32(ts_wr *w, uint32_t v) { wr_le(w, v, 4); }
void ts_wr_u64(ts_wr *w, uint64_t v) { wr_le(w, v, 8); }

int ts_wr_status(const ts_wr *w) { return w->failed ? TS_ENOMEM : 0; }
