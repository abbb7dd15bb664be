/* checkpoint.c - see checkpoint.h.
 *
 * Layout (all little-endian), format 2:
 *   4  magic "TSCK"          4  format version (2)
 *   8  job tag
 *   8  wall-clock time       8  checkpoint interval (IEEE doubles, seconds)
 *   4  level                 8  step, 8 steps (step == steps: the level is finished)
 *   4  width, height, planes, stats count
 *   4  coarse width, height, reference width, height (inside a level; else 0)
 *   planes x width*height    canvas bytes
 *   width*height x 2 x u32   copy map (x, y)
 *   inside a level only:
 *     width*height           placed blocks (0 or 1)
 *     planes x coarse w*h    the level above's canvas (0x0 at the coarsest)
 *     ref w*h x u32          usage counters
 *   stats count x 64 bytes   level statistics, from `level` upwards
 *   8  FNV-1a 64 of every byte before it
 * The checksum catches a file damaged on disk; the tag a file left by
 * another job; the version one left by an older build (format 1 had no
 * checkpoints inside a level); the exact length a truncated one. */
#include "checkpoint.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "cursor.h"

#define CK_MAGIC 0x4b435354u /* "TSCK" */
#define CK_VERSION 2u

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

static int inside_level(const ts_mrf_checkpoint *ck) { return ck->step < ck->steps; }

/* Arrays of u32 go through a chunk: a call per value would cost more than
 * the rest of a checkpoint of the finest level together. */
static void write_u32s(ts_wr *w, const uint32_t *v, size_t n) {
  uint8_t chunk[4096];
  for (size_t i = 0; i < n;) {
    size_t k = 0;
    for (; k < sizeof(chunk) && i < n; k += 4, i++) ts_put_le(chunk + k, v[i], 4);
    ts_wr_bytes(w, chunk, k);
  }
}

