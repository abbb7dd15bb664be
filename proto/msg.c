/* msg.c - see msg.h. Every reader ends with ts_rd_done(exact): a payload
 * that is short, or longer than its message, is a protocol error. */
#include "msg.h"

#include <stddef.h>
#include <stdio.h>
#include <string.h>

#include "error.h"
#include "patchmatch.h"

static int bad(char *err, char type, const char *what) {
  return ts_error(err, TS_EPROTO, "malformed '%c' message: %s", type, what);
}

static int finish(const ts_rd *r, char *err, char type) {
  return ts_rd_done(r, 1) == 0 ? 0 : bad(err, type, "wrong payload length");
}

void ts_wr_str(ts_wr *w, const char *s) {
  size_t n = strlen(s);
  if (n > UINT16_MAX) n = UINT16_MAX;
  ts_wr_u16(w, (uint16_t)n);
  ts_wr_bytes(w, s, n);
}

void ts_rd_str(ts_rd *r, char *buf, size_t cap) {
  uint16_t n = ts_rd_u16(r);
  const uint8_t *p = ts_rd_bytes(r, n);
  buf[0] = '\0';
  if (p == NULL) return;
  if (n >= cap || memchr(p, 0, n) != NULL) {
    r->failed = 1;
    return;
  }
  memcpy(buf, p, n);
  buf[n] = '\0';
}

