/* cursor.h - bounds-checked little-endian readers and writers of byte
 * buffers: wire payloads (proto/), checkpoints and spool files.
 *
 * ts_rd: every read past the end fails, the failure is sticky, so a decoder
 * checks once at the end. ts_wr builds a buffer that grows, with the same
 * sticky error. */
#ifndef TS_CURSOR_H
#define TS_CURSOR_H

#include <stddef.h>
#include <stdint.h>

/* n little-endian bytes at p (n <= 8). */
static inline void ts_put_le(uint8_t *p, uint64_t v, int n) {
  for (int i = 0; i < n; i++) p[i] = (uint8_t)(v >> (8 * i));
}
static inline uint64_t ts_get_le(const uint8_t *p, int n) {
  uint64_t v = 0;
  for (int i = 0; i < n; i++) v |= (uint64_t)p[i] << (8 * i);
  return v;
}

/* Bounds-checked little-endian payload cursor. */
typedef struct {
  const uint8_t *p;
  size_t len, off;
  int failed;
} ts_rd;

void ts_rd_init(ts_rd *r, const void *p, size_t len);
uint8_t ts_rd_u8(ts_rd *r);
uint16_t ts_rd_u16(ts_rd *r);
uint32_t ts_rd_u32(ts_rd *r);
uint64_t ts_rd_u64(ts_rd *r);
/* The next n bytes of the payload, or NULL (and failed) past its end. */
const uint8_t *ts_rd_bytes(ts_rd *r, size_t n);
/* 0 if every read was in bounds and, with exact, the payload was used up;
 * else TS_EPROTO. */
int ts_rd_done(const ts_rd *r, int exact);

/* Growing little-endian payload writer. */
typedef struct {
  uint8_t *buf;
  size_t len, cap;
  int failed;
  /* Window mode (ts_wr_window): pos counts every byte written, and only
   * those at offsets [from, to) reach buf. */
  int windowed;
  uint64_t pos, from, to;
} ts_wr;

void ts_wr_init(ts_wr *w);
void ts_wr_free(ts_wr *w);
void ts_wr_u8(ts_wr *w, uint8_t v);
void ts_wr_u16(ts_wr *w, uint16_t v);
void ts_wr_u32(ts_wr *w, uint32_t v);
void ts_wr_u64(ts_wr *w, uint64_t v);
void ts_wr_bytes(ts_wr *w, const void *p, size_t n);
/* 0, or TS_ENOMEM if any write could not grow the buffer. */
int ts_wr_status(const ts_wr *w);

/* Window mode, so that a message too large to hold whole can be produced a
 * piece at a time by its ordinary writer (proto/pieces.h): from this call
 * on, writes are counted from offset 0, and only the bytes at offsets
 * [from, to) of that stream are appended to the buffer. A writer run with
 * from == to only measures its message. ts_wr_window_end leaves the mode
 * and returns how many bytes were written in it. */
void ts_wr_window(ts_wr *w, uint64_t from, uint64_t to);
uint64_t ts_wr_window_end(ts_wr *w);

#endif
