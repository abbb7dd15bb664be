/* cursor.c - see cursor.h. */
#include "cursor.h"

#include <stdlib.h>
#include <string.h>

#include "error.h"

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
  return p ? ts_get_le(p, n) : 0;
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

static void wr_append(ts_wr *w, const void *p, size_t n) {
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

void ts_wr_bytes(ts_wr *w, const void *p, size_t n) {
  if (!w->windowed) {
    wr_append(w, p, n);
    return;
  }
  uint64_t at = w->pos;
  w->pos += n;
  uint64_t lo = at > w->from ? at : w->from;
  uint64_t hi = w->pos < w->to ? w->pos : w->to;
  if (lo < hi) wr_append(w, (const uint8_t *)p + (lo - at), (size_t)(hi - lo));
}

void ts_wr_window(ts_wr *w, uint64_t from, uint64_t to) {
  w->windowed = 1;
  w->pos = 0;
  w->from = from;
  w->to = to;
}

uint64_t ts_wr_window_end(ts_wr *w) {
  w->windowed = 0;
  return w->pos;
}

static void wr_le(ts_wr *w, uint64_t v, int n) {
  uint8_t b[8];
  ts_put_le(b, v, n);
  ts_wr_bytes(w, b, (size_t)n);
}

void ts_wr_u8(ts_wr *w, uint8_t v) { wr_le(w, v, 1); }
void ts_wr_u16(ts_wr *w, uint16_t v) { wr_le(w, v, 2); }
void ts_wr_u32(ts_wr *w, uint32_t v) { wr_le(w, v, 4); }
void ts_wr_u64(ts_wr *w, uint64_t v) { wr_le(w, v, 8); }

int ts_wr_status(const ts_wr *w) { return w->failed ? TS_ENOMEM : 0; }
