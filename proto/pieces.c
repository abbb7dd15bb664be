/* pieces.c - see pieces.h. */
#include "pieces.h"

#include <stdlib.h>
#include <string.h>

#include "error.h"

/* A frame type as text in messages: the letter, or '?' for a byte that
 * is not printable. */
static char printable(uint8_t type) { return type >= 32 && type < 127 ? (char)type : '?'; }

/* ---- sending ------------------------------------------------------------ */

uint64_t ts_payload_size(ts_payload_fn *fn, const void *arg) {
  ts_wr w;
  ts_wr_init(&w);
  ts_wr_window(&w, 0, 0); /* keeps nothing: only counts */
  if (fn != NULL) fn(&w, arg);
  return ts_wr_window_end(&w);
}

int ts_outmsg_init(ts_outmsg *m, uint8_t type, uint32_t id, ts_payload_fn *fn, const void *arg,
                   uint32_t max_payload, int pieces, char *err) {
  memset(m, 0, sizeof(*m));
  m->type = type;
  m->id = id;
  m->total = ts_payload_size(fn, arg);
  if (m->total <= max_payload) return 0;
  if (pieces) {
    if (max_payload <= TS_PIECE_HEADER)
      return ts_error(err, TS_EINVAL, "a frame limit of %u bytes cannot hold a piece of a message", max_payload);
    m->piece = max_payload - TS_PIECE_HEADER;
    return 0;
  }
  if (m->total <= UINT32_MAX) return 0; /* whole: the receiver's limit is its own to enforce */
  return ts_error(err, TS_ETOOBIG, "a '%c' message of %llu bytes does not fit in a frame and the peer takes no "
                  "pieces", printable(type), (unsigned long long)m->total);
}

/* Appends the header of m's next frame (a whole frame, or a piece with its
 * piece header). */
static void begin_frame(ts_outmsg *m, ts_wr *out) {
  uint64_t n = m->piece ? m->total - m->done : m->total;
  if (m->piece && n > m->piece) n = m->piece;
  uint8_t h[TS_FRAME_HEADER];
  if (m->piece) {
    ts_frame_header(h, TS_FRAME_PIECE, m->id, (uint32_t)(TS_PIECE_HEADER + n));
    ts_wr_bytes(out, h, sizeof(h));
    ts_wr_u8(out, m->type);
    ts_wr_u64(out, m->total);
    ts_wr_u64(out, m->done);
  } else {
    ts_frame_header(h, m->type, m->id, (uint32_t)n);
    ts_wr_bytes(out, h, sizeof(h));
  }
  m->frame_end = m->done + n;
  m->frames++;
}

int ts_outmsg_produce(ts_outmsg *m, ts_payload_fn *fn, const void *arg, ts_wr *out, size_t chunk, char *err) {
  if (m->done == m->frame_end) {
    if (m->frames > 0 && m->done == m->total) return 1;
    begin_frame(m, out);
  }
  uint64_t k = m->frame_end - m->done;
  if (k > chunk) k = chunk;
  if (k > 0) {
    size_t before = out->len;
    ts_wr_window(out, m->done, m->done + k);
    if (fn != NULL) fn(out, arg);
    uint64_t written = ts_wr_window_end(out);
    if (ts_wr_status(out) != 0) return ts_error(err, TS_ENOMEM, "out of memory for an outgoing message");
    if (written != m->total || out->len - before != k)
      return ts_error(err, TS_EINVAL, "the '%c' message changed while it was sent (%llu bytes, then %llu)",
                      printable(m->type), (unsigned long long)m->total, (unsigned long long)written);
    m->done += k;
  }
  if (ts_wr_status(out) != 0) return ts_error(err, TS_ENOMEM, "out of memory for an outgoing message");
  return m->done == m->frame_end && m->done == m->total;
}

/* ---- receiving ---------------------------------------------------------- */

void ts_pieces_init(ts_pieces *p, uint64_t max_message) {
  memset(p, 0, sizeof(*p));
  p->max_message = max_message < UINT32_MAX ? max_message : UINT32_MAX;
}

void ts_pieces_free(ts_pieces *p) {
  free(p->buf);
  p->buf = NULL;
  p->cap = 0;
  p->active = p->delivered = 0;
}

