/* slice.c - see slice.h. Each class range is cut into one contiguous run
 * of groups per scan thread; each thread scans its runs for every query of
 * the batch (so each run is streamed once per batch, SMP as in seed 002
 * §3.6.3) and the per-thread minima are merged with the lowest-index tie
 * rule. */
#include "slice.h"

#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "slice_impl.h"

/* Anchor rows holding vectors [i0[c], i1[c]) of every class; one row of
 * the box when the slice is empty. */
static void anchor_rows(const ts_anchors *a, const uint32_t *i0, const uint32_t *i1, int *ay0, int *ay1) {
  *ay0 = INT32_MAX;
  *ay1 = INT32_MIN;
  for (int c = 0; c < a->nclass; c++) {
    if (i1[c] <= i0[c]) continue;
    int y0, y1;
    ts_anchors_rows(a, c, i0[c], i1[c], &y0, &y1);
    if (y0 < *ay0) *ay0 = y0;
    if (y1 > *ay1) *ay1 = y1;
  }
  if (*ay0 > *ay1) *ay0 = a->y0, *ay1 = a->y0 + 1;
}

/* The rows of [y0, y1) also in [b0, b1), as [*k0, *k1); none: both y1. */
static void keep_rows(int y0, int y1, int b0, int b1, int32_t *k0, int32_t *k1) {
  int lo = y0 > b0 ? y0 : b0, hi = y1 < b1 ? y1 : b1;
  if (lo >= hi) lo = hi = y1;
  *k0 = lo;
  *k1 = hi;
}

/* Rows [y0, k0) and [k1, y1) of an image `row` bytes wide at px. */
static ts_slice_rows rows_of(const uint8_t *px, size_t row, int y0, int k1) {
  return (ts_slice_rows){px + (size_t)y0 * row, px + (size_t)k1 * row};
}

void ts_slice_describe(ts_slice_desc *m, const ts_refset *rs, const ts_usage *counts, uint32_t set,
                       uint32_t gen, uint32_t image, const uint32_t *i0, const uint32_t *i1,
                       const ts_slice_held *held) {
  const ts_window *win = rs->window;
  const ts_anchors *a = rs->anchors;
  memset(m, 0, offsetof(ts_slice_desc, offbuf));
  m->set = set;
  m->gen = gen;
  m->image = image;
  m->win = win->spec;
  m->w = a->w;
  m->h = a->h;
  if (ts_window_has_coarse(win)) {
    m->cw = rs->ref->coarse[0]->w;
    m->ch = rs->ref->coarse[0]->h;
  }
  m->nclass = (uint16_t)a->nclass;
  m->labelled = rs->labels != NULL ? TS_SLICE_LABELS_ROWS : TS_SLICE_LABELS_NONE;
  m->masked = rs->valid != NULL;
  memcpy(m->count, a->count, sizeof(uint32_t) * (size_t)a->nclass);
  memcpy(m->i0, i0, sizeof(uint32_t) * (size_t)a->nclass);
  memcpy(m->i1, i1, sizeof(uint32_t) * (size_t)a->nclass);
  anchor_rows(a, i0, i1, &m->ay0, &m->ay1);
  for (int c = 0; c < a->nclass; c++) m->above[c] = ts_anchors_above(a, c, m->ay0);
  ts_window_rows(win, m->ay0, m->ay1, &m->fy0, &m->fy1, &m->cy0, &m->cy1);
  ts_slice_held none = {0, 0, 0, 0, 0, 0, 0};
  if (held == NULL) held = &none;
  m->base_gen = held->gen;
  keep_rows(m->fy0, m->fy1, held->fy0, held->fy1, &m->kfy0, &m->kfy1);
  keep_rows(m->cy0, m->cy1, held->cy0, held->cy1, &m->kcy0, &m->kcy1);
  keep_rows(m->ay0, m->ay1, held->ay0, held->ay1, &m->kay0, &m->kay1);
  for (int p = 0; p < win->spec.nplanes[TS_SRC_FINE]; p++)
    m->fine[p] = rows_of(rs->ref->fine[p]->px, (size_t)a->w, m->fy0, m->kfy1);
  for (int p = 0; p < win->spec.nplanes[TS_SRC_COARSE]; p++)
    m->coarse[p] = rows_of(rs->ref->coarse[p]->px, (size_t)m->cw, m->cy0, m->kcy1);
  if (m->labelled == TS_SLICE_LABELS_ROWS) m->labels = rows_of(rs->labels->px, (size_t)a->w, m->ay0, m->kay1);
  if (m->masked) m->valid = rows_of(rs->valid->px, (size_t)a->w, m->ay0, m->kay1);
  m->usage = !rs->usage                           ? TS_SLICE_USAGE_NONE
             : counts == NULL || counts->total == 0 ? TS_SLICE_USAGE_ZERO
                                                  : TS_SLICE_USAGE_COUNTS;
  if (m->usage == TS_SLICE_USAGE_COUNTS)
    m->counts = rows_of((const uint8_t *)counts->count, 4 * (size_t)a->w, m->fy0, m->kfy1);
}

