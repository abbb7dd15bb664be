/* slice.c - see slice.h. Each class range is cut into one contiguous run
 * of groups per scan thread; each thread scans its runs for every query of
 * the batch (so each run is streamed once per batch, SMP as in seed 002
 * §3.6.3) and the per-thread minima are merged with the lowest-index tie
 * rule. */
#include "slice.h"

#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "neigh.h"

struct ts_slice {
  uint32_t set, gen;
  ts_shape shape;
  ts_refgrid grid;
  uint32_t i0[4], i1[4];
  ts_plane fine[TS_MAX_PLANES], coarse[TS_MAX_PLANES];
  ts_l1_set cls[4];
  uint32_t *penalty[4]; /* per class, indexed like the class set */
  int with_usage;
  ts_usage usage;
  /* Per-batch scratch, grown on demand. */
  uint32_t cap_q;
  size_t cap_bytes;
  uint8_t *qbuf, *mbuf;
  uint32_t *order;
  ts_l1_best *tbest; /* threads x cap_q */
  int cap_threads;
  /* The batch being scanned (read by the pool threads). */
  const ts_l1_impl *simd;
  uint32_t nq, qstart[5], vbytes;
  uint64_t usage_k;
  int masked;
};

void ts_slice_describe(ts_slice_desc *m, const ts_refset *rs, const ts_usage *counts, uint32_t set,
                       uint32_t gen, const uint32_t *i0, const uint32_t *i1) {
  const ts_shape *s = rs->shape;
  const ts_refgrid *g = rs->grid;
  memset(m, 0, sizeof(*m));
  m->set = set;
  m->gen = gen;
  m->kind = (uint8_t)s->kind;
  m->wn = (uint8_t)s->wn;
  m->wb = (uint8_t)s->wb;
  m->has_coarse = s->wc > 0;
  m->nplanes = (uint8_t)s->nplanes;
  m->parity = (uint8_t)g->parity;
  m->coarse_weight = s->coarse_weight;
  m->wfine = s->wfine;
  m->wcoarse = s->wcoarse;
  m->w = g->w;
  m->h = g->h;
  if (m->has_coarse) {
    m->cw = rs->ref->coarse[0]->w;
    m->ch = rs->ref->coarse[0]->h;
  }
  m->fy0 = m->cy0 = INT32_MAX;
  m->fy1 = m->cy1 = INT32_MIN;
  for (int c = 0; c < g->nclass; c++) {
    m->i0[c] = i0[c];
    m->i1[c] = i1[c];
    if (i1[c] <= i0[c]) continue;
    int fy0, fy1, cy0, cy1;
    ts_refgrid_rows(s, g, c, i0[c], i1[c], &fy0, &fy1, &cy0, &cy1);
    if (fy0 < m->fy0) m->fy0 = fy0;
    if (fy1 > m->fy1) m->fy1 = fy1;
    if (cy0 < m->cy0) m->cy0 = cy0;
    if (cy1 > m->cy1) m->cy1 = cy1;
  }
  if (m->fy0 > m->fy1) m->fy0 = 0, m->fy1 = 1; /* an empty slice still ships one row */
  if (!m->has_coarse) m->cy0 = m->cy1 = 0;
  else if (m->cy0 > m->cy1) m->cy0 = 0, m->cy1 = 1;
  for (int p = 0; p < s->nplanes; p++) {
    m->fine[p] = rs->ref->fine[p]->px + (size_t)m->fy0 * (size_t)g->w;
    if (m->has_coarse) m->coarse[p] = rs->ref->coarse[p]->px + (size_t)m->cy0 * (size_t)m->cw;
  }
  m->usage = !rs->usage                           ? TS_SLICE_USAGE_NONE
             : counts == NULL || counts->total == 0 ? TS_SLICE_USAGE_ZERO
                                                  : TS_SLICE_USAGE_COUNTS;
  if (m->usage == TS_SLICE_USAGE_COUNTS) m->counts = (const uint8_t *)(counts->count + (size_t)m->fy0 * (size_t)g->w);
}

void ts_slice_free(ts_slice *s) {
  if (s == NULL) return;
  for (int c = 0; c < 4; c++) {
    if (s->cls[c].data != NULL) ts_l1_set_free(&s->cls[c]);
    free(s->penalty[c]);
  }
  for (int p = 0; p < TS_MAX_PLANES; p++) {
    ts_plane_free(&s->fine[p]);
    ts_plane_free(&s->coarse[p]);
  }
  ts_usage_free(&s->usage);
  ts_shape_free(&s->shape);
  free(s->qbuf);
  free(s->mbuf);
  free(s->order);
  free(s->tbest);
  free(s);
}