static uint32_t le32(const uint8_t *p) {
  return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static uint64_t le64(const uint8_t *p) { return (uint64_t)le32(p) | (uint64_t)le32(p + 4) << 32; }

/* ---- I ------------------------------------------------------------------ */

void ts_msg_ident_write(ts_wr *w, const ts_msg_ident *m) {
  ts_wr_u8(w, m->role);
  ts_wr_u32(w, m->caps);
  ts_wr_u16(w, m->threads);
  ts_wr_u8(w, m->simd);
  ts_wr_str(w, m->name);
  if (m->modbus_port != 0) ts_wr_u16(w, m->modbus_port);
}

int ts_msg_ident_read(const ts_frame *f, ts_msg_ident *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  m->role = ts_rd_u8(&r);
  m->caps = ts_rd_u32(&r);
  m->threads = ts_rd_u16(&r);
  m->simd = ts_rd_u8(&r);
  ts_rd_str(&r, m->name, sizeof(m->name));
  m->modbus_port = r.len - r.off == 2 ? ts_rd_u16(&r) : 0; /* optional trailing field */
  if (finish(&r, err, 'I') != 0) return TS_EPROTO;
  if (m->role < TS_ROLE_COORD || m->role > TS_ROLE_CLIENT) return bad(err, 'I', "unknown role");
  if (m->simd >= TS_SIMD_COUNT) return bad(err, 'I', "unknown kernel variant");
  return 0;
}

/* ---- A ------------------------------------------------------------------ */

static int auth_has_nonce(uint8_t step) { return step == TS_AUTH_CHALLENGE || step == TS_AUTH_RESPONSE; }
static int auth_has_mac(uint8_t step) { return step == TS_AUTH_RESPONSE || step == TS_AUTH_PROOF; }

void ts_msg_auth_write(ts_wr *w, const ts_msg_auth *m) {
  ts_wr_u8(w, m->step);
  if (auth_has_nonce(m->step)) {
    ts_wr_bytes(w, m->nonce, TS_AUTH_NONCE);
    ts_wr_u8(w, m->key_kind);
    ts_wr_str(w, m->key_name);
  }
  if (auth_has_mac(m->step)) ts_wr_bytes(w, m->mac, TS_AUTH_MAC);
}

/* A key's name: what a log line and a job's owner field can show as is. */
static int key_name_ok(const char *s) {
  for (; *s; s++)
    if (!((*s >= 'a' && *s <= 'z') || (*s >= 'A' && *s <= 'Z') || (*s >= '0' && *s <= '9') || strchr("._@-", *s)))
      return 0;
  return 1;
}

int ts_msg_auth_read(const ts_frame *f, ts_msg_auth *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  memset(m, 0, sizeof(*m));
  m->step = ts_rd_u8(&r);
  if (r.failed || m->step < TS_AUTH_CHALLENGE || m->step > TS_AUTH_PROOF) return bad(err, 'A', "unknown step");
  const uint8_t *p;
  if (auth_has_nonce(m->step) && (p = ts_rd_bytes(&r, TS_AUTH_NONCE)) != NULL) {
    memcpy(m->nonce, p, TS_AUTH_NONCE);
    m->key_kind = ts_rd_u8(&r);
    ts_rd_str(&r, m->key_name, sizeof(m->key_name));
  }
  if (auth_has_mac(m->step) && (p = ts_rd_bytes(&r, TS_AUTH_MAC)) != NULL) memcpy(m->mac, p, TS_AUTH_MAC);
  if (finish(&r, err, 'A') != 0) return TS_EPROTO;
  if (m->key_kind > 4 || !key_name_ok(m->key_name)) return bad(err, 'A', "key kind or name out of range");
  if (m->step == TS_AUTH_RESPONSE && (m->key_kind == 0 || m->key_name[0] == '\0'))
    return bad(err, 'A', "a response must name its key");
  return 0;
}

/* ---- C ------------------------------------------------------------------ */

void ts_msg_calib_req_write(ts_wr *w, const ts_msg_calib_req *m) { ts_wr_u32(w, m->millis); }

int ts_msg_calib_req_read(const ts_frame *f, ts_msg_calib_req *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  m->millis = ts_rd_u32(&r);
  if (finish(&r, err, 'C') != 0) return TS_EPROTO;
  if (m->millis < 1 || m->millis > 10000) return bad(err, 'C', "calibration time outside 1..10000 ms");
  return 0;
}

void ts_msg_calib_write(ts_wr *w, const ts_msg_calib *m) {
  ts_wr_u64(w, m->pairs);
  ts_wr_u64(w, m->nanos);
  if (m->max_payload == 0) return;
  ts_wr_u32(w, m->max_payload);
  ts_wr_u64(w, m->max_message);
}

#define CALIB_LIMITS_BYTES 12 /* the optional trailing limits */

int ts_msg_calib_read(const ts_frame *f, ts_msg_calib *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  m->pairs = ts_rd_u64(&r);
  m->nanos = ts_rd_u64(&r);
  m->max_payload = 0;
  m->max_message = 0;
  if (r.len - r.off == CALIB_LIMITS_BYTES) { /* optional: only to a coordinator with TS_CAP_PIECES */
    m->max_payload = ts_rd_u32(&r);
    m->max_message = ts_rd_u64(&r);
    if (m->max_payload < TS_FRAME_LIMIT_MIN || m->max_message < TS_FRAME_LIMIT_MIN)
      return bad(err, 'C', "frame or message limit under 1024 bytes");
  }
  if (finish(&r, err, 'C') != 0) return TS_EPROTO;
  if (m->pairs == 0 || m->nanos == 0) return bad(err, 'C', "empty calibration");
  return 0;
}

/* ---- N ------------------------------------------------------------------ */

static void wr_box(ts_wr *w, const ts_box *b) {
  ts_wr_u16(w, (uint16_t)b->dx0);
  ts_wr_u16(w, (uint16_t)b->dy0);
  ts_wr_u16(w, (uint16_t)b->dx1);
  ts_wr_u16(w, (uint16_t)b->dy1);
}

static void rd_box(ts_rd *r, ts_box *b) {
  b->dx0 = (int16_t)ts_rd_u16(r);
  b->dy0 = (int16_t)ts_rd_u16(r);
  b->dx1 = (int16_t)ts_rd_u16(r);
  b->dy1 = (int16_t)ts_rd_u16(r);
}

static void wr_window(ts_wr *w, const ts_window_spec *s) {
  for (int src = 0; src < TS_NSRC; src++) ts_wr_u8(w, (uint8_t)s->nplanes[src]);
  ts_wr_u16(w, (uint16_t)s->centre);
  ts_wr_u16(w, (uint16_t)s->block);
  for (int src = 0; src < TS_NSRC; src++) {
    if (s->nplanes[src] == 0) continue;
    wr_box(w, &s->extent[src]);
    ts_wr_u16(w, (uint16_t)s->noff[src]);
    for (int k = 0; k < s->noff[src]; k++) {
      ts_wr_u16(w, (uint16_t)s->dx[src][k]);
      ts_wr_u16(w, (uint16_t)s->dy[src][k]);
    }
  }
  ts_wr_u8(w, (uint8_t)s->nparts);
  for (int p = 0; p < s->nparts; p++) {
    ts_wr_u8(w, s->part[p].source);
    ts_wr_u8(w, s->part[p].plane0);
    ts_wr_u8(w, s->part[p].nplanes);
    ts_wr_u32(w, s->part[p].weight);
  }
  ts_wr_u8(w, s->known != NULL);
  if (s->known != NULL) ts_wr_bytes(w, s->known, (size_t)s->noff[TS_SRC_FINE]);
}

/* Reads a window into m->win, its offsets into m->offbuf. Counts are
 * bounded here so the reads stay in offbuf; the rest is ts_window_init's
 * to check. */
static int rd_window(ts_rd *r, ts_window_spec *s, int16_t *o, uint8_t *knownbuf, char *err) {
  for (int src = 0; src < TS_NSRC; src++) s->nplanes[src] = ts_rd_u8(r);
  s->centre = ts_rd_u16(r);
  s->block = ts_rd_u16(r);
  for (int src = 0; src < TS_NSRC; src++) {
    if (s->nplanes[src] == 0) continue;
    rd_box(r, &s->extent[src]);
    s->noff[src] = ts_rd_u16(r);
    if (s->noff[src] > TS_WIN_MAX_OFFSETS) return bad(err, 'N', "too many window offsets");
    s->dx[src] = o;
    s->dy[src] = o + s->noff[src];
    for (int k = 0; k < s->noff[src]; k++) {
      o[k] = (int16_t)ts_rd_u16(r);
      o[s->noff[src] + k] = (int16_t)ts_rd_u16(r);
    }
    o += 2 * s->noff[src];
  }
  s->nparts = ts_rd_u8(r);
  if (s->nparts > TS_L1_MAX_PARTS) return bad(err, 'N', "too many weighted parts");
  for (int p = 0; p < s->nparts; p++) {
    s->part[p].source = ts_rd_u8(r);
    s->part[p].plane0 = ts_rd_u8(r);
    s->part[p].nplanes = ts_rd_u8(r);
    s->part[p].weight = ts_rd_u32(r);
  }
  uint8_t known = ts_rd_u8(r);
  if (known > 1) return bad(err, 'N', "known-offsets flag");
  if (known) {
    const uint8_t *k = ts_rd_bytes(r, (size_t)s->noff[TS_SRC_FINE]);
    if (k != NULL) memcpy(knownbuf, k, (size_t)s->noff[TS_SRC_FINE]);
    s->known = knownbuf;
  }
  return 0;
}

static int slice_has_planes(const ts_slice_desc *m) { return m->labelled || m->masked; }

/* Rows [y0, k0) and [k1, y1), `row` bytes each: what travels of rows
 * [y0, y1) when [k0, k1) are kept. */
static void wr_rows(ts_wr *w, ts_slice_rows r, size_t row, int y0, int y1, int k0, int k1) {
  ts_wr_bytes(w, r.lo, row * (size_t)(k0 - y0));
  ts_wr_bytes(w, r.hi, row * (size_t)(y1 - k1));
}

static ts_slice_rows rd_rows(ts_rd *r, size_t row, int y0, int y1, int k0, int k1) {
  ts_slice_rows out;
  out.lo = ts_rd_bytes(r, row * (size_t)(k0 - y0));
  out.hi = ts_rd_bytes(r, row * (size_t)(y1 - k1));
  return out;
}

/* A label tile: its sides (1..TS_SLICE_MAX_TILE) and bytes. */
static int rd_tile(ts_rd *r, ts_slice_desc *m, char *err) {
  m->tile_w = ts_rd_u8(r);
  m->tile_h = ts_rd_u8(r);
  if (m->tile_w < 1 || m->tile_h < 1 || m->tile_w > TS_SLICE_MAX_TILE || m->tile_h > TS_SLICE_MAX_TILE)
    return bad(err, 'N', "label tile size");
  const uint8_t *t = ts_rd_bytes(r, (size_t)m->tile_w * m->tile_h);
  if (t != NULL) memcpy(m->tile, t, (size_t)m->tile_w * m->tile_h);
  return 0;
}

/* A partitioned set's codebook (lbg.h): its mode, then for a partitioned
 * set the probe, the vector size, the partitions of every class and the
 * centroids, class after class. */
static void wr_lbg(ts_wr *w, const ts_lbg_codebook *cb, int nclass) {
  ts_wr_u8(w, cb->mode);
  if (cb->mode == TS_LBG_OFF) return;
  ts_wr_u32(w, cb->probe);
  ts_wr_u32(w, cb->vbytes);
  uint64_t n = 0;
  for (int c = 0; c < nclass; c++) {
    ts_wr_u32(w, cb->npart[c]);
    n += cb->npart[c];
  }
  ts_wr_bytes(w, cb->cent, (size_t)n * cb->vbytes);
}

/* Sizes bounded here so the centroids lie in the payload; whether the
 * codebook fits the set is ts_slice_load's to check (ts_lbg_check). */
static int rd_lbg(ts_rd *r, ts_lbg_codebook *cb, int nclass, char *err) {
  cb->mode = ts_rd_u8(r);
  if (cb->mode == TS_LBG_OFF) return 0;
  if (cb->mode > TS_LBG_EXACT) return bad(err, 'N', "partitioning mode");
  cb->probe = ts_rd_u32(r);
  cb->vbytes = ts_rd_u32(r);
  cb->nclass = nclass;
  if (cb->vbytes == 0 || cb->vbytes % TS_L1_CHUNK != 0 || cb->vbytes > TS_L1_MAX_CHUNKS * TS_L1_CHUNK)
    return bad(err, 'N', "codebook vector size");
  uint64_t n = 0;
  for (int c = 0; c < nclass; c++) {
    cb->npart[c] = ts_rd_u32(r);
    if (cb->npart[c] > TS_LBG_MAX_PARTITIONS) return bad(err, 'N', "partitions of a class");
    n += cb->npart[c];
  }
  if (r->failed || n * cb->vbytes > r->len - r->off) return bad(err, 'N', "truncated codebook");
  cb->cent = ts_rd_bytes(r, (size_t)n * cb->vbytes);
  return 0;
}

void ts_msg_slice_write(ts_wr *w, const ts_slice_desc *m) {
  ts_wr_u32(w, m->set);
  ts_wr_u32(w, m->gen);
  ts_wr_u32(w, m->image);
  wr_window(w, &m->win);
  ts_wr_u32(w, (uint32_t)m->w);
  ts_wr_u32(w, (uint32_t)m->h);
  ts_wr_u32(w, (uint32_t)m->cw);
  ts_wr_u32(w, (uint32_t)m->ch);
  ts_wr_u16(w, m->nclass);
  ts_wr_u8(w, m->labelled);
  ts_wr_u8(w, m->masked);
  if (m->labelled == TS_SLICE_LABELS_TILE) {
    ts_wr_u8(w, m->tile_w);
    ts_wr_u8(w, m->tile_h);
    ts_wr_bytes(w, m->tile, (size_t)m->tile_w * m->tile_h);
  }
  for (int c = 0; c < m->nclass; c++) {
    ts_wr_u32(w, m->count[c]);
    ts_wr_u32(w, m->i0[c]);
    ts_wr_u32(w, m->i1[c]);
  }
  ts_wr_u32(w, (uint32_t)m->ay0);
  ts_wr_u32(w, (uint32_t)m->ay1);
  for (int c = 0; c < m->nclass && slice_has_planes(m); c++) ts_wr_u32(w, m->above[c]);
  ts_wr_u32(w, (uint32_t)m->fy0);
  ts_wr_u32(w, (uint32_t)m->fy1);
  ts_wr_u32(w, (uint32_t)m->cy0);
  ts_wr_u32(w, (uint32_t)m->cy1);
  ts_wr_u32(w, m->base_gen);
  const int32_t kept[6] = {m->kfy0, m->kfy1, m->kcy0, m->kcy1, m->kay0, m->kay1};
  for (int k = 0; k < 6; k++) ts_wr_u32(w, (uint32_t)kept[k]);
  ts_wr_u8(w, m->fine_from_image);
  if (m->fine_from_image) ts_wr_u64(w, m->fine_sum);
  size_t w1 = (size_t)m->w, cw = (size_t)m->cw;
  for (int p = 0; p < m->win.nplanes[TS_SRC_FINE] && !m->fine_from_image; p++)
    wr_rows(w, m->fine[p], w1, m->fy0, m->fy1, m->kfy0, m->kfy1);
  for (int p = 0; p < m->win.nplanes[TS_SRC_COARSE]; p++)
    wr_rows(w, m->coarse[p], cw, m->cy0, m->cy1, m->kcy0, m->kcy1);
  if (m->labelled == TS_SLICE_LABELS_ROWS) wr_rows(w, m->labels, w1, m->ay0, m->ay1, m->kay0, m->kay1);
  if (m->masked) wr_rows(w, m->valid, w1, m->ay0, m->ay1, m->kay0, m->kay1);
  ts_wr_u8(w, m->usage);
  if (m->usage == TS_SLICE_USAGE_COUNTS) wr_rows(w, m->counts, 4 * w1, m->fy0, m->fy1, m->kfy0, m->kfy1);
  wr_lbg(w, &m->lbg, m->nclass);
}

/* What the row reads below need: sizes and row ranges within the levels
 * (window, anchors and vector ranges are ts_slice_load's to check). */
static int slice_check_geometry(const ts_slice_desc *m, char *err) {
  int coarse = m->win.nplanes[TS_SRC_COARSE] > 0;
  if (m->w < 1 || m->h < 1 || m->w > TS_SLICE_MAX_SIDE || m->h > TS_SLICE_MAX_SIDE ||
      (uint64_t)m->w * (uint64_t)m->h > TS_SLICE_MAX_PIXELS)
    return bad(err, 'N', "level size");
  if (coarse ? (m->cw < 1 || m->ch < 1 || m->cw > m->w || m->ch > m->h) : (m->cw != 0 || m->ch != 0))
    return bad(err, 'N', "coarse level size");
  if (m->nclass < 1 || m->nclass > TS_MAX_CLASSES || m->labelled > TS_SLICE_LABELS_TILE || m->masked > 1)
    return bad(err, 'N', "classes, label or validity flag");
  if (m->fine_from_image > 1) return bad(err, 'N', "fine-rows-from-image flag");
  if (m->ay0 < 0 || m->ay0 >= m->ay1 || m->ay1 > m->h) return bad(err, 'N', "anchor row range");
  if (m->fy0 < 0 || m->fy0 >= m->fy1 || m->fy1 > m->h) return bad(err, 'N', "fine row range");
  if (coarse ? (m->cy0 < 0 || m->cy0 >= m->cy1 || m->cy1 > m->ch) : (m->cy0 != 0 || m->cy1 != 0))
    return bad(err, 'N', "coarse row range");
  if (m->kfy0 < m->fy0 || m->kfy0 > m->kfy1 || m->kfy1 > m->fy1 || m->kcy0 < m->cy0 || m->kcy0 > m->kcy1 ||
      m->kcy1 > m->cy1 || m->kay0 < m->ay0 || m->kay0 > m->kay1 || m->kay1 > m->ay1)
    return bad(err, 'N', "kept rows outside the rows read");
  return 0;
}

int ts_msg_slice_read(const ts_frame *f, ts_slice_desc *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  memset(m, 0, offsetof(ts_slice_desc, offbuf));
  m->set = ts_rd_u32(&r);
  m->gen = ts_rd_u32(&r);
  m->image = ts_rd_u32(&r);
  int rc = rd_window(&r, &m->win, m->offbuf, m->knownbuf, err);
  if (rc != 0) return rc;
  m->w = (int32_t)ts_rd_u32(&r);
  m->h = (int32_t)ts_rd_u32(&r);
  m->cw = (int32_t)ts_rd_u32(&r);
  m->ch = (int32_t)ts_rd_u32(&r);
  m->nclass = ts_rd_u16(&r);
  m->labelled = ts_rd_u8(&r);
  m->masked = ts_rd_u8(&r);
  if (m->nclass > TS_MAX_CLASSES) return bad(err, 'N', "classes");
  if (m->labelled == TS_SLICE_LABELS_TILE && (rc = rd_tile(&r, m, err)) != 0) return rc;
  for (int c = 0; c < m->nclass; c++) {
    m->count[c] = ts_rd_u32(&r);
    m->i0[c] = ts_rd_u32(&r);
    m->i1[c] = ts_rd_u32(&r);
  }
  m->ay0 = (int32_t)ts_rd_u32(&r);
  m->ay1 = (int32_t)ts_rd_u32(&r);
  for (int c = 0; c < m->nclass && slice_has_planes(m); c++) m->above[c] = ts_rd_u32(&r);
  m->fy0 = (int32_t)ts_rd_u32(&r);
  m->fy1 = (int32_t)ts_rd_u32(&r);
  m->cy0 = (int32_t)ts_rd_u32(&r);
  m->cy1 = (int32_t)ts_rd_u32(&r);
  m->base_gen = ts_rd_u32(&r);
  int32_t *kept[6] = {&m->kfy0, &m->kfy1, &m->kcy0, &m->kcy1, &m->kay0, &m->kay1};
  for (int k = 0; k < 6; k++) *kept[k] = (int32_t)ts_rd_u32(&r);
  m->fine_from_image = ts_rd_u8(&r);
  if (m->fine_from_image == 1) m->fine_sum = ts_rd_u64(&r);
  if (r.failed) return bad(err, 'N', "truncated header");
  rc = slice_check_geometry(m, err);
  if (rc != 0) return rc;
  size_t w = (size_t)m->w, cw = (size_t)m->cw;
  for (int p = 0; p < m->win.nplanes[TS_SRC_FINE] && p < TS_WIN_MAX_PLANES && !m->fine_from_image; p++)
    m->fine[p] = rd_rows(&r, w, m->fy0, m->fy1, m->kfy0, m->kfy1);
  for (int p = 0; p < m->win.nplanes[TS_SRC_COARSE] && p < TS_WIN_MAX_PLANES; p++)
    m->coarse[p] = rd_rows(&r, cw, m->cy0, m->cy1, m->kcy0, m->kcy1);
  if (m->labelled == TS_SLICE_LABELS_ROWS) m->labels = rd_rows(&r, w, m->ay0, m->ay1, m->kay0, m->kay1);
  if (m->masked) m->valid = rd_rows(&r, w, m->ay0, m->ay1, m->kay0, m->kay1);
  m->usage = ts_rd_u8(&r);
  if (m->usage == TS_SLICE_USAGE_COUNTS) m->counts = rd_rows(&r, 4 * w, m->fy0, m->fy1, m->kfy0, m->kfy1);
  if ((rc = rd_lbg(&r, &m->lbg, m->nclass, err)) != 0) return rc;
  if (finish(&r, err, 'N') != 0) return TS_EPROTO;
  if (m->usage > TS_SLICE_USAGE_COUNTS) return bad(err, 'N', "usage mode");
  return 0;
}

void ts_msg_loaded_write(ts_wr *w, const ts_msg_loaded *m) {
  ts_wr_u32(w, m->set);
  ts_wr_u32(w, m->gen);
  ts_wr_u64(w, m->vectors);
}

int ts_msg_loaded_read(const ts_frame *f, ts_msg_loaded *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  m->set = ts_rd_u32(&r);
  m->gen = ts_rd_u32(&r);
  m->vectors = ts_rd_u64(&r);
  return finish(&r, err, 'N');
}

/* ---- R ------------------------------------------------------------------ */

static void wr_places(ts_wr *w, const ts_place *p, uint32_t n) {
  ts_wr_u32(w, n);
  for (uint32_t i = 0; i < n; i++) {
    ts_wr_u32(w, p[i].dst);
    ts_wr_u32(w, p[i].src);
  }
}

static const uint8_t *rd_places(ts_rd *r, uint32_t *n, uint32_t len) {
  *n = ts_rd_u32(r);
  if (*n > len / TS_PLACE_BYTES) {
    r->failed = 1;
    return NULL;
  }
  return ts_rd_bytes(r, (size_t)*n * TS_PLACE_BYTES);
}

void ts_msg_place_at(const uint8_t *places, uint32_t i, ts_place *p) {
  p->dst = le32(places + (size_t)i * TS_PLACE_BYTES);
  p->src = le32(places + (size_t)i * TS_PLACE_BYTES + 4);
}

static void wr_planes(ts_wr *w, const uint8_t *const *planes, int n, int pw, int ph) {
  for (int k = 0; k < n; k++) ts_wr_bytes(w, planes[k], (size_t)pw * (size_t)ph);
}

/* n planes of pw x ph, bounded by what is left of the payload first. */
static int rd_planes(ts_rd *r, const uint8_t **planes, int n, int pw, int ph) {
  uint64_t bytes = (uint64_t)pw * (uint64_t)ph;
  if (pw < 0 || ph < 0 || bytes * (uint64_t)n > r->len - r->off) return TS_EPROTO;
  for (int k = 0; k < n; k++) planes[k] = ts_rd_bytes(r, (size_t)bytes);
  return 0;
}

static void wr_load(ts_wr *w, const ts_replica_desc *d) {
  ts_wr_u32(w, (uint32_t)d->w);
  ts_wr_u32(w, (uint32_t)d->h);
  ts_wr_u8(w, (uint8_t)d->nplanes);
  ts_wr_u32(w, (uint32_t)d->cw);
  ts_wr_u32(w, (uint32_t)d->ch);
  ts_wr_u8(w, (uint8_t)((d->done != NULL ? TS_LOAD_DONE : 0) | (d->bounded ? TS_LOAD_BOUNDED : 0) |
                        (d->block != 0 && d->copy == NULL ? TS_LOAD_NO_COPY : 0)));
  ts_wr_u16(w, (uint16_t)d->block);
  wr_planes(w, d->fine, d->nplanes, d->w, d->h);
  wr_planes(w, d->coarse, d->cw ? d->nplanes : 0, d->cw, d->ch);
  if (d->done != NULL) ts_wr_bytes(w, d->done, (size_t)d->w * (size_t)d->h);
  if (d->block == 0) return;
  ts_wr_u32(w, (uint32_t)d->rw);
  ts_wr_u32(w, (uint32_t)d->rh);
  wr_planes(w, d->ref, d->nplanes, d->rw, d->rh);
  size_t npx = (size_t)d->w * (size_t)d->h;
  for (size_t i = 0; d->copy != NULL && i < 2 * npx; i++) ts_wr_u32(w, d->copy[i]);
}

static int rd_load(ts_rd *r, ts_msg_image *m, char *err) {
  ts_replica_desc *d = &m->d;
  d->w = (int)ts_rd_u32(r);
  d->h = (int)ts_rd_u32(r);
  d->nplanes = ts_rd_u8(r);
  d->cw = (int)ts_rd_u32(r);
  d->ch = (int)ts_rd_u32(r);
  uint8_t flags = ts_rd_u8(r);
  d->block = ts_rd_u16(r);
  if (r->failed) return bad(err, 'R', "truncated header");
  if (d->nplanes < 1 || d->nplanes > TS_WIN_MAX_PLANES ||
      (flags & ~(TS_LOAD_DONE | TS_LOAD_BOUNDED | TS_LOAD_NO_COPY)) != 0)
    return bad(err, 'R', "planes or flags");
  int has_done = (flags & TS_LOAD_DONE) != 0;
  d->bounded = (flags & TS_LOAD_BOUNDED) != 0;
  if (rd_planes(r, d->fine, d->nplanes, d->w, d->h) != 0 ||
      rd_planes(r, d->coarse, d->cw ? d->nplanes : 0, d->cw, d->ch) != 0)
    return bad(err, 'R', "image size");
  if (has_done && rd_planes(r, &d->done, 1, d->w, d->h) != 0) return bad(err, 'R', "image size");
  if (d->block == 0) return 0;
  d->rw = (int)ts_rd_u32(r);
  d->rh = (int)ts_rd_u32(r);
  const uint8_t *copy[8] = {NULL};
  if (rd_planes(r, d->ref, d->nplanes, d->rw, d->rh) != 0 ||
      ((flags & TS_LOAD_NO_COPY) == 0 && rd_planes(r, copy, 8, d->w, d->h) != 0))
    return bad(err, 'R', "reference or copy map size");
  m->copy_le = copy[0]; /* 8 bytes per pixel, contiguous; NULL: none */
  return 0;
}

void ts_msg_image_write(ts_wr *w, const ts_msg_image *m) {
  ts_wr_u32(w, m->image);
  ts_wr_u8(w, m->op);
  ts_wr_u64(w, m->seq);
  if (m->op == TS_IMAGE_LOAD) wr_load(w, &m->d);
  if (m->op != TS_IMAGE_NEXT) return;
  wr_places(w, m->place, m->nplace);
  ts_wr_u32(w, (uint32_t)m->w);
  ts_wr_u32(w, (uint32_t)m->h);
  ts_wr_u32(w, (uint32_t)m->rw);
  ts_wr_u32(w, (uint32_t)m->rh);
  ts_wr_u8(w, (uint8_t)m->nplanes);
  wr_planes(w, m->d.ref, m->nplanes, m->rw, m->rh);
}
int ts_msg_image_read(const ts_frame *f, ts_msg_image *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  memset(m, 0, sizeof(*m));
  m->image = ts_rd_u32(&r);
  m->op = ts_rd_u8(&r);
  m->seq = ts_rd_u64(&r);
  if (m->op == TS_IMAGE_LOAD) {
    int rc = rd_load(&r, m, err);
    if (rc != 0) return rc;
  } else if (m->op == TS_IMAGE_NEXT) {
    m->places = rd_places(&r, &m->nplace, f->len);
    m->w = (int)ts_rd_u32(&r);
    m->h = (int)ts_rd_u32(&r);
    m->rw = (int)ts_rd_u32(&r);
    m->rh = (int)ts_rd_u32(&r);
    m->nplanes = ts_rd_u8(&r);
    if (r.failed) return bad(err, 'R', "truncated header");
    if (m->nplanes < 1 || m->nplanes > TS_WIN_MAX_PLANES || rd_planes(&r, m->d.ref, m->nplanes, m->rw, m->rh) != 0)
      return bad(err, 'R', "reference size");
  } else if (m->op != TS_IMAGE_CLOSE) {
    return bad(err, 'R', "operation");
  }
  return finish(&r, err, 'R');
}

void ts_msg_image_ack_write(ts_wr *w, uint32_t image) { ts_wr_u32(w, image); }

int ts_msg_image_ack_read(const ts_frame *f, uint32_t *image, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  *image = ts_rd_u32(&r);
  return finish(&r, err, 'R');
}

/* ---- V ------------------------------------------------------------------ */

void ts_msg_query_write(ts_wr *w, uint32_t set, uint32_t gen, uint32_t image, uint64_t seq, const ts_place *p,
                        uint32_t np, const ts_query_batch *b, uint32_t q0, uint32_t q1) {
  ts_wr_u32(w, set);
  ts_wr_u32(w, gen);
  ts_wr_u32(w, image);
  ts_wr_u64(w, seq);
  wr_places(w, p, np);
  uint32_t nq = q1 - q0;
  uint8_t flags = (b->masked ? TS_QUERY_MASKS : 0) | (b->klass ? TS_QUERY_CLASSES : 0);
  ts_wr_u32(w, nq);
  ts_wr_u8(w, flags);
  ts_wr_u64(w, b->usage_k);
  for (uint32_t i = q0; i < q1; i++) ts_wr_u32(w, b->pos[i]);
  if (b->klass) ts_wr_bytes(w, b->klass + q0, nq);
}

int ts_msg_query_read(const ts_frame *f, ts_msg_query *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  memset(m, 0, sizeof(*m));
  m->set = ts_rd_u32(&r);
  m->gen = ts_rd_u32(&r);
  m->image = ts_rd_u32(&r);
  m->seq = ts_rd_u64(&r);
  m->places = rd_places(&r, &m->nplace, f->len);
  m->nq = ts_rd_u32(&r);
  m->flags = ts_rd_u8(&r);
  m->usage_k = ts_rd_u64(&r);
  if (r.failed) return bad(err, 'V', "truncated header");
  if (m->flags & ~(TS_QUERY_MASKS | TS_QUERY_CLASSES)) return bad(err, 'V', "unknown flags");
  if (m->nq > f->len / 4) return bad(err, 'V', "query count");
  m->pos = ts_rd_bytes(&r, (size_t)m->nq * 4);
  if (m->flags & TS_QUERY_CLASSES) m->klass = ts_rd_bytes(&r, m->nq);
  return finish(&r, err, 'V');
}

uint32_t ts_msg_pos_at(const ts_msg_query *m, uint32_t i) { return le32(m->pos + (size_t)i * 4); }

void ts_msg_answer_write(ts_wr *w, uint32_t set, uint32_t gen, uint64_t scan_nanos, uint64_t pairs,
                         const ts_l1_best *best, uint32_t nq) {
  ts_wr_u32(w, set);
  ts_wr_u32(w, gen);
  ts_wr_u32(w, nq);
  ts_wr_u64(w, scan_nanos);
  ts_wr_u64(w, pairs);
  for (uint32_t i = 0; i < nq; i++) {
    ts_wr_u32(w, best[i].index);
    ts_wr_u64(w, best[i].dist);
  }
}

int ts_msg_answer_read(const ts_frame *f, ts_msg_answer *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  m->set = ts_rd_u32(&r);
  m->gen = ts_rd_u32(&r);
  m->nq = ts_rd_u32(&r);
  m->scan_nanos = ts_rd_u64(&r);
  m->pairs = ts_rd_u64(&r);
  if (m->nq > f->len / TS_RESULT_BYTES) return bad(err, 'V', "answer count");
  m->results = ts_rd_bytes(&r, (size_t)m->nq * TS_RESULT_BYTES);
  return finish(&r, err, 'V');
}

void ts_msg_result_at(const ts_msg_answer *m, uint32_t i, ts_l1_best *b) {
  const uint8_t *p = m->results + (size_t)i * TS_RESULT_BYTES;
  b->index = le32(p);
  b->dist = le64(p + 4);
  b->pad_ = 0;
}

/* ---- Q ------------------------------------------------------------------ */

void ts_msg_unload_write(ts_wr *w, const ts_msg_unload *m) { ts_wr_u32(w, m->set); }

int ts_msg_unload_read(const ts_frame *f, ts_msg_unload *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  m->set = ts_rd_u32(&r);
  return finish(&r, err, 'Q');
}

/* ---- E ------------------------------------------------------------------ */

void ts_msg_error_write(ts_wr *w, int code, const char *text) {
  ts_wr_u32(w, (uint32_t)code);
  char buf[TS_ERR_LEN];
  snprintf(buf, sizeof(buf), "%s", text); /* cut to what a reader accepts */
  ts_wr_str(w, buf);
}

int ts_msg_error_read(const ts_frame *f, ts_msg_error *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  m->code = (int32_t)ts_rd_u32(&r);
  ts_rd_str(&r, m->text, sizeof(m->text));
  if (finish(&r, err, 'E') != 0) return TS_EPROTO;
  if (m->code >= 0) return bad(err, 'E', "error code must be negative");
  return 0;
}

/* ---- S ------------------------------------------------------------------ */

int ts_msg_key_valid(const char *key) {
  size_t n = strlen(key);
  if (n == 0 || n >= TS_MSG_KEY_MAX) return 0;
  for (size_t i = 0; i < n; i++)
    if (!((key[i] >= 'a' && key[i] <= 'z') || (key[i] >= '0' && key[i] <= '9') || key[i] == '_')) return 0;
  return 1;
}

void ts_msg_submit_write(ts_wr *w, const ts_msg_submit *m) {
  ts_wr_u32(w, m->spec_len);
  ts_wr_bytes(w, m->spec, m->spec_len);
  ts_wr_str(w, m->ref_name);
  ts_wr_u32(w, m->ref_len);
  ts_wr_bytes(w, m->ref, m->ref_len);
  if (m->nmore == 0) return; /* no tail: the message as it was before inputs had names */
  ts_wr_u8(w, (uint8_t)m->nmore);
  for (uint32_t k = 0; k < m->nmore; k++) {
    ts_wr_str(w, m->more[k].key);
    ts_wr_str(w, m->more[k].name);
    ts_wr_u32(w, m->more[k].len);
    ts_wr_bytes(w, m->more[k].data, m->more[k].len);
  }
}

/* The tail of further inputs, if the payload goes on after the first. */
static int submit_read_more(ts_rd *r, ts_msg_submit *m, char *err) {
  m->nmore = 0;
  if (r->failed || r->off == r->len) return 0;
  m->nmore = ts_rd_u8(r);
  if (m->nmore == 0 || m->nmore >= TS_MSG_MAX_INPUTS)
    return bad(err, 'S', "the count of further inputs must be 1..63");
  for (uint32_t k = 0; k < m->nmore && !r->failed; k++) {
    ts_msg_input *in = &m->more[k];
    ts_rd_str(r, in->key, sizeof(in->key));
    ts_rd_str(r, in->name, sizeof(in->name));
    in->len = ts_rd_u32(r);
    in->data = ts_rd_bytes(r, in->len);
    if (r->failed) break;
    if (!ts_msg_key_valid(in->key)) return bad(err, 'S', "an input key must be 1..31 of a-z, 0-9 and _");
    if (in->len == 0) return bad(err, 'S', "empty input image");
    for (uint32_t i = 0; i < k; i++)
      if (strcmp(m->more[i].key, in->key) == 0) return bad(err, 'S', "an input key given twice");
  }
  return 0;
}

int ts_msg_submit_read(const ts_frame *f, ts_msg_submit *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  m->spec_len = ts_rd_u32(&r);
  if (m->spec_len > TS_SPEC_MAX) return bad(err, 'S', "job spec over 16384 bytes");
  m->spec = (const char *)ts_rd_bytes(&r, m->spec_len);
  ts_rd_str(&r, m->ref_name, sizeof(m->ref_name));
  m->ref_len = ts_rd_u32(&r);
  m->ref = ts_rd_bytes(&r, m->ref_len);
  if (submit_read_more(&r, m, err) != 0) return TS_EPROTO;
  if (finish(&r, err, 'S') != 0) return TS_EPROTO;
  if (m->spec_len > 0 && memchr(m->spec, 0, m->spec_len) != NULL) return bad(err, 'S', "NUL in the job spec");
  if (m->ref_len == 0) return bad(err, 'S', "empty reference image");
  return 0;
}

void ts_msg_jobid_write(ts_wr *w, uint64_t id) { ts_wr_u64(w, id); }

int ts_msg_jobid_read(const ts_frame *f, uint64_t *id, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  *id = ts_rd_u64(&r);
  return finish(&r, err, (char)f->type);
}

/* ---- W ------------------------------------------------------------------ */

const char *ts_job_state_name(int state) {
  static const char *const names[TS_JOB_STATE_COUNT] = {"queued", "running", "done", "failed", "canceled"};
  return state >= 0 && state < TS_JOB_STATE_COUNT ? names[state] : "unknown";
}

void ts_msg_status_req_write(ts_wr *w, const ts_msg_status_req *m) {
  ts_wr_u64(w, m->id);
  ts_wr_u8(w, m->follow);
}

int ts_msg_status_req_read(const ts_frame *f, ts_msg_status_req *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  m->id = ts_rd_u64(&r);
  m->follow = ts_rd_u8(&r);
  if (finish(&r, err, 'W') != 0) return TS_EPROTO;
  if (m->follow > 1 || (m->follow && m->id == 0)) return bad(err, 'W', "follow needs one job id");
  return 0;
}

void ts_msg_status_write(ts_wr *w, const ts_job_status *s, uint32_t n) {
  ts_wr_u32(w, n);
  for (uint32_t i = 0; i < n; i++) {
    ts_wr_u64(w, s[i].id);
    ts_wr_u8(w, s[i].state);
    ts_wr_u8(w, s[i].level);
    ts_wr_u8(w, s[i].levels);
    ts_wr_u16(w, s[i].permille);
    ts_wr_u32(w, s[i].eta_ms);
    ts_wr_u16(w, s[i].workers);
    ts_wr_str(w, s[i].text);
    ts_wr_u8(w, s[i].flags);
    ts_wr_u64(w, s[i].submitted_ms);
    ts_wr_u64(w, s[i].started_ms);
    ts_wr_u64(w, s[i].ended_ms);
    ts_wr_str(w, s[i].engine);
    ts_wr_str(w, s[i].owner);
    ts_wr_str(w, s[i].output);
  }
}

int ts_msg_status_read(const ts_frame *f, ts_job_status *s, uint32_t cap, uint32_t *n, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  *n = ts_rd_u32(&r);
  if (*n > cap) return bad(err, 'W', "more job records than expected");
  for (uint32_t i = 0; i < *n; i++) {
    s[i].id = ts_rd_u64(&r);
    s[i].state = ts_rd_u8(&r);
    s[i].level = ts_rd_u8(&r);
    s[i].levels = ts_rd_u8(&r);
    s[i].permille = ts_rd_u16(&r);
    s[i].eta_ms = ts_rd_u32(&r);
    s[i].workers = ts_rd_u16(&r);
    ts_rd_str(&r, s[i].text, sizeof(s[i].text));
    s[i].flags = ts_rd_u8(&r);
    s[i].submitted_ms = ts_rd_u64(&r);
    s[i].started_ms = ts_rd_u64(&r);
    s[i].ended_ms = ts_rd_u64(&r);
    ts_rd_str(&r, s[i].engine, sizeof(s[i].engine));
    ts_rd_str(&r, s[i].owner, sizeof(s[i].owner));
    ts_rd_str(&r, s[i].output, sizeof(s[i].output));
    if (r.failed) break;
    if (s[i].state >= TS_JOB_STATE_COUNT || s[i].permille > 1000) return bad(err, 'W', "job state");
    if (s[i].flags & ~TS_JOB_HELD || ((s[i].flags & TS_JOB_HELD) && s[i].state != TS_JOB_QUEUED))
      return bad(err, 'W', "job flags");
  }
  return finish(&r, err, 'W');
}

/* ---- F ------------------------------------------------------------------ */

void ts_msg_files_write(ts_wr *w, const ts_msg_files *m) {
  ts_wr_u32(w, m->n);
  for (uint32_t i = 0; i < m->n; i++) {
    ts_wr_str(w, m->name[i]);
    ts_wr_u64(w, m->size[i]);
    ts_wr_u32(w, m->len[i]);
    ts_wr_bytes(w, m->data[i], m->len[i]);
  }
}

int ts_msg_files_read(const ts_frame *f, ts_msg_files *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  m->n = ts_rd_u32(&r);
  if (m->n > TS_FETCH_MAX_FILES) return bad(err, 'F', "too many files");
  for (uint32_t i = 0; i < m->n; i++) {
    ts_rd_str(&r, m->name[i], sizeof(m->name[i]));
    m->size[i] = ts_rd_u64(&r);
    m->len[i] = ts_rd_u32(&r);
    m->data[i] = m->len[i] > 0 ? ts_rd_bytes(&r, m->len[i]) : NULL;
    /* Whole inline, or none of it: a small file in ranges, or a partial one, is a lie. */
    if (m->size[i] <= TS_FETCH_INLINE ? m->len[i] != m->size[i] : m->len[i] != 0)
      return bad(err, 'F', "a file's inline bytes do not match its size");
  }
  return finish(&r, err, 'F');
}

/* ---- B ------------------------------------------------------------------ */

void ts_msg_range_write(ts_wr *w, const ts_msg_range *m) {
  ts_wr_u64(w, m->id);
  ts_wr_str(w, m->name);
  ts_wr_u64(w, m->offset);
  ts_wr_u32(w, m->len);
}

int ts_msg_range_read(const ts_frame *f, ts_msg_range *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  m->id = ts_rd_u64(&r);
  ts_rd_str(&r, m->name, sizeof(m->name));
  m->offset = ts_rd_u64(&r);
  m->len = ts_rd_u32(&r);
  int rc = finish(&r, err, 'B');
  if (rc == 0 && (m->len == 0 || m->len > TS_RANGE_MAX || m->offset > UINT64_MAX - m->len))
    return bad(err, 'B', "range length or offset");
  return rc;
}

/* ---- P ------------------------------------------------------------------ */

const char *ts_worker_state_name(int state) {
  static const char *const names[TS_WORKER_STATE_COUNT] = {"calibrating", "ready", "failed", "draining"};
  return state >= 0 && state < TS_WORKER_STATE_COUNT ? names[state] : "unknown";
}

void ts_msg_pool_write(ts_wr *w, const ts_worker_info *wi, uint32_t n) {
  ts_wr_u32(w, n);
  for (uint32_t i = 0; i < n; i++) {
    ts_wr_str(w, wi[i].addr);
    ts_wr_u16(w, wi[i].threads);
    ts_wr_u8(w, wi[i].simd);
    ts_wr_u8(w, wi[i].state);
    ts_wr_u64(w, wi[i].calibrated);
    ts_wr_u64(w, wi[i].rate);
    ts_wr_u16(w, wi[i].share);
    ts_wr_u64(w, wi[i].batches);
    ts_wr_str(w, wi[i].name);
    ts_wr_u64(w, wi[i].died_ms);
  }
}

int ts_msg_pool_read(const ts_frame *f, ts_worker_info *wi, uint32_t cap, uint32_t *n, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  *n = ts_rd_u32(&r);
  if (*n > cap) return bad(err, 'P', "more workers than expected");
  for (uint32_t i = 0; i < *n; i++) {
    ts_rd_str(&r, wi[i].addr, sizeof(wi[i].addr));
    wi[i].threads = ts_rd_u16(&r);
    wi[i].simd = ts_rd_u8(&r);
    wi[i].state = ts_rd_u8(&r);
    wi[i].calibrated = ts_rd_u64(&r);
    wi[i].rate = ts_rd_u64(&r);
    wi[i].share = ts_rd_u16(&r);
    wi[i].batches = ts_rd_u64(&r);
    ts_rd_str(&r, wi[i].name, sizeof(wi[i].name));
    wi[i].died_ms = ts_rd_u64(&r);
    if (r.failed) break;
    if (wi[i].state >= TS_WORKER_STATE_COUNT || wi[i].share > 1000) return bad(err, 'P', "worker record");
    if ((wi[i].died_ms != 0) != (wi[i].state == TS_WORKER_FAILED)) return bad(err, 'P', "worker death time");
  }
  return finish(&r, err, 'P');
}

/* ---- G ------------------------------------------------------------------ */

void ts_msg_field_write(ts_wr *w, const ts_msg_field *m) {
  ts_wr_u32(w, m->set);
  wr_window(w, &m->win);
  ts_wr_u32(w, (uint32_t)m->w);
  ts_wr_u32(w, (uint32_t)m->h);
  ts_wr_u8(w, (uint8_t)m->nplanes);
  wr_planes(w, m->plane, m->nplanes, m->w, m->h);
}

int ts_msg_field_read(const ts_frame *f, ts_msg_field *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  memset(m, 0, sizeof(*m));
  m->set = ts_rd_u32(&r);
  int rc = rd_window(&r, &m->win, m->offbuf, m->knownbuf, err);
  if (rc != 0) return rc;
  m->w = (int)ts_rd_u32(&r);
  m->h = (int)ts_rd_u32(&r);
  m->nplanes = ts_rd_u8(&r);
  if (r.failed) return bad(err, 'G', "truncated header");
  if (m->nplanes < 1 || m->nplanes > TS_WIN_MAX_PLANES || m->nplanes != m->win.nplanes[TS_SRC_FINE])
    return bad(err, 'G', "plane count");
  if (m->w < 1 || m->h < 1 || m->w > TS_PASS_MAX_SIDE || m->h > TS_PASS_MAX_SIDE ||
      rd_planes(&r, m->plane, m->nplanes, m->w, m->h) != 0)
    return bad(err, 'G', "source size");
  return finish(&r, err, 'G');
}

void ts_msg_field_ack_write(ts_wr *w, uint32_t set) { ts_wr_u32(w, set); }

int ts_msg_field_ack_read(const ts_frame *f, uint32_t *set, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  *set = ts_rd_u32(&r);
  return finish(&r, err, 'G');
}

/* ---- T ------------------------------------------------------------------ */

void ts_msg_pass_write(ts_wr *w, const ts_msg_pass *m) {
  ts_wr_u32(w, m->set);
  ts_wr_u32(w, m->image);
  ts_wr_u64(w, m->seq);
  ts_wr_u32(w, m->tw);
  ts_wr_u32(w, m->th);
  ts_wr_u64(w, m->usage_k);
  ts_wr_u64(w, m->seed);
  ts_wr_u32(w, m->pass);
  ts_wr_u32(w, m->ntiles);
  for (uint32_t i = 0; i < m->ntiles; i++) ts_wr_u32(w, m->tiles[i]);
  for (size_t i = 0; i < 2 * (size_t)m->tw * m->th; i++) ts_wr_u16(w, (uint16_t)m->field[i]);
}

int ts_msg_pass_read(const ts_frame *f, ts_msg_pass *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  memset(m, 0, sizeof(*m));
  m->set = ts_rd_u32(&r);
  m->image = ts_rd_u32(&r);
  m->seq = ts_rd_u64(&r);
  m->tw = ts_rd_u32(&r);
  m->th = ts_rd_u32(&r);
  m->usage_k = ts_rd_u64(&r);
  m->seed = ts_rd_u64(&r);
  m->pass = ts_rd_u32(&r);
  m->ntiles = ts_rd_u32(&r);
  if (r.failed) return bad(err, 'T', "truncated header");
  uint64_t n = (uint64_t)m->tw * m->th;
  if (m->tw < 1 || m->th < 1 || m->tw > TS_PASS_MAX_SIDE || m->th > TS_PASS_MAX_SIDE || 4 * n > r.len - r.off)
    return bad(err, 'T', "field size");
  if (m->ntiles > (r.len - r.off) / 4) return bad(err, 'T', "tile count");
  m->tiles_le = ts_rd_bytes(&r, (size_t)m->ntiles * 4);
  m->field_le = ts_rd_bytes(&r, (size_t)n * 4);
  return finish(&r, err, 'T');
}

void ts_msg_pass_field(const ts_msg_pass *m, uint32_t *field) {
  const uint8_t *p = m->field_le;
  for (size_t i = 0; i < 2 * (size_t)m->tw * m->th; i++) field[i] = (uint32_t)p[2 * i] | (uint32_t)p[2 * i + 1] << 8;
}

uint32_t ts_msg_pass_tile(const ts_msg_pass *m, uint32_t i) { return le32(m->tiles_le + (size_t)i * 4); }

void ts_msg_pass_answer_write(ts_wr *w, uint32_t set, uint32_t pass, uint64_t nanos, const uint32_t *tiles,
                              uint32_t n, uint32_t tw, uint32_t th, const uint32_t *out) {
  uint32_t ntx = (tw + TS_PM_TILE - 1) / TS_PM_TILE, count = 0;
  for (uint32_t i = 0; i < n; i++) {
    uint32_t x0 = tiles[i] % ntx * TS_PM_TILE, y0 = tiles[i] / ntx * TS_PM_TILE;
    count += ((x0 + TS_PM_TILE < tw ? x0 + TS_PM_TILE : tw) - x0) * ((y0 + TS_PM_TILE < th ? y0 + TS_PM_TILE : th) - y0);
  }
  ts_wr_u32(w, set);
  ts_wr_u32(w, pass);
  ts_wr_u64(w, nanos);
  ts_wr_u32(w, count);
  for (uint32_t i = 0; i < n; i++) {
    uint32_t x0 = tiles[i] % ntx * TS_PM_TILE, y0 = tiles[i] / ntx * TS_PM_TILE;
    uint32_t x1 = x0 + TS_PM_TILE < tw ? x0 + TS_PM_TILE : tw, y1 = y0 + TS_PM_TILE < th ? y0 + TS_PM_TILE : th;
    for (uint32_t y = y0; y < y1; y++)
      for (uint32_t x = x0; x < x1; x++) {
        ts_wr_u16(w, (uint16_t)out[2 * ((size_t)y * tw + x)]);
        ts_wr_u16(w, (uint16_t)out[2 * ((size_t)y * tw + x) + 1]);
      }
  }
}

int ts_msg_pass_answer_read(const ts_frame *f, ts_msg_pass_answer *m, char *err) {
  ts_rd r;
  ts_rd_init(&r, f->payload, f->len);
  memset(m, 0, sizeof(*m));
  m->set = ts_rd_u32(&r);
  m->pass = ts_rd_u32(&r);
  m->nanos = ts_rd_u64(&r);
  m->nentries = ts_rd_u32(&r);
  if (r.failed) return bad(err, 'T', "truncated answer");
  if (m->nentries > (r.len - r.off) / 4) return bad(err, 'T', "entry count");
  m->entries = ts_rd_bytes(&r, (size_t)m->nentries * 4);
  return finish(&r, err, 'T');
}