void ts_slice_describe_lbg(ts_slice_desc *m, const ts_lbg_codebook *cb) {
  m->lbg = *cb;
  m->lbg.own = NULL; /* the message only points at the centroids */
}

uint64_t ts_slice_row_bytes(const ts_slice_desc *m, int kept) {
  uint64_t f = (uint64_t)(m->kfy1 - m->kfy0), c = (uint64_t)(m->kcy1 - m->kcy0), a = (uint64_t)(m->kay1 - m->kay0);
  if (!kept) {
    f = (uint64_t)(m->fy1 - m->fy0) - f;
    c = (uint64_t)(m->cy1 - m->cy0) - c;
    a = (uint64_t)(m->ay1 - m->ay0) - a;
  }
  uint64_t w = (uint64_t)m->w;
  uint64_t bytes = c * (uint64_t)m->cw * m->win.nplanes[TS_SRC_COARSE];
  if (kept || !m->fine_from_image) bytes += f * w * m->win.nplanes[TS_SRC_FINE];
  bytes += a * w * (uint64_t)((m->labelled == TS_SLICE_LABELS_ROWS) + m->masked);
  if (m->usage == TS_SLICE_USAGE_COUNTS) bytes += 4 * f * w;
  return bytes;
}

/* FNV-1a, a word at a time: the check need not resist an adversary (the
 * peer is trusted with the job anyway), only tell two levels apart. */
static uint64_t sum_bytes(uint64_t h, const uint8_t *p, size_t n) {
  size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    uint64_t v;
    memcpy(&v, p + i, 8);
    h = (h ^ v) * 0x100000001b3ull;
  }
  for (; i < n; i++) h = (h ^ p[i]) * 0x100000001b3ull;
  return h;
}

uint64_t ts_slice_fine_sum(const ts_slice_desc *m) {
  uint64_t h = 0xcbf29ce484222325ull;
  size_t row = (size_t)m->w;
  for (int p = 0; p < m->win.nplanes[TS_SRC_FINE] && p < TS_WIN_MAX_PLANES; p++) {
    h = sum_bytes(h, m->fine[p].lo, row * (size_t)(m->kfy0 - m->fy0));
    h = sum_bytes(h, m->fine[p].hi, row * (size_t)(m->fy1 - m->kfy1));
  }
  return h;
}

/* Whether labels repeat the tw x th tile at their top-left corner. */
static int repeats(const ts_plane *l, int tw, int th) {
  for (int y = 0; y < l->h; y++) {
    const uint8_t *row = l->px + (size_t)y * (size_t)l->w, *trow = l->px + (size_t)(y % th) * (size_t)l->w;
    for (int x = 0; x < l->w; x++)
      if (row[x] != trow[x % tw]) return 0;
  }
  return 1;
}

int ts_slice_label_tile(const ts_plane *labels, uint8_t *tw, uint8_t *th, uint8_t *tile) {
  for (int h = 1; h <= TS_SLICE_MAX_TILE && h <= labels->h; h++)
    for (int w = 1; w <= TS_SLICE_MAX_TILE && w <= labels->w; w++) {
      if (!repeats(labels, w, h)) continue;
      *tw = (uint8_t)w;
      *th = (uint8_t)h;
      for (int y = 0; y < h; y++) memcpy(tile + y * w, labels->px + (size_t)y * (size_t)labels->w, (size_t)w);
      return 1;
    }
  return 0;
}

ts_slice_held ts_slice_held_by(const ts_slice_desc *m) {
  return (ts_slice_held){m->gen, m->fy0, m->fy1, m->cy0, m->cy1, m->ay0, m->ay1};
}