uint32_t ts_slice_set(const ts_slice *s) { return s->set; }
uint32_t ts_slice_gen(const ts_slice *s) { return s->gen; }
uint32_t ts_slice_vbytes(const ts_slice *s) { return ts_shape_bytes(&s->shape); }

uint64_t ts_slice_vectors(const ts_slice *s) {
  uint64_t n = 0;
  for (int c = 0; c < s->grid.nclass; c++) n += s->i1[c] - s->i0[c];
  return n;
}

/* Full-size plane, zero outside rows [y0, y1), which come from rows. */
static int plane_from_rows(ts_plane *p, int w, int h, int y0, int y1, const uint8_t *rows) {
  if (ts_plane_alloc(p, w, h) != 0) return TS_ENOMEM;
  memset(p->px, 0, (size_t)w * (size_t)h);
  memcpy(p->px + (size_t)y0 * (size_t)w, rows, (size_t)w * (size_t)(y1 - y0));
  return 0;
}

/* Every class range must lie in its class and read only the shipped rows. */
static int check_ranges(const ts_slice *s, const ts_slice_desc *m, char *err) {
  for (int c = 0; c < s->grid.nclass; c++) {
    if (m->i1[c] > s->grid.count[c])
      return ts_error(err, TS_EINVAL, "slice range %u..%u past class %d's %u vectors", m->i0[c], m->i1[c], c,
                      s->grid.count[c]);
    if (m->i1[c] == m->i0[c]) continue;
    int fy0, fy1, cy0, cy1;
    ts_refgrid_rows(&s->shape, &s->grid, c, m->i0[c], m->i1[c], &fy0, &fy1, &cy0, &cy1);
    if (fy0 < m->fy0 || fy1 > m->fy1 || (m->has_coarse && (cy0 < m->cy0 || cy1 > m->cy1)))
      return ts_error(err, TS_EINVAL, "slice of class %d reads rows %d..%d (coarse %d..%d) outside the %d..%d "
                      "(coarse %d..%d) sent", c, fy0, fy1 - 1, cy0, cy1 - 1, m->fy0, m->fy1 - 1, m->cy0, m->cy1 - 1);
  }
  return 0;
}

/* Loads the counters of the shipped rows and the block sums of every
 * block inside them (all the slice's blocks are). */
