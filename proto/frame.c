/* frame.c - see frame.h. */
#include "frame.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "version.h"

void ts_version_print(const char *program) {
  printf("%s %s (wire protocol %d)\n", program, TS_VERSION, TS_PROTO_VERSION);
}

void ts_frame_header(uint8_t out[TS_FRAME_HEADER], uint8_t type, uint32_t id, uint32_t len) {
  out[0] = 'T';
  out[1] = 'S';
  out[2] = TS_PROTO_VERSION;
  out[3] = type;
  ts_put_le(out + 4, len, 4);
  ts_put_le(out + 8, id, 4);
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
    return ts_error(err, TS_EPROTO, "the peer speaks texsyn protocol version %u, this build %u: run the same release on both sides", h[2], TS_PROTO_VERSION);
  uint32_t len = (uint32_t)ts_get_le(h + 4, 4);
  if (len > r->max_payload)
    return ts_error(err, TS_ETOOBIG, "frame '%c' of %u bytes exceeds the limit of %u", h[3] >= 32 && h[3] < 127 ? h[3] : '?',
                    len, r->max_payload);
  if (r->len - TS_FRAME_HEADER < len) return 0;
  f->type = h[3];
  f->len = len;
  f->id = (uint32_t)ts_get_le(h + 8, 4);
  f->payload = r->buf + TS_FRAME_HEADER;
  r->consumed = TS_FRAME_HEADER + (size_t)len;
  return 1;
}

/* ---- cursor ------------------------------------------------------------ */
