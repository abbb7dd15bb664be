/* fuzz_frame.c - libFuzzer target for the frame reader and payload cursor:
 * the input is fed in pieces whose sizes come from the input itself, every
 * frame found is walked with the cursor. Any crash, sanitizer report or
 * frame outside the fed bytes is a bug. Build and run: make fuzz. */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#include "error.h"
#include "frame.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  ts_frame_reader r;
  ts_frame_reader_init(&r, 1u << 16);
  char err[TS_ERR_LEN];
  size_t off = 0;
  while (off < size) {
    size_t piece = 1 + data[off] % 17; /* split sizes driven by the input */
    if (piece > size - off) piece = size - off;
    if (ts_frame_reader_feed(&r, data + off, piece) != 0) break;
    off += piece;
    ts_frame f;
    int rc;
    while ((rc = ts_frame_reader_next(&r, &f, err)) == 1) {
      if (f.len > (1u << 16)) abort();
      ts_rd c;
      ts_rd_init(&c, f.payload, f.len);
      while (ts_rd_done(&c, 0) == 0 && c.off < c.len) ts_rd_u32(&c);
    }
    if (rc < 0) break;
  }
  ts_frame_reader_free(&r);
  return 0;
}
