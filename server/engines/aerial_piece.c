/* aerial_piece.c - a finished tile of an aerial scene as a checkpoint piece
 * (aerial.h). Little-endian, as checkpoint.c's:
 *
 *   u32 magic "TSAP", u32 version, u64 tag, u32 tile index,
 *   u32 x0, y0, w, h (the core),
 *   u32 levels, per level u64 blocks, steps, seeds, comparisons,
 *   u32 classes, per class u32 rank, u64 blocks, f64 usage mean, variance,
 *   w * h luminance bytes, 3 * w * h colour bytes, w * h u32 copies
 *   (rows top to bottom), u32 edits, the edits (aerial.h),
 *   u64 FNV-1a of everything before. */
#include <string.h>

#include "aerial.h"
#include "checkpoint.h"
#include "cursor.h"
#include "error.h"

#define PIECE_MAGIC 0x50415354u /* "TSAP" */
#define PIECE_VERSION 2u /* 2: the copies and edits */

static uint64_t bits_of(double v) {
  uint64_t b;
  memcpy(&b, &v, sizeof(b));
  return b;
}

static double double_of(uint64_t b) {
  double v;
  memcpy(&v, &b, sizeof(v));
  return v;
}

int ts_aerial_piece_encode(const aerial_piece *pc, int levels, uint64_t tag, uint8_t **buf, size_t *len) {
  ts_wr w;
  ts_wr_init(&w);
  ts_wr_u32(&w, PIECE_MAGIC);
  ts_wr_u32(&w, PIECE_VERSION);
  ts_wr_u64(&w, tag);
  ts_wr_u32(&w, pc->index);
  ts_wr_u32(&w, (uint32_t)pc->x0);
  ts_wr_u32(&w, (uint32_t)pc->y0);
  ts_wr_u32(&w, (uint32_t)pc->w);
  ts_wr_u32(&w, (uint32_t)pc->h);
  ts_wr_u32(&w, (uint32_t)levels);
  for (int l = 0; l < levels; l++) {
    ts_wr_u64(&w, pc->level[l].blocks);
    ts_wr_u64(&w, pc->level[l].steps);
    ts_wr_u64(&w, pc->level[l].seeds);
    ts_wr_u64(&w, pc->level[l].pairs);
  }
  ts_wr_u32(&w, (uint32_t)pc->nclass);
  for (int c = 0; c < pc->nclass; c++) {
    ts_wr_u32(&w, (uint32_t)pc->rank[c]);
    ts_wr_u64(&w, pc->cls[c].blocks);
    ts_wr_u64(&w, bits_of(pc->cls[c].usage_mean));
    ts_wr_u64(&w, bits_of(pc->cls[c].usage_variance));
  }
  for (int y = 0; y < pc->h; y++) ts_wr_bytes(&w, pc->luma + (size_t)y * pc->stride, (size_t)pc->w);
  for (int y = 0; y < pc->h; y++) ts_wr_bytes(&w, pc->rgb + 3 * (size_t)y * pc->stride, 3 * (size_t)pc->w);
  for (int y = 0; y < pc->h; y++)
    for (int x = 0; x < pc->w; x++) ts_wr_u32(&w, pc->src[(size_t)y * pc->stride + (size_t)x]);
  ts_wr_u32(&w, pc->nedits);
  if (pc->nedits > 0) ts_wr_bytes(&w, pc->edits, (size_t)pc->nedits * AERIAL_EDIT_BYTES);
  if (ts_wr_status(&w) == 0) ts_wr_u64(&w, ts_checkpoint_tag(w.buf, w.len));
  if (ts_wr_status(&w) != 0) {
    ts_wr_free(&w);
    return TS_ENOMEM;
  }
  *buf = w.buf;
  *len = w.len;
  return 0;
}

int ts_aerial_piece_decode(const uint8_t *buf, size_t len, int levels, uint64_t tag, uint32_t index, int x0, int y0,
                           int w, int h, aerial_piece *pc, char *err) {
  if (len < 8 || ts_checkpoint_tag(buf, len - 8) != ts_get_le(buf + len - 8, 8))
    return ts_error(err, TS_EPROTO, "torn or damaged (checksum)");
  ts_rd r;
  ts_rd_init(&r, buf, len - 8);
  memset(pc, 0, sizeof(*pc));
  if (ts_rd_u32(&r) != PIECE_MAGIC || ts_rd_u32(&r) != PIECE_VERSION) return ts_error(err, TS_EPROTO, "not a tile piece of this version");
  if (ts_rd_u64(&r) != tag) return ts_error(err, TS_EPROTO, "of another job");
  pc->index = ts_rd_u32(&r);
  pc->x0 = (int)ts_rd_u32(&r);
  pc->y0 = (int)ts_rd_u32(&r);
  pc->w = (int)ts_rd_u32(&r);
  pc->h = (int)ts_rd_u32(&r);
  if (r.failed || pc->index != index || pc->x0 != x0 || pc->y0 != y0 || pc->w != w || pc->h != h)
    return ts_error(err, TS_EPROTO, "of another tile");
  if ((int)ts_rd_u32(&r) != levels) return ts_error(err, TS_EPROTO, "of another pyramid");
  for (int l = 0; l < levels; l++) {
    pc->level[l].blocks = ts_rd_u64(&r);
    pc->level[l].steps = ts_rd_u64(&r);
    pc->level[l].seeds = ts_rd_u64(&r);
    pc->level[l].pairs = ts_rd_u64(&r);
  }
  uint32_t n = ts_rd_u32(&r);
  if (n > TS_FILL_MAX_CLASSES) return ts_error(err, TS_EPROTO, "%u classes", n);
  pc->nclass = (int)n;
  for (int c = 0; c < pc->nclass; c++) {
    uint32_t rank = ts_rd_u32(&r);
    if (rank >= TS_FILL_MAX_CLASSES) return ts_error(err, TS_EPROTO, "class rank %u", rank);
    pc->rank[c] = (int)rank;
    pc->cls[c].blocks = ts_rd_u64(&r);
    pc->cls[c].usage_mean = double_of(ts_rd_u64(&r));
    pc->cls[c].usage_variance = double_of(ts_rd_u64(&r));
  }
  size_t npx = (size_t)w * (size_t)h;
  pc->luma = ts_rd_bytes(&r, npx);
  pc->rgb = ts_rd_bytes(&r, 3 * npx);
  pc->src_le = ts_rd_bytes(&r, 4 * npx);
  pc->nedits = ts_rd_u32(&r);
  if (r.failed || pc->nedits > (len - 8) / AERIAL_EDIT_BYTES) return ts_error(err, TS_EPROTO, "truncated or overlong");
  pc->edits = ts_rd_bytes(&r, (size_t)pc->nedits * AERIAL_EDIT_BYTES);
  pc->stride = (size_t)w;
  if (ts_rd_done(&r, 1) != 0) return ts_error(err, TS_EPROTO, "truncated or overlong");
  return 0;
}
