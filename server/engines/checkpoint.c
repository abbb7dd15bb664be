/* checkpoint.c - see checkpoint.h.
 *
 * Layout (all little-endian):
 *   4  magic "TSCK"          4  format version (1)
 *   8  job tag               4  level, width, height, planes, stats count
 *   planes x width*height    canvas bytes
 *   width*height x 2 x u32   copy map (x, y)
 *   stats count x 64 bytes   level statistics, from `level` upwards
 *   8  FNV-1a 64 of every byte before it
 * The checksum catches a file damaged on disk; the tag a file left by
 * another job; the exact length a truncated one. */
#include "checkpoint.h"

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "cursor.h"

#define CK_MAGIC 0x4b435354u /* "TSCK" */
#define CK_VERSION 1u

static uint64_t fnv1a64(const uint8_t *p, size_t n) {
  uint64_t h = 0xcbf29ce484222325ull;
  for (size_t i = 0; i < n; i++) h = (h ^ p[i]) * 0x100000001b3ull;
  return h;
}

uint64_t ts_checkpoint_tag(const void *spec, size_t len) { return fnv1a64(spec, len); }

static uint64_t double_bits(double d) {
  uint64_t u;
  memcpy(&u, &d, sizeof(u));
  return u;
}

static double bits_double(uint64_t u) {
  double d;
  memcpy(&d, &u, sizeof(d));
  return d;
}

static void write_stats(ts_wr *w, const ts_mrf_level_stats *s) {
  ts_wr_u64(w, double_bits(s->seconds));
  ts_wr_u64(w, s->blocks);
  ts_wr_u64(w, s->steps);
  ts_wr_u64(w, s->pairs);
  ts_wr_u64(w, s->wire_bytes);
  ts_wr_u64(w, s->round_trips);
  ts_wr_u32(w, (uint32_t)s->ref_w);
  ts_wr_u32(w, (uint32_t)s->ref_h);
  ts_wr_u32(w, (uint32_t)s->out_w);
  ts_wr_u32(w, (uint32_t)s->out_h);
}

/* Sizes beyond int are refused rather than cut: a checkpoint either
 * decodes to exactly what was encoded or not at all. */
static int read_stats(ts_rd *r, ts_mrf_level_stats *s) {
  s->seconds = bits_double(ts_rd_u64(r));
  s->blocks = ts_rd_u64(r);
  s->steps = ts_rd_u64(r);
  s->pairs = ts_rd_u64(r);
  s->wire_bytes = ts_rd_u64(r);
  s->round_trips = ts_rd_u64(r);
  int *sizes[4] = {&s->ref_w, &s->ref_h, &s->out_w, &s->out_h};
  int rc = 0;
  for (int k = 0; k < 4; k++) {
    uint32_t v = ts_rd_u32(r);
    if (v > INT32_MAX) rc = TS_EPROTO;
    *sizes[k] = (int)(v & INT32_MAX);
  }
  return rc;
}

int ts_checkpoint_encode(const ts_mrf_checkpoint *ck, int levels, uint64_t tag, uint8_t **buf, size_t *len,
                         char *err) {
  size_t npx = (size_t)ck->width * ck->height;
  ts_wr w;
  ts_wr_init(&w);
  ts_wr_u32(&w, CK_MAGIC);
  ts_wr_u32(&w, CK_VERSION);
  ts_wr_u64(&w, tag);
  ts_wr_u32(&w, (uint32_t)ck->level);
  ts_wr_u32(&w, (uint32_t)ck->width);
  ts_wr_u32(&w, (uint32_t)ck->height);
  ts_wr_u32(&w, (uint32_t)ck->nplanes);
  ts_wr_u32(&w, (uint32_t)(levels - ck->level));
  for (int k = 0; k < ck->nplanes; k++) ts_wr_bytes(&w, ck->planes[k], npx);
  for (size_t i = 0; i < 2 * npx; i++) ts_wr_u32(&w, ck->copy[i]);
  for (int l = ck->level; l < levels; l++) write_stats(&w, &ck->stats[l]);
  if (ts_wr_status(&w) == 0) ts_wr_u64(&w, fnv1a64(w.buf, w.len));
  if (ts_wr_status(&w) != 0) {
    ts_wr_free(&w);
    return ts_error(err, TS_ENOMEM, "out of memory encoding a checkpoint");
  }
  *buf = w.buf;
  *len = w.len;
  return 0;
}

