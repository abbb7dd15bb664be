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
 * Payloads are read and written with the cursors of common/cursor.h. */
#ifndef TS_FRAME_H
#define TS_FRAME_H

#include <stddef.h>
#include <stdint.h>

#include "cursor.h"

#define TS_PROTO_VERSION 8
#define TS_FRAME_HEADER 12
#define TS_FRAME_DEFAULT_MAX (64u << 20) /* payload limit unless configured */
#define TS_FRAME_LIMIT_MIN 1024u /* the smallest payload limit a daemon takes (--max-frame) */
#define TS_FRAME_PIECE 'M' /* a piece of a message larger than a frame (pieces.h) */

typedef struct {
  uint8_t type;
  uint32_t id;
  uint32_t len;
  const uint8_t *payload; /* valid until the next call on the reader */
} ts_frame;

void ts_frame_header(uint8_t out[TS_FRAME_HEADER], uint8_t type, uint32_t id, uint32_t len);
/* `PROGRAM --version`: "texsyn-worker 0.1.0 (wire protocol 6)" on stdout. */
void ts_version_print(const char *program);

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

#endif