void ts_slice_free(ts_slice *s) {
  if (s == NULL) return;
  ts__slice_lbg_free(s);
  for (int c = 0; c < s->nclass; c++) {
    if (s->cls != NULL && s->cls[c].data != NULL) ts_l1_set_free(&s->cls[c]);
    if (s->penalty != NULL) free(s->penalty[c]);
  }
  free(s->cls);
  free(s->penalty);
  for (int p = 0; p < TS_WIN_MAX_PLANES; p++) {
    ts_plane_free(&s->fine[p]);
    ts_plane_free(&s->coarse[p]);
    free(s->rows_fine[p]);
    free(s->rows_coarse[p]);
  }
  free(s->rows_labels);
  free(s->rows_valid);
  ts_usage_free(&s->usage);
  ts_anchors_free(&s->anchors);
  ts_window_free(&s->window);
  free(s->qbuf);
  free(s->mbuf);
  free(s->order);
  free(s->tbest);
  free(s);
}

uint32_t ts_slice_set(const ts_slice *s) { return s->set; }
uint32_t ts_slice_gen(const ts_slice *s) { return s->gen; }
uint32_t ts_slice_image(const ts_slice *s) { return s->image; }
uint32_t ts_slice_vbytes(const ts_slice *s) { return ts_window_bytes(&s->window); }
int ts_slice_lbg(const ts_slice *s) { return s->lbg.mode; }

uint64_t ts_slice_query_cost(const ts_slice *s, int c) {
  uint64_t held = s->i1[c] - s->i0[c];
  if (s->lbg.mode == TS_LBG_OFF) return held;
  uint64_t np = s->part[c].npart, probe = s->lbg.probe < np ? s->lbg.probe : np;
  return np + (np ? held * probe / np : 0);
}
const ts_window *ts_slice_window(const ts_slice *s) { return &s->window; }

uint64_t ts_slice_vectors(const ts_slice *s) {
  uint64_t n = 0;
  for (int c = 0; c < s->nclass; c++) n += s->i1[c] - s->i0[c];
  return n;
}

/* Rows [y0, y1) of one image, `row` bytes each, joined into dst: the
 * message's rows around the kept ones [k0, k1), which start at kept. */
static void join_rows(uint8_t *dst, size_t row, int y0, int y1, int k0, int k1, ts_slice_rows r,
                      const uint8_t *kept) {
  size_t lo = row * (size_t)(k0 - y0), mid = row * (size_t)(k1 - k0), hi = row * (size_t)(y1 - k1);
  if (lo > 0) memcpy(dst, r.lo, lo);
  if (mid > 0) memcpy(dst + lo, kept, mid);
  if (hi > 0) memcpy(dst + lo + mid, r.hi, hi);
}

/* A joined copy of rows [y0, y1) (see join_rows), or NULL. */
static uint8_t *rows_copy(size_t row, int y0, int y1, int k0, int k1, ts_slice_rows r, const uint8_t *kept) {
  uint8_t *dst = malloc(row * (size_t)(y1 - y0));
  if (dst != NULL) join_rows(dst, row, y0, y1, k0, k1, r, kept);
  return dst;
}

/* Kept rows [k0, k1) of rows held from y0 on, `row` bytes each (NULL:
 * none kept). */
static const uint8_t *held_rows(const uint8_t *rows, size_t row, int y0, int k0, int k1) {
  return rows == NULL || k1 <= k0 ? NULL : rows + row * (size_t)(k0 - y0);
}

/* Full-size plane, zero outside rows [y0, y1), which come from rows. */
static int plane_from_rows(ts_plane *p, int w, int h, int y0, int y1, const uint8_t *rows) {
  if (ts_plane_alloc(p, w, h) != 0) return TS_ENOMEM;
  memset(p->px, 0, (size_t)w * (size_t)h);
  memcpy(p->px + (size_t)y0 * (size_t)w, rows, (size_t)w * (size_t)(y1 - y0));
  return 0;
}

/* The base a message keeps rows from must be the slice it names, of the
 * same level, holding every kept row. */
