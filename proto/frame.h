/* frame.h - framing of the texsyn wire protocol (proto/PROTOCOL.md).
 *
 * Every message is one frame: a 12-byte header and a payload.
 *
 *   offset size field
 *   0      2    magic "TS" (0x54 0x53)
 *   2      1    version (TS_PROTO_VERSION)
 *   3      1    type (an ASCII letter, e.g. 'I', 'V')
 *   4      4    payload length, little-endian
 *   8      4    request id, little-endian (echoed in the reply)
 *
 * A reader accepts bytes in pieces of any size (a frame may arrive one byte
 * at a time, or many frames in one read) and hands out whole frames. Any
 * malformed header or a payload over the configured limit is an error, after
 * which the connection must be closed: nothing in a bad stream can be
 * trusted to find the next frame.
 *
 * Payloads are read with the bounds-checked cursor ts_rd: every read past
 * the end fails, the failure is sticky, so a decoder checks once at the end.
 * ts_wr builds payloads in a growing buffer, with the same sticky error. */
#ifndef TS_FRAME_H
#define TS_FRAME_H

#include <stddef.h>
#include <stdint.h>

#define TS_PROTO_VERSION 1
#define TS_FRAME_HEADER 12
#define TS_FRAME_DEFAULT_MAX (64u << 20) /* payload limit unless configured */

typedef struct {
  uint8_t type;
  uint32_t id;
  uint32_t len;
  const uint8_t *payload; /* valid until the next call on the reader */
} ts_frame;

void ts_frame_header(uint8_t out[TS_FRAME_HEADER], uint8_t type, uint32_t id, uint32_t len);

typedef struct {
  uint8_t *buf;
  size_t len, cap;  /* bytes held, allocated */
  size_t consumed;  /* bytes of buf handed out as the previous frame */
  uint32_t max_payload;
} ts_frame_reader;

void ts_frame_reader_init(ts_frame_reader *r, uint32_t max_payload);
void ts_frame_reader_free(ts_frame_reader *r);
/* Appends received bytes. 0 or TS_ENOMEM. */
int ts_frame_reader_feed(ts_frame_reader *r, const void *data, size_t len);
/* 1: *f is the next whole frame; 0: more bytes needed; or TS_EPROTO /
 * TS_ETOOBIG with a message (bad magic, version, oversized payload). */
int ts_frame_reader_next(ts_frame_reader *r, ts_frame *f, char *err);

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

#endif