/* Every bad sequence says so first, then what was wrong. */
#define BAD "bad message in pieces: "

/* Checks where piece (type, id, total, offset) fits: the start of a new
 * message, or the next piece of the one being reassembled. */
static int check_piece(ts_pieces *p, uint8_t type, uint32_t id, uint64_t total, uint64_t offset, char *err) {
  if (type == TS_FRAME_PIECE) return ts_error(err, TS_EPROTO, BAD "a piece of a piece");
  if (!p->active) {
    if (offset != 0)
      return ts_error(err, TS_EPROTO, BAD "the first piece of '%c' id %u is at offset %llu, not 0", printable(type),
                      id, (unsigned long long)offset);
    if (total > p->max_message)
      return ts_error(err, TS_ETOOBIG, "a '%c' message in pieces of %llu bytes exceeds the limit of %llu "
                      "(texsyn-worker --max-message)", printable(type), (unsigned long long)total,
                      (unsigned long long)p->max_message);
    p->active = 1;
    p->type = type;
    p->id = id;
    p->total = total;
    p->got = 0;
    p->count = 0;
    return 0;
  }
  if (type != p->type || id != p->id || total != p->total)
    return ts_error(err, TS_EPROTO, BAD "a piece of '%c' id %u (%llu bytes) inside '%c' id %u (%llu bytes)",
                    printable(type), id, (unsigned long long)total, printable(p->type), p->id,
                    (unsigned long long)p->total);
  if (offset != p->got)
    return ts_error(err, TS_EPROTO, BAD "a piece at offset %llu of '%c' id %u where %llu was next (pieces come "
                    "in order)", (unsigned long long)offset, printable(type), id, (unsigned long long)p->got);
  return 0;
}

/* Room for `more` bytes after those received: grows geometrically, never
 * past the declared total, so memory follows the bytes that arrived, not
 * what the first piece claimed. */
static int reserve(ts_pieces *p, size_t more) {
  size_t need = (size_t)p->got + more;
  if (need <= p->cap) return 0;
  size_t cap = p->cap * 2 > need ? p->cap * 2 : need;
  if (cap < 65536) cap = 65536;
  if (cap > p->total) cap = (size_t)p->total;
  uint8_t *b = realloc(p->buf, cap);
  if (b == NULL) return TS_ENOMEM;
  p->buf = b;
  p->cap = cap;
  return 0;
}

int ts_pieces_next(ts_pieces *p, const ts_frame *f, ts_frame *out, char *err) {
  if (p->delivered) ts_pieces_free(p);
  if (f->type != TS_FRAME_PIECE) {
    if (p->active)
      return ts_error(err, TS_EPROTO, BAD "a '%c' frame after %llu of the %llu bytes of '%c' "
                      "id %u", printable(f->type), (unsigned long long)p->got, (unsigned long long)p->total,
                      printable(p->type), p->id);
    p->count = 0;
    *out = *f;
    return 1;
  }
  if (p->max_message == 0)
    return ts_error(err, TS_EPROTO, "a message in pieces ('M' frame), which this connection does not take");
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  uint8_t type = ts_rd_u8(&r);
  uint64_t total = ts_rd_u64(&r);
  uint64_t offset = ts_rd_u64(&r);
  size_t n = f->len - r.off;
  if (r.failed || n == 0) return ts_error(err, TS_EPROTO, BAD "an 'M' frame shorter than its 17-byte header and one byte");
  int rc = check_piece(p, type, f->id, total, offset, err);
  if (rc != 0) return rc;
  if (n > p->total - p->got)
    return ts_error(err, TS_EPROTO, BAD "a piece of %zu bytes at offset %llu runs past the end of '%c' id %u (%llu "
                    "bytes)", n, (unsigned long long)offset, printable(type), p->id, (unsigned long long)p->total);
  if (reserve(p, n) != 0)
    return ts_error(err, TS_ENOMEM, "out of memory for a message in pieces of %llu bytes",
                    (unsigned long long)p->total);
  memcpy(p->buf + p->got, f->payload + r.off, n);
  p->got += n;
  p->count++;
  if (p->got < p->total) return 0;
  p->active = 0;
  p->delivered = 1;
  *out = (ts_frame){p->type, p->id, (uint32_t)p->total, p->buf};
  return 1;
}