static int check_base(const ts_slice *b, const ts_slice_desc *m, char *err) {
  int keeps = m->kfy1 > m->kfy0 || m->kcy1 > m->kcy0 || m->kay1 > m->kay0;
  if (m->base_gen == 0)
    return keeps ? ts_error(err, TS_EINVAL, "slice keeps rows but names no generation to keep them from") : 0;
  if (b == NULL || b->gen != m->base_gen)
    return ts_error(err, TS_EINVAL, "slice %u generation %u keeps rows of generation %u, which this worker does not "
                    "hold", m->set, m->gen, m->base_gen);
  const ts_anchors *a = &b->anchors;
  int same = a->w == m->w && a->h == m->h && b->cw == m->cw && b->nclass == m->nclass &&
             memcmp(a->count, m->count, sizeof(uint32_t) * (size_t)m->nclass) == 0 &&
             b->with_usage == (m->usage != TS_SLICE_USAGE_NONE) && b->lbg.mode == m->lbg.mode;
  if (!same) return ts_error(err, TS_EINVAL, "slice %u generation %u is of another level than its base", m->set, m->gen);
  const ts_slice_held *h = &b->held;
  if ((m->kfy1 > m->kfy0 && (m->kfy0 < h->fy0 || m->kfy1 > h->fy1)) ||
      (m->kcy1 > m->kcy0 && (m->kcy0 < h->cy0 || m->kcy1 > h->cy1)) ||
      (m->kay1 > m->kay0 && (m->kay0 < h->ay0 || m->kay1 > h->ay1)))
    return ts_error(err, TS_EINVAL, "slice %u keeps rows its generation %u does not hold", m->set, m->base_gen);
  return 0;
}
/* Every class range must lie in its class and in the anchor rows held, and
 * those anchors read only the shipped rows. */
static int check_ranges(const ts_slice *s, const ts_slice_desc *m, char *err) {
  const ts_anchors *a = &s->anchors;
  for (int c = 0; c < s->nclass; c++) {
    if (m->i0[c] > m->i1[c] || m->i1[c] > a->count[c])
      return ts_error(err, TS_EINVAL, "slice range %u..%u past class %d's %u vectors", m->i0[c], m->i1[c], c,
                      a->count[c]);
    if (m->i1[c] == m->i0[c]) continue;
    int held, y0, y1;
    if (a->indexed) {
      held = ts_anchors_above(a, c, m->ay0) <= m->i0[c] && m->i1[c] <= ts_anchors_above(a, c, m->ay1);
    } else {
      ts_anchors_rows(a, c, m->i0[c], m->i1[c], &y0, &y1);
      held = y0 >= m->ay0 && y1 <= m->ay1;
    }
    if (!held)
      return ts_error(err, TS_EINVAL, "vectors %u..%u of class %d lie outside the anchor rows %d..%d sent", m->i0[c],
                      m->i1[c] - 1, c, m->ay0, m->ay1 - 1);
  }
  int fy0, fy1, cy0, cy1;
  ts_window_rows(&s->window, m->ay0, m->ay1, &fy0, &fy1, &cy0, &cy1);
  if (fy0 < m->fy0 || fy1 > m->fy1 || (ts_window_has_coarse(&s->window) && (cy0 < m->cy0 || cy1 > m->cy1)))
    return ts_error(err, TS_EINVAL, "anchor rows %d..%d read rows %d..%d (coarse %d..%d), outside the %d..%d "
                    "(coarse %d..%d) sent", m->ay0, m->ay1 - 1, fy0, fy1 - 1, cy0, cy1 - 1, m->fy0, m->fy1 - 1,
                    m->cy0, m->cy1 - 1);
  return 0;
}