static void usage_load_rows(ts_usage *u, int y0, int y1, const uint8_t *le) {
  const ts_refgrid *g = &u->grid;
  for (int y = y0; y < y1; y++)
    for (int x = 0; x < g->w; x++) {
      const uint8_t *p = le + 4 * ((size_t)(y - y0) * (size_t)g->w + (size_t)x);
      uint32_t v = (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
      u->count[(size_t)y * (size_t)g->w + (size_t)x] = v;
      u->total += v;
    }
  ts_usage_sum_blocks(u, y0, y1);
}

static int build(ts_slice *s, const ts_slice_desc *m, char *err) {
  int rc = ts_shape_init(&s->shape, (ts_shape_kind)m->kind, m->wn, m->wb, m->has_coarse, m->nplanes,
                         m->coarse_weight, err);
  if (rc != 0) return rc;
  /* The engine may weight a shape differently from its lambda (masked
   * queries use the plain shape's weights): the message's weights rule. */
  if (m->wfine == 0 || (m->has_coarse == 0) != (m->wcoarse == 0))
    return ts_error(err, TS_EINVAL, "weights %u/%u do not fit the shape", m->wfine, m->wcoarse);
  s->shape.wfine = m->wfine;
  s->shape.wcoarse = m->wcoarse;
  rc = ts_refgrid_init(&s->grid, &s->shape, m->w, m->h, m->cw, m->ch, m->parity, err);
  if (rc == 0) rc = check_ranges(s, m, err);
  if (rc != 0) return rc;
  ts_levelplanes planes = {m->nplanes, {0}, {0}};
  for (int p = 0; p < m->nplanes; p++) {
    if (plane_from_rows(&s->fine[p], m->w, m->h, m->fy0, m->fy1, m->fine[p]) != 0 ||
        (m->has_coarse && plane_from_rows(&s->coarse[p], m->cw, m->ch, m->cy0, m->cy1, m->coarse[p]) != 0))
      return ts_error(err, TS_ENOMEM, "out of memory for the slice's planes");
    planes.fine[p] = &s->fine[p];
    planes.coarse[p] = &s->coarse[p];
  }
  s->with_usage = m->usage != TS_SLICE_USAGE_NONE;
  if (s->with_usage && ts_usage_init(&s->usage, &s->grid, m->wb, 1) != 0)
    return ts_error(err, TS_ENOMEM, "out of memory for the usage replica");
  if (m->usage == TS_SLICE_USAGE_COUNTS) usage_load_rows(&s->usage, m->fy0, m->fy1, m->counts);
  for (int c = 0; c < s->grid.nclass; c++) {
    s->i0[c] = m->i0[c];
    s->i1[c] = m->i1[c];
    rc = ts_vecset_build(&s->shape, &s->grid, &planes, c, m->i0[c], m->i1[c], &s->cls[c]);
    if (rc == 0 && s->with_usage) {
      s->penalty[c] = calloc((size_t)s->cls[c].ngroups * TS_L1_GROUP + 1, sizeof(uint32_t));
      if (s->penalty[c] == NULL) rc = TS_ENOMEM;
    }
    if (rc != 0) return ts_error(err, rc, "cannot build the slice's vectors: %s", ts_strerror(rc));
  }
  /* The vectors hold what the scans need; the planes can go. */
  for (int p = 0; p < TS_MAX_PLANES; p++) {
    ts_plane_free(&s->fine[p]);
    ts_plane_free(&s->coarse[p]);
  }
  return 0;
}

int ts_slice_load(ts_slice **out, const ts_slice_desc *m, char *err) {
  *out = NULL;
  ts_slice *s = calloc(1, sizeof(*s));
  if (s == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  s->set = m->set;
  s->gen = m->gen;
  int rc = build(s, m, err);
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
    if (c[i].x < 0 || c[i].y < 0 || c[i].x + c[i].w > s->grid.w || c[i].y + c[i].h > s->grid.h)
      return ts_error(err, TS_EINVAL, "usage commit %ux%u at (%d, %d) outside the %dx%d reference", c[i].w, c[i].h,
                      c[i].x, c[i].y, s->grid.w, s->grid.h);
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
  for (int c = 0; c < s->grid.nclass; c++) {
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
      const uint32_t *uj = s->usage.u + s->grid.base[c] + s->i0[c];
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
static int gather_queries(ts_slice *s, const ts_query_batch *b, char *err) {
  uint32_t fill[5] = {0};
  for (uint32_t i = 0; i < b->nq; i++) {
    int c = b->klass ? b->klass[i] : 0;
    if (c >= s->grid.nclass) return ts_error(err, TS_EINVAL, "query %u has class %d of %d", i, c, s->grid.nclass);
    fill[c + 1]++;
  }
  for (int c = 0; c < 4; c++) fill[c + 1] += fill[c];
  memcpy(s->qstart, fill, sizeof(fill));
  for (uint32_t i = 0; i < b->nq; i++) {
    int c = b->klass ? b->klass[i] : 0;
    uint32_t r = fill[c]++;
    s->order[r] = i;
    memcpy(s->qbuf + (size_t)r * s->vbytes, b->queries + (size_t)i * s->vbytes, s->vbytes);
    if (b->masks) memcpy(s->mbuf + (size_t)r * s->vbytes, b->masks + (size_t)i * s->vbytes, s->vbytes);
  }
  return 0;
}

int ts_slice_scan(ts_slice *s, ts_pool *pool, int threads, const ts_l1_impl *simd, const ts_query_batch *b,
                  ts_l1_best *out, uint64_t *pairs, char *err) {
  *pairs = 0;
  if (b->nq == 0) return 0;
  if (b->usage_k != 0 && !s->with_usage) return ts_error(err, TS_EINVAL, "a usage penalty on a slice without usage");
  s->vbytes = ts_shape_bytes(&s->shape);
  threads = threads == 1 ? 1 : ts_pool_size(pool); /* the pool runs all or one */
  if (ensure_scratch(s, b->nq, s->vbytes, threads) != 0)
    return ts_error(err, TS_ENOMEM, "out of memory for a batch of %u queries", b->nq);
  int rc = gather_queries(s, b, err);
  if (rc != 0) return rc;
  s->simd = simd;
  s->nq = b->nq;
  s->usage_k = b->usage_k;
  s->masked = b->masks != NULL;
  if (threads == 1) scan_runs(s, 0, 1);
  else ts_pool_run(pool, scan_runs, s);
  for (int c = 0; c < s->grid.nclass; c++) {
    uint32_t base = s->grid.base[c] + s->i0[c];
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