/* The fixed header; checks what can be checked before any allocation. */
static int read_header(ts_rd *r, uint64_t tag, uint64_t max_pixels, ts_mrf_checkpoint *ck, uint32_t *nstats,
                       char *err) {
  uint32_t magic = ts_rd_u32(r), version = ts_rd_u32(r);
  uint64_t file_tag = ts_rd_u64(r);
  uint32_t level = ts_rd_u32(r), w = ts_rd_u32(r), h = ts_rd_u32(r), planes = ts_rd_u32(r);
  *nstats = ts_rd_u32(r);
  if (ts_rd_done(r, 0) != 0 || magic != CK_MAGIC) return ts_error(err, TS_EPROTO, "not a texsyn checkpoint");
  if (version != CK_VERSION)
    return ts_error(err, TS_EPROTO, "checkpoint format %u, this build reads %u", version, CK_VERSION);
  if (file_tag != tag) return ts_error(err, TS_EPROTO, "checkpoint of another job spec");
  if (level < 1 || level >= TS_MRF_MAX_LEVELS || *nstats < 1 || level + *nstats > TS_MRF_MAX_LEVELS)
    return ts_error(err, TS_EPROTO, "checkpoint of level %u with %u levels of statistics", level, *nstats);
  if (w < 1 || h < 1 || (uint64_t)w * h > max_pixels)
    return ts_error(err, TS_EPROTO, "checkpoint canvas %ux%u is outside 1..%llu pixels", w, h,
                    (unsigned long long)max_pixels);
  if (planes < 1 || planes > TS_MAX_PLANES) return ts_error(err, TS_EPROTO, "checkpoint with %u planes", planes);
  ck->level = (int)level;
  ck->width = (int)w;
  ck->height = (int)h;
  ck->nplanes = (int)planes;
  return 0;
}

static uint64_t stored_checksum(const uint8_t *p) {
  ts_rd r;
  ts_rd_init(&r, p, 8);
  return ts_rd_u64(&r);
}

int ts_checkpoint_decode(const uint8_t *buf, size_t len, uint64_t tag, uint64_t max_pixels,
                         ts_mrf_checkpoint *ck, char *err) {
  memset(ck, 0, sizeof(*ck));
  if (len < 8 || fnv1a64(buf, len - 8) != stored_checksum(buf + len - 8))
    return ts_error(err, TS_EPROTO, "checkpoint is truncated or damaged (checksum mismatch)");
  ts_rd r;
  ts_rd_init(&r, buf, len - 8);
  uint32_t nstats;
  int rc = read_header(&r, tag, max_pixels, ck, &nstats, err);
  if (rc != 0) return rc;
  size_t npx = (size_t)ck->width * ck->height;
  /* Sizes are known now: refuse a wrong length before allocating. */
  if (r.len - r.off != npx * (size_t)ck->nplanes + npx * 8 + (size_t)nstats * 64)
    return ts_error(err, TS_EPROTO, "checkpoint length does not match its %dx%d canvas", ck->width, ck->height);
  for (int k = 0; k < ck->nplanes && rc == 0; k++) {
    ck->planes[k] = malloc(npx);
    if (ck->planes[k] == NULL) rc = TS_ENOMEM;
    else memcpy(ck->planes[k], ts_rd_bytes(&r, npx), npx);
  }
  ck->copy = rc == 0 ? malloc(npx * 8) : NULL;
  if (ck->copy == NULL) rc = TS_ENOMEM;
  for (size_t i = 0; rc == 0 && i < 2 * npx; i++) ck->copy[i] = ts_rd_u32(&r);
  for (uint32_t s = 0; rc == 0 && s < nstats; s++) rc = read_stats(&r, &ck->stats[ck->level + (int)s]);
  if (rc == 0 && ts_rd_done(&r, 1) != 0) rc = TS_EPROTO;
  if (rc != 0) {
    ts_checkpoint_free(ck);
    return ts_error(err, rc, rc == TS_ENOMEM ? "out of memory reading a checkpoint" : "malformed checkpoint");
  }
  return 0;
}

void ts_checkpoint_free(ts_mrf_checkpoint *ck) {
  for (int k = 0; k < TS_MAX_PLANES; k++) free(ck->planes[k]);
  free(ck->copy);
  memset(ck, 0, sizeof(*ck));
}