/* Adds the counters of rows [y0, y1) (u32 little-endian) to u. */
static void usage_load_rows(ts_usage *u, int y0, int y1, const uint8_t *le) {
  const ts_anchors *g = &u->grid;
  for (int y = y0; y < y1; y++)
    for (int x = 0; x < g->w; x++) {
      const uint8_t *p = le + 4 * ((size_t)(y - y0) * (size_t)g->w + (size_t)x);
      uint32_t v = (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
      u->count[(size_t)y * (size_t)g->w + (size_t)x] = v;
      u->total += v;
    }
}

/* The counters of the fine rows: the message's, and the kept rows' from
 * the base (which has counted every placement since, as this slice
 * would have); then the block sums of every block inside them. */
static void load_usage(ts_slice *s, const ts_slice_desc *m, const ts_slice *base) {
  ts_usage *u = &s->usage;
  size_t w = (size_t)m->w;
  if (m->usage == TS_SLICE_USAGE_COUNTS) {
    usage_load_rows(u, m->fy0, m->kfy0, m->counts.lo);
    usage_load_rows(u, m->kfy1, m->fy1, m->counts.hi);
  }
  if (m->kfy1 > m->kfy0)
    usage_load_rows(u, m->kfy0, m->kfy1, (const uint8_t *)(base->usage.count + (size_t)m->kfy0 * w));
  ts_usage_sum_blocks(u, m->fy0, m->fy1);
}

/* Label rows [ay0, ay1) of a tiled message, or NULL. */
static uint8_t *tile_rows(const ts_slice_desc *m) {
  size_t w = (size_t)m->w;
  uint8_t *rows = malloc(w * (size_t)(m->ay1 - m->ay0));
  if (rows == NULL) return NULL;
  for (int y = m->ay0; y < m->ay1; y++) {
    const uint8_t *t = m->tile + (y % m->tile_h) * m->tile_w;
    uint8_t *row = rows + w * (size_t)(y - m->ay0);
    for (size_t x = 0; x < w; x++) row[x] = t[x % m->tile_w];
  }
  return rows;
}

/* The rows the slice reads, joined from the message and the base, kept
 * for the next slice; full-size level planes of them for the build. */
static int load_rows(ts_slice *s, const ts_slice_desc *m, const ts_slice *base, ts_levelplanes *planes, char *err) {
  const ts_slice_held *h = base != NULL ? &base->held : NULL;
  size_t w = (size_t)m->w, cw = (size_t)m->cw;
  for (int p = 0; p < m->win.nplanes[TS_SRC_FINE]; p++) {
    const uint8_t *kept = h ? held_rows(base->rows_fine[p], w, h->fy0, m->kfy0, m->kfy1) : NULL;
    s->rows_fine[p] = rows_copy(w, m->fy0, m->fy1, m->kfy0, m->kfy1, m->fine[p], kept);
    if (s->rows_fine[p] == NULL || plane_from_rows(&s->fine[p], m->w, m->h, m->fy0, m->fy1, s->rows_fine[p]) != 0)
      return ts_error(err, TS_ENOMEM, "out of memory for the slice's planes");
    planes->fine[p] = &s->fine[p];
  }
  for (int p = 0; p < m->win.nplanes[TS_SRC_COARSE]; p++) {
    const uint8_t *kept = h ? held_rows(base->rows_coarse[p], cw, h->cy0, m->kcy0, m->kcy1) : NULL;
    s->rows_coarse[p] = rows_copy(cw, m->cy0, m->cy1, m->kcy0, m->kcy1, m->coarse[p], kept);
    if (s->rows_coarse[p] == NULL ||
        plane_from_rows(&s->coarse[p], m->cw, m->ch, m->cy0, m->cy1, s->rows_coarse[p]) != 0)
      return ts_error(err, TS_ENOMEM, "out of memory for the slice's planes");
    planes->coarse[p] = &s->coarse[p];
  }
  if (m->labelled == TS_SLICE_LABELS_ROWS)
    s->rows_labels = rows_copy(w, m->ay0, m->ay1, m->kay0, m->kay1, m->labels,
                               h ? held_rows(base->rows_labels, w, h->ay0, m->kay0, m->kay1) : NULL);
  else if (m->labelled == TS_SLICE_LABELS_TILE)
    s->rows_labels = tile_rows(m);
  if (m->labelled != TS_SLICE_LABELS_NONE && s->rows_labels == NULL)
    return ts_error(err, TS_ENOMEM, "out of memory for the slice's label rows");
  if (m->masked && (s->rows_valid = rows_copy(w, m->ay0, m->ay1, m->kay0, m->kay1, m->valid,
                                              h ? held_rows(base->rows_valid, w, h->ay0, m->kay0, m->kay1) : NULL)) == NULL)
    return ts_error(err, TS_ENOMEM, "out of memory for the slice's validity rows");
  s->held = ts_slice_held_by(m);
  s->cw = m->cw;
  return 0;
}

/* Allocates each class's vector set (and penalties), weighted by the
 * window's parts. */
static int alloc_sets(ts_slice *s, char *err) {
  s->cls = calloc((size_t)s->nclass, sizeof(*s->cls));
  s->penalty = calloc((size_t)s->nclass, sizeof(*s->penalty));
  if (s->cls == NULL || s->penalty == NULL) return ts_error(err, TS_ENOMEM, "out of memory for the slice");
  for (int c = 0; c < s->nclass; c++) {
    int rc = ts_l1_set_init(&s->cls[c], s->i1[c] - s->i0[c], s->window.nchunks);
    if (rc == 0) rc = ts_window_weigh(&s->window, &s->cls[c], err);
    else return ts_error(err, rc, "cannot hold the slice's vectors of class %d: %s", c, ts_strerror(rc));
    if (rc != 0) return rc;
    if (s->with_usage) {
      s->penalty[c] = calloc((size_t)s->cls[c].ngroups * TS_L1_GROUP + 1, sizeof(uint32_t));
      if (s->penalty[c] == NULL) return ts_error(err, TS_ENOMEM, "out of memory for the slice's penalties");
    }
  }
  return 0;
}

/* One pass over anchor rows [ay0, ay1): every anchor in its class's range
 * gets its vector, copied from the base slice when that holds it (same
 * set and level: the same bytes) and built from the planes otherwise. */
static void fill_rows(ts_slice *s, const ts_slice *base, const ts_levelplanes *planes, int ay0, int ay1) {
  const ts_anchors *a = &s->anchors;
  uint8_t vec[TS_L1_MAX_CHUNKS * TS_L1_CHUNK];
  for (int y = ay0; y < ay1; y++)
    for (int x = a->x0; x < a->x0 + a->nx; x++) {
      int64_t j = ts_anchors_index(a, x, y);
      if (j < 0) continue;
      int c = a->nclass == 1 ? 0 : ts_anchors_class(a, (uint32_t)j);
      uint32_t rank = (uint32_t)j - a->base[c];
      if (rank < s->i0[c] || rank >= s->i1[c]) continue;
      if (base != NULL && rank >= base->i0[c] && rank < base->i1[c])
        ts_l1_set_get(&base->cls[c], rank - base->i0[c], vec);
      else
        ts_vec_ref(&s->window, planes, x, y, vec);
      ts_l1_set_put(&s->cls[c], rank - s->i0[c], vec);
    }
}

/* Building a big slice's vectors is most of its load time (a 4096x4096
 * colour reference: 8.7 GB of vectors, 49 s on one thread), so the pool's
 * threads each take a band of anchor rows; every vector has its own slot. */
typedef struct {
  ts_slice *s;
  const ts_slice *base;
  const ts_levelplanes *planes;
  int ay0, ay1;
} fill_job;

static void fill_band(void *arg, int w, int nw) {
  const fill_job *j = arg;
  int64_t rows = j->ay1 - j->ay0;
  fill_rows(j->s, j->base, j->planes, j->ay0 + (int)(rows * w / nw), j->ay0 + (int)(rows * (w + 1) / nw));
}

static int build(ts_slice *s, const ts_slice_desc *m, const ts_slice *base, ts_pool *pool, char *err) {
  int rc = check_base(base, m, err);
  if (rc != 0) return rc;
  if (m->base_gen == 0) base = NULL;
  if ((rc = ts_window_init(&s->window, &m->win, err)) != 0) return rc;
  if (base != NULL && ts_window_bytes(&s->window) != ts_window_bytes(&base->window))
    return ts_error(err, TS_EINVAL, "slice %u generation %u has another window than its base", m->set, m->gen);
  ts_levelplanes planes;
  memset(&planes, 0, sizeof(planes));
  if ((rc = load_rows(s, m, base, &planes, err)) != 0) return rc;
  rc = ts_anchors_init_rows(&s->anchors, &s->window, m->w, m->h, m->cw, m->ch, m->nclass, m->count, m->ay0, m->ay1,
                            s->rows_labels, s->rows_valid, m->above, err);
  if (rc != 0) return rc;
  s->nclass = m->nclass;
  if ((rc = check_ranges(s, m, err)) != 0) return rc;
  if (m->lbg.mode != TS_LBG_OFF && (rc = ts__slice_lbg_take(s, m, err)) != 0) return rc;
  memcpy(s->i0, m->i0, sizeof(uint32_t) * (size_t)s->nclass);
  memcpy(s->i1, m->i1, sizeof(uint32_t) * (size_t)s->nclass);
  s->with_usage = m->usage != TS_SLICE_USAGE_NONE;
  if (s->with_usage && ts_usage_init(&s->usage, &s->anchors, m->win.block, 1) != 0)
    return ts_error(err, TS_ENOMEM, "out of memory for the usage replica");
  if (s->with_usage) load_usage(s, m, base);
  if ((rc = alloc_sets(s, err)) != 0) return rc;
  /* A partitioned base holds its vectors by partition, not by rank: they
   * are built again. */
  fill_job job = {s, m->lbg.mode == TS_LBG_OFF ? base : NULL, &planes, m->ay0, m->ay1};
  if (pool != NULL) ts_pool_run(pool, fill_band, &job);
  else fill_band(&job, 0, 1);
  if (m->lbg.mode != TS_LBG_OFF && (rc = ts__slice_partition(s, pool, err)) != 0) return rc;
  /* The vectors hold what the scans need, the rows what a re-slice keeps:
   * the full-size planes can go. */
  for (int p = 0; p < TS_WIN_MAX_PLANES; p++) {
    ts_plane_free(&s->fine[p]);
    ts_plane_free(&s->coarse[p]);
  }
  return 0;
}

int ts_slice_load(ts_slice **out, const ts_slice_desc *m, const ts_slice *base, ts_pool *pool, char *err) {
  *out = NULL;
  ts_slice *s = calloc(1, sizeof(*s));
  if (s == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  s->set = m->set;
  s->gen = m->gen;
  s->image = m->image;
  int rc = build(s, m, base, pool, err);
  if (rc != 0) {
    ts_slice_free(s);
    return rc;
  }
  *out = s;
  return 0;
}

int ts_slice_commit(ts_slice *s, const ts_commit *c, uint32_t n, char *err) {
  if (!s->with_usage) return 0;
  for (uint32_t i = 0; i < n; i++) {
    if (c[i].x < 0 || c[i].y < 0 || c[i].x + c[i].w > s->anchors.w || c[i].y + c[i].h > s->anchors.h)
      return ts_error(err, TS_EINVAL, "usage commit %ux%u at (%d, %d) outside the %dx%d reference", c[i].w, c[i].h,
                      c[i].x, c[i].y, s->anchors.w, s->anchors.h);
    if (c[i].delta != 1 && c[i].delta != -1) return ts_error(err, TS_EINVAL, "usage commit delta %d", (int)c[i].delta);
  }
  for (uint32_t i = 0; i < n; i++) ts_usage_commit(&s->usage, c[i].x, c[i].y, c[i].w, c[i].h, c[i].delta);
  return 0;
}

static int ensure_scratch(ts_slice *s, uint32_t nq, uint32_t vbytes, int threads) {
  if (nq <= s->cap_q && (size_t)nq * vbytes <= s->cap_bytes && threads <= s->cap_threads) return 0;
  uint32_t cap = nq > 2 * s->cap_q ? nq : 2 * s->cap_q;
  int nt = threads > s->cap_threads ? threads : s->cap_threads;
  size_t bytes = (size_t)cap * vbytes;
  free(s->qbuf);
  free(s->mbuf);
  free(s->order);
  free(s->tbest);
  s->qbuf = malloc(bytes);
  s->mbuf = malloc(bytes);
  s->order = malloc(sizeof(uint32_t) * cap);
  s->tbest = malloc(sizeof(ts_l1_best) * cap * (size_t)nt);
  s->cap_q = cap;
  s->cap_bytes = bytes;
  s->cap_threads = nt;
  if (s->qbuf == NULL || s->mbuf == NULL || s->order == NULL || s->tbest == NULL) {
    s->cap_q = 0;
    s->cap_bytes = 0;
    return TS_ENOMEM;
  }
  return 0;
}

/* Pool job: thread w scans its run of groups of every class with queries. */
static void scan_runs(void *arg, int w, int nw) {
  ts_slice *s = arg;
  ts_l1_best *best = s->tbest + (size_t)w * s->cap_q;
  ts_l1_best_reset(best, s->nq);
  for (int c = 0; c < s->nclass; c++) {
    uint32_t q0 = s->qstart[c], nq = s->qstart[c + 1] - q0;
    const ts_l1_set *set = &s->cls[c];
    if (nq == 0 || set->ngroups == 0) continue;
    uint32_t g0 = (uint32_t)((uint64_t)set->ngroups * w / nw);
    uint32_t g1 = (uint32_t)((uint64_t)set->ngroups * (w + 1) / nw);
    if (g0 == g1) continue;
    const uint32_t *pen = NULL;
    if (s->usage_k != 0) {
      uint32_t *p = s->penalty[c];
      uint32_t v1 = g1 * TS_L1_GROUP < set->nvec ? g1 * TS_L1_GROUP : set->nvec;
      const uint32_t *uj = s->usage.u + s->anchors.base[c] + s->i0[c];
      for (uint32_t v = g0 * TS_L1_GROUP; v < v1; v++) p[v] = ts_usage_penalty(uj[v], s->usage_k);
      pen = p;
    }
    const uint8_t *q = s->qbuf + (size_t)q0 * s->vbytes;
    const uint8_t *m = s->masked ? s->mbuf + (size_t)q0 * s->vbytes : NULL;
    ts_l1_scan_fn *fn = nq == 1 ? s->simd->single : s->simd->batch;
    fn(set, g0, g1, q, m, pen, nq, best + q0);
  }
}

/* Groups the queries by class, keeping their order within a class. */
static int gather_queries(ts_slice *s, const ts_vec_batch *b, char *err) {
  uint32_t fill[TS_MAX_CLASSES + 1] = {0};
  for (uint32_t i = 0; i < b->nq; i++) {
    int c = b->klass ? b->klass[i] : 0;
    if (c >= s->nclass) return ts_error(err, TS_EINVAL, "query %u has class %d of %d", i, c, s->nclass);
    fill[c + 1]++;
  }
  for (int c = 0; c < s->nclass; c++) fill[c + 1] += fill[c];
  memcpy(s->qstart, fill, sizeof(uint32_t) * (size_t)(s->nclass + 1));
  for (uint32_t i = 0; i < b->nq; i++) {
    int c = b->klass ? b->klass[i] : 0;
    uint32_t r = fill[c]++;
    s->order[r] = i;
    memcpy(s->qbuf + (size_t)r * s->vbytes, b->queries + (size_t)i * s->vbytes, s->vbytes);
    if (b->masks) memcpy(s->mbuf + (size_t)r * s->vbytes, b->masks + (size_t)i * s->vbytes, s->vbytes);
  }
  return 0;
}

int ts_slice_scan(ts_slice *s, ts_pool *pool, int threads, const ts_l1_impl *simd, const ts_vec_batch *b,
                  ts_l1_best *out, uint64_t *pairs, char *err) {
  *pairs = 0;
  if (b->nq == 0) return 0;
  if (b->usage_k != 0 && !s->with_usage) return ts_error(err, TS_EINVAL, "a usage penalty on a slice without usage");
  s->vbytes = ts_window_bytes(&s->window);
  threads = threads == 1 ? 1 : ts_pool_size(pool); /* the pool runs all or one */
  if (ensure_scratch(s, b->nq, s->vbytes, threads) != 0)
    return ts_error(err, TS_ENOMEM, "out of memory for a batch of %u queries", b->nq);
  int rc = gather_queries(s, b, err);
  if (rc != 0) return rc;
  s->simd = simd;
  s->nq = b->nq;
  s->usage_k = b->usage_k;
  s->masked = b->masks != NULL;
  if (s->lbg.mode != TS_LBG_OFF) {
    if ((rc = ts__slice_scan_lbg(s, pool, threads, pairs, err)) != 0) return rc;
    for (uint32_t r = 0; r < b->nq; r++) out[s->order[r]] = s->lx.best[r];
    return 0;
  }
  if (threads == 1) scan_runs(s, 0, 1);
  else ts_pool_run(pool, scan_runs, s);
  for (int c = 0; c < s->nclass; c++) {
    uint32_t base = s->anchors.base[c] + s->i0[c];
    for (uint32_t r = s->qstart[c]; r < s->qstart[c + 1]; r++) {
      ts_l1_best best = s->tbest[r];
      for (int w = 1; w < threads; w++) ts_l1_best_merge(&best, &s->tbest[(size_t)w * s->cap_q + r], 1);
      if (best.index != UINT32_MAX) best.index += base;
      out[s->order[r]] = best;
    }
    *pairs += (uint64_t)(s->qstart[c + 1] - s->qstart[c]) * (s->i1[c] - s->i0[c]);
  }
  return 0;
}
