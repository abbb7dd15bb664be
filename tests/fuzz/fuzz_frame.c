/* fuzz_frame.c - libFuzzer target for the frame reader, the reassembly of
 * messages in pieces and the payload cursor: the input is fed in pieces
 * whose sizes come from the input itself, every frame found goes through
 * the reassembler, and every message handed out is walked with the cursor.
 * Any crash, sanitizer report, or frame or message over its limit is a
 * bug. Build and run: make fuzz. */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#include "error.h"
#include "frame.h"
#include "pieces.h"

#define FRAME_LIMIT (1u << 16)
#define MESSAGE_LIMIT (1u << 18)

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* Feeds what the reader holds through the reassembler; -1 once the
 * stream is bad (the connection would be closed). */
static int drain(ts_frame_reader *r, ts_pieces *p, char *err) {
  ts_frame f, m;
  int rc;
  while ((rc = ts_frame_reader_next(r, &f, err)) == 1) {
    if (f.len > FRAME_LIMIT) abort();
    rc = ts_pieces_next(p, &f, &m, err);
    if (rc < 0) return -1;
    if (rc == 0) continue;
    if (m.len > MESSAGE_LIMIT || m.type == TS_FRAME_PIECE) abort();
    ts_rd c;
    ts_rd_init(&c, m.payload, m.len);
    while (ts_rd_done(&c, 0) == 0 && c.off < c.len) ts_rd_u32(&c);
  }
  return rc < 0 ? -1 : 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  ts_frame_reader r;
  ts_pieces p;
  ts_frame_reader_init(&r, FRAME_LIMIT);
  ts_pieces_init(&p, MESSAGE_LIMIT);
  char err[TS_ERR_LEN];
  size_t off = 0;
  while (off < size) {
    size_t piece = 1 + data[off] % 17; /* split sizes driven by the input */
    if (piece > size - off) piece = size - off;
    if (ts_frame_reader_feed(&r, data + off, piece) != 0) break;
    off += piece;
    if (drain(&r, &p, err) != 0) break;
  }
  ts_pieces_free(&p);
  ts_frame_reader_free(&r);
  return 0;
}