int ts_checkpoint_encode(const ts_mrf_checkpoint *ck, int levels, uint64_t tag, uint8_t **buf, size_t *len,
                         char *err) {
  size_t npx = (size_t)ck->width * ck->height, cnpx = (size_t)ck->coarse_width * ck->coarse_height;
  int inside = inside_level(ck);
  ts_wr w;
  ts_wr_init(&w);
  ts_wr_u32(&w, CK_MAGIC);
  ts_wr_u32(&w, CK_VERSION);
  ts_wr_u64(&w, tag);
  ts_wr_u64(&w, double_bits(ck->saved_at));
  ts_wr_u64(&w, double_bits(ck->interval));
  ts_wr_u32(&w, (uint32_t)ck->level);
  ts_wr_u64(&w, ck->step);
  ts_wr_u64(&w, ck->steps);
  ts_wr_u32(&w, (uint32_t)ck->width);
  ts_wr_u32(&w, (uint32_t)ck->height);
  ts_wr_u32(&w, (uint32_t)ck->nplanes);
  ts_wr_u32(&w, (uint32_t)(levels - ck->level));
  ts_wr_u32(&w, inside ? (uint32_t)ck->coarse_width : 0);
  ts_wr_u32(&w, inside ? (uint32_t)ck->coarse_height : 0);
  ts_wr_u32(&w, inside ? (uint32_t)ck->ref_width : 0);
  ts_wr_u32(&w, inside ? (uint32_t)ck->ref_height : 0);
  for (int k = 0; k < ck->nplanes; k++) ts_wr_bytes(&w, ck->planes[k], npx);
  write_u32s(&w, ck->copy, 2 * npx);
  if (inside) {
    ts_wr_bytes(&w, ck->done, npx);
    for (int k = 0; k < ck->nplanes; k++) ts_wr_bytes(&w, ck->coarse[k], cnpx);
    write_u32s(&w, ck->usage, (size_t)ck->ref_width * ck->ref_height);
  }
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

/* A w x h image of the checkpoint within 1..max_pixels pixels. */
static int check_size(const char *what, uint32_t w, uint32_t h, uint64_t max_pixels, char *err) {
  if (w < 1 || h < 1 || w > INT32_MAX || h > INT32_MAX || (uint64_t)w * h > max_pixels)
    return ts_error(err, TS_EPROTO, "checkpoint %s %ux%u is outside 1..%llu pixels", what, w, h,
                    (unsigned long long)max_pixels);
  return 0;
}

/* The sizes of what follows a checkpoint inside a level, and nothing
 * of them at a level's end. The coarsest level (one level of statistics)
 * has no level above it. */
static int check_inside_sizes(const ts_mrf_checkpoint *ck, uint32_t cw, uint32_t ch, uint32_t rw, uint32_t rh,
                              uint32_t nstats, uint64_t max_pixels, char *err) {
  if (!inside_level(ck))
    return cw == 0 && ch == 0 && rw == 0 && rh == 0
               ? 0
               : ts_error(err, TS_EPROTO, "checkpoint after level %d with the sizes of one inside it", ck->level);
  int rc = check_size("reference", rw, rh, max_pixels, err);
  if (rc == 0 && nstats == 1 && (cw != 0 || ch != 0))
    rc = ts_error(err, TS_EPROTO, "checkpoint inside the coarsest level with a %ux%u level above it", cw, ch);
  if (rc == 0 && nstats > 1) rc = check_size("coarse canvas", cw, ch, max_pixels, err);
  return rc;
}

/* The fixed header; checks what can be checked before any allocation. */
static int read_header(ts_rd *r, uint64_t tag, uint64_t max_pixels, ts_mrf_checkpoint *ck, uint32_t *nstats,
                       char *err) {
  uint32_t magic = ts_rd_u32(r), version = ts_rd_u32(r);
  uint64_t file_tag = ts_rd_u64(r);
  ck->saved_at = bits_double(ts_rd_u64(r));
  ck->interval = bits_double(ts_rd_u64(r));
  uint32_t level = ts_rd_u32(r);
  ck->step = ts_rd_u64(r);
  ck->steps = ts_rd_u64(r);
  uint32_t w = ts_rd_u32(r), h = ts_rd_u32(r), planes = ts_rd_u32(r);
  *nstats = ts_rd_u32(r);
  uint32_t cw = ts_rd_u32(r), ch = ts_rd_u32(r), rw = ts_rd_u32(r), rh = ts_rd_u32(r);
  if (magic != CK_MAGIC) return ts_error(err, TS_EPROTO, "not a texsyn checkpoint");
  /* Before the header's length: format 1's was shorter. */
  if (version != CK_VERSION)
    return ts_error(err, TS_EPROTO, "checkpoint format %u, this build reads %u", version, CK_VERSION);
  if (ts_rd_done(r, 0) != 0) return ts_error(err, TS_EPROTO, "checkpoint header is truncated");
  if (file_tag != tag) return ts_error(err, TS_EPROTO, "checkpoint of another job spec");
  int inside = ck->step < ck->steps;
  if (level >= TS_MRF_MAX_LEVELS || (level < 1 && !inside) || *nstats < 1 || level + *nstats > TS_MRF_MAX_LEVELS)
    return ts_error(err, TS_EPROTO, "checkpoint %s level %u with %u levels of statistics",
                    inside ? "inside" : "after", level, *nstats);
  if (ck->step > ck->steps || ck->steps < 1)
    return ts_error(err, TS_EPROTO, "checkpoint at step %llu of %llu", (unsigned long long)ck->step,
                    (unsigned long long)ck->steps);
  if (!isfinite(ck->saved_at) || !(ck->interval >= 0 && isfinite(ck->interval)))
    return ts_error(err, TS_EPROTO, "checkpoint with time %g and interval %g", ck->saved_at, ck->interval);
  int rc = check_size("canvas", w, h, max_pixels, err);
  if (rc != 0) return rc;
  if (planes < 1 || planes > TS_MAX_PLANES) return ts_error(err, TS_EPROTO, "checkpoint with %u planes", planes);
  ck->level = (int)level;
  ck->width = (int)w;
  ck->height = (int)h;
  ck->nplanes = (int)planes;
  rc = check_inside_sizes(ck, cw, ch, rw, rh, *nstats, max_pixels, err);
  ck->coarse_width = (int)cw;
  ck->coarse_height = (int)ch;
  ck->ref_width = (int)rw;
  ck->ref_height = (int)rh;
  return rc;
}

/* Takes n items of `size` bytes from the `left` ones; -1 if they are not
 * there (never overflows, whatever the header claims). */
static int take(uint64_t *left, uint64_t n, uint64_t size) {
  if (size > 0 && n > *left / size) return -1;
  *left -= n * size;
  return 0;
}

/* The body must be exactly what the header's sizes say. */
static int body_fits(const ts_mrf_checkpoint *ck, uint32_t nstats, uint64_t left) {
  uint64_t npx = (uint64_t)ck->width * (uint64_t)ck->height;
  uint64_t cnpx = (uint64_t)ck->coarse_width * (uint64_t)ck->coarse_height;
  uint64_t rnpx = (uint64_t)ck->ref_width * (uint64_t)ck->ref_height;
  /* At a level's end there are no placed blocks, and cnpx = rnpx = 0. */
  int bad = take(&left, npx, (uint64_t)ck->nplanes) || take(&left, npx, 8) ||
            take(&left, npx, (uint64_t)inside_level(ck)) || take(&left, cnpx, (uint64_t)ck->nplanes) ||
            take(&left, rnpx, 4) || take(&left, nstats, 64);
  return !bad && left == 0;
}

/* malloc'd copy of the next n bytes, or NULL. */
static uint8_t *read_copy(ts_rd *r, size_t n) {
  uint8_t *p = malloc(n ? n : 1);
  if (p != NULL) memcpy(p, ts_rd_bytes(r, n), n);
  return p;
}

static uint32_t *read_u32s(ts_rd *r, size_t n) {
  uint32_t *v = malloc(n * sizeof(uint32_t));
  const uint8_t *p = ts_rd_bytes(r, 4 * n);
  for (size_t i = 0; v != NULL && i < n; i++) v[i] = (uint32_t)ts_get_le(p + 4 * i, 4);
  return v;
}

/* The body, once its length is known to match: 0 or TS_ENOMEM. */
static int read_body(ts_rd *r, ts_mrf_checkpoint *ck) {
  size_t npx = (size_t)ck->width * ck->height, cnpx = (size_t)ck->coarse_width * ck->coarse_height;
  int ok = 1;
  for (int k = 0; k < ck->nplanes; k++) ok = ok && (ck->planes[k] = read_copy(r, npx)) != NULL;
  ok = ok && (ck->copy = read_u32s(r, 2 * npx)) != NULL;
  if (!inside_level(ck)) return ok ? 0 : TS_ENOMEM;
  ok = ok && (ck->done = read_copy(r, npx)) != NULL;
  for (int k = 0; cnpx > 0 && k < ck->nplanes; k++) ok = ok && (ck->coarse[k] = read_copy(r, cnpx)) != NULL;
  ok = ok && (ck->usage = read_u32s(r, (size_t)ck->ref_width * ck->ref_height)) != NULL;
  return ok ? 0 : TS_ENOMEM;
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
  /* Sizes are known now: refuse a wrong length before allocating. */
  if (rc == 0 && !body_fits(ck, nstats, r.len - r.off))
    rc = ts_error(err, TS_EPROTO, "checkpoint length does not match its %dx%d canvas", ck->width, ck->height);
  if (rc != 0) {
    memset(ck, 0, sizeof(*ck));
    return rc;
  }
  rc = read_body(&r, ck);
  for (uint32_t s = 0; rc == 0 && s < nstats; s++) rc = read_stats(&r, &ck->stats[ck->level + (int)s]);
  if (rc == 0 && ts_rd_done(&r, 1) != 0) rc = TS_EPROTO;
  if (rc != 0) {
    ts_checkpoint_free(ck);
    return ts_error(err, rc, rc == TS_ENOMEM ? "out of memory reading a checkpoint" : "malformed checkpoint");
  }
  return 0;
}

void ts_checkpoint_free(ts_mrf_checkpoint *ck) {
  for (int k = 0; k < TS_MAX_PLANES; k++) {
    free(ck->planes[k]);
    free(ck->coarse[k]);
  }
  free(ck->copy);
  free(ck->done);
  free(ck->usage);
  memset(ck, 0, sizeof(*ck));
}
