/* neigh.c - see neigh.h. */
#include "neigh.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"

int ts_coarse_width(int wn) {
  int c = (wn + 1) / 2; /* ceil(wn / 2) */
  return (c % 2 == 1) ? c : c + 1;
}

static int fine_in_shape(ts_shape_kind kind, int dx, int dy, int wb) {
  if (kind == TS_SHAPE_SQUARE) return 1;
  return dy < 0 || (dy < wb && dx < 0);
}

static uint64_t gcd64(uint64_t a, uint64_t b) {
  while (b != 0) {
    uint64_t t = a % b;
    a = b;
    b = t;
  }
  return a;
}

/* Weights from the pixel counts of the neighbourhood proper (the square
 * without the block, Table 3.1, or the L). */
static void shape_set_weights(ts_shape *s, double coarse_weight) {
  int nfine = s->kind == TS_SHAPE_SQUARE ? s->wn * s->wn - s->wb * s->wb : s->nfine_px;
  if (s->wc == 0) {
    s->wfine = 1;
    s->wcoarse = 0;
    return;
  }
  /* D = D_fine + lambda * (n_fine / n_coarse) * D_coarse, scaled by
   * 16 * n_coarse to stay integral; lambda quantised to 1/16 of a pixel
   * ratio. Reduced by the gcd so distances stay small. */
  uint64_t wf = 16ull * (uint64_t)s->ncoarse_px;
  uint64_t wc = (uint64_t)llround(coarse_weight * 16.0 * nfine);
  uint64_t g = gcd64(wf, wc);
  if (g == 0) g = 1;
  s->wfine = (uint32_t)(wf / g);
  s->wcoarse = (uint32_t)(wc / g);
}

int ts_shape_init(ts_shape *s, ts_shape_kind kind, int wn, int wb,
                  int has_coarse, int nplanes, double coarse_weight,
                  char *err) {
  memset(s, 0, sizeof(*s));
  if (wb < 1 || wb % 2 == 0 || wn % 2 == 0 || wn < wb + 2 || wn > TS_MAX_WN)
    return ts_error(err, TS_EINVAL,
                    "neighbourhood %d / block %d: need odd sizes with "
                    "block < window <= %d",
                    wn, wb, TS_MAX_WN);
  if (nplanes < 1 || nplanes > TS_MAX_PLANES)
    return ts_error(err, TS_EINVAL, "%d feature planes: need 1..%d", nplanes,
                    TS_MAX_PLANES);
  if (!(coarse_weight >= 0.0 && coarse_weight <= 1000.0))
    return ts_error(err, TS_EINVAL, "coarse weight %g: need 0..1000",
                    coarse_weight);
  s->wn = wn;
  s->wb = wb;
  s->wc = has_coarse ? ts_coarse_width(wn) : 0;
  s->kind = kind;
  s->nplanes = nplanes;
  int h = (wn - wb) / 2;
  s->fine_dx = malloc(sizeof(int16_t) * (size_t)wn * wn);
  s->fine_dy = malloc(sizeof(int16_t) * (size_t)wn * wn);
  if (s->fine_dx == NULL || s->fine_dy == NULL) {
    ts_shape_free(s);
    return ts_error(err, TS_ENOMEM, "out of memory for a neighbourhood");
  }
  for (int dy = -h; dy < wb + h; dy++)
    for (int dx = -h; dx < wb + h; dx++)
      if (fine_in_shape(kind, dx, dy, wb)) {
        s->fine_dx[s->nfine_px] = (int16_t)dx;
        s->fine_dy[s->nfine_px] = (int16_t)dy;
        s->nfine_px++;
      }
  s->ncoarse_px = s->wc * s->wc;
  uint32_t fine_bytes = (uint32_t)(s->nfine_px * nplanes);
  uint32_t coarse_bytes = (uint32_t)(s->ncoarse_px * nplanes);
  s->nfine_chunks = (fine_bytes + TS_L1_CHUNK - 1) / TS_L1_CHUNK;
  s->nchunks = s->nfine_chunks + (coarse_bytes + TS_L1_CHUNK - 1) / TS_L1_CHUNK;
  if (s->nchunks > TS_L1_MAX_CHUNKS) {
    ts_shape_free(s);
    return ts_error(err, TS_EINVAL,
                    "neighbourhood of %u bytes is too long (max %d)",
                    fine_bytes + coarse_bytes, TS_L1_MAX_CHUNKS * TS_L1_CHUNK);
  }
  s->coarse_weight = coarse_weight;
  shape_set_weights(s, coarse_weight);
  return 0;
}

void ts_shape_free(ts_shape *s) {
  free(s->fine_dx);
  free(s->fine_dy);
  s->fine_dx = s->fine_dy = NULL;
}

/* Number of values in [lo, lo+n) with the given parity (0/1), and the first. */
static int parity_span(int lo, int n, int par, int *first) {
  int off = ((lo & 1) != par) ? 1 : 0;
  *first = lo + off;
  return n > off ? (n - off + 1) / 2 : 0;
}

int ts_refgrid_init(ts_refgrid *g, const ts_shape *s, int w, int h, int cw,
                    int ch, int parity, char *err) {
  memset(g, 0, sizeof(*g));
  int hn = (s->wn - s->wb) / 2, half_b = (s->wb - 1) / 2;
  int xmin = hn, ymin = hn;
  int xmax = w - s->wb - hn, ymax = h - s->wb - hn;
  if (s->wc > 0) {
    int hc = (s->wc - 1) / 2;
    /* coarse centre (x + half_b) / 2 must be within [hc, cw - 1 - hc] */
    int cxmin = 2 * hc - half_b, cxmax = 2 * (cw - 1 - hc) + 1 - half_b;
    int cymin = 2 * hc - half_b, cymax = 2 * (ch - 1 - hc) + 1 - half_b;
    if (cxmin > xmin) xmin = cxmin;
    if (cymin > ymin) ymin = cymin;
    if (cxmax < xmax) xmax = cxmax;
    if (cymax < ymax) ymax = cymax;
  }
  g->w = w;
  g->h = h;
  g->x0 = xmin;
  g->y0 = ymin;
  g->nx = xmax >= xmin ? xmax - xmin + 1 : 0;
  g->ny = ymax >= ymin ? ymax - ymin + 1 : 0;
  g->parity = parity ? 1 : 0;
  g->nclass = parity ? 4 : 1;
  for (int c = 0; c < g->nclass; c++) {
    int fx, fy;
    uint64_t n;
    if (parity)
      n = (uint64_t)parity_span(g->x0, g->nx, c & 1, &fx) *
          (uint64_t)parity_span(g->y0, g->ny, (c >> 1) & 1, &fy);
    else
      n = (uint64_t)g->nx * (uint64_t)g->ny;
    if (n == 0 || n > UINT32_MAX / 2)
      return ts_error(err, TS_EINVAL,
                      "reference level %dx%d has %s block positions for a "
                      "%dx%d window%s: use a larger reference, fewer levels "
                      "or a smaller window",
                      w, h, n == 0 ? "no" : "too many", s->wn, s->wn,
                      parity && n == 0 ? " in some parity class" : "");
    g->base[c] = g->total;
    g->count[c] = (uint32_t)n;
    g->total += (uint32_t)n;
  }
  return 0;
}

void ts_refgrid_pos(const ts_refgrid *g, int c, uint32_t i, int *x, int *y) {
  if (!g->parity) {
    *x = g->x0 + (int)(i % (uint32_t)g->nx);
    *y = g->y0 + (int)(i / (uint32_t)g->nx);
    return;
  }
  int fx, fy;
  int ncols = parity_span(g->x0, g->nx, c & 1, &fx);
  parity_span(g->y0, g->ny, (c >> 1) & 1, &fy);
  *x = fx + 2 * (int)(i % (uint32_t)ncols);
  *y = fy + 2 * (int)(i / (uint32_t)ncols);
}

int64_t ts_refgrid_index(const ts_refgrid *g, int x, int y) {
  if (x < g->x0 || y < g->y0 || x >= g->x0 + g->nx || y >= g->y0 + g->ny)
    return -1;
  if (!g->parity)
    return (int64_t)(y - g->y0) * g->nx + (x - g->x0);
  int c = ts_refgrid_class(g, x, y);
  int fx, fy;
  int ncols = parity_span(g->x0, g->nx, c & 1, &fx);
  parity_span(g->y0, g->ny, (c >> 1) & 1, &fy);
  return (int64_t)g->base[c] + (int64_t)((y - fy) / 2) * ncols + (x - fx) / 2;
}

void ts_refgrid_split(const ts_refgrid *g, uint32_t global, int *c,
                      uint32_t *i) {
  int k = 0;
  while (k + 1 < g->nclass && global >= g->base[k + 1]) k++;
  *c = k;
  *i = global - g->base[k];
}

void ts_refgrid_rows(const ts_shape *s, const ts_refgrid *g, int c, uint32_t i0, uint32_t i1,
                     int *fy0, int *fy1, int *cy0, int *cy1) {
  int x, ya, yb, hn = (s->wn - s->wb) / 2;
  ts_refgrid_pos(g, c, i0, &x, &ya);
  ts_refgrid_pos(g, c, i1 - 1, &x, &yb);
  *fy0 = ya - hn;
  *fy1 = yb + s->wb + hn;
  *cy0 = *cy1 = 0;
  if (s->wc > 0) {
    int hc = (s->wc - 1) / 2, half_b = (s->wb - 1) / 2;
    *cy0 = (ya + half_b) / 2 - hc;
    *cy1 = (yb + half_b) / 2 + hc + 1;
  }
}

void ts_vec_ref(const ts_shape *s, const ts_levelplanes *ref, int x, int y,
                uint8_t *out) {
  uint32_t n = 0;
  for (int p = 0; p < s->nplanes; p++) {
    const ts_plane *pl = ref->fine[p];
    for (int k = 0; k < s->nfine_px; k++)
      out[n++] = ts_plane_at(pl, x + s->fine_dx[k], y + s->fine_dy[k]);
  }
  while (n < s->nfine_chunks * TS_L1_CHUNK) out[n++] = 0;
  if (s->wc > 0) {
    int hc = (s->wc - 1) / 2, half_b = (s->wb - 1) / 2;
    int cx = (x + half_b) / 2, cy = (y + half_b) / 2;
    for (int p = 0; p < s->nplanes; p++) {
      const ts_plane *pl = ref->coarse[p];
      for (int dy = -hc; dy <= hc; dy++)
        for (int dx = -hc; dx <= hc; dx++) out[n++] = ts_plane_at(pl, cx + dx, cy + dy);
    }
  }
  while (n < ts_shape_bytes(s)) out[n++] = 0;
}

void ts_vec_query(const ts_shape *s, const ts_levelplanes *canvas, int x,
                  int y, uint8_t *out) {
  uint32_t n = 0;
  const ts_plane *f0 = canvas->fine[0];
  int hn = (s->wn - s->wb) / 2;
  int inside = x >= hn && y >= hn && x + s->wb + hn <= f0->w && y + s->wb + hn <= f0->h;
  for (int p = 0; p < s->nplanes; p++) {
    const ts_plane *pl = canvas->fine[p];
    if (inside) /* no wrap: skip the modulo (most blocks) */
      for (int k = 0; k < s->nfine_px; k++) out[n++] = ts_plane_at(pl, x + s->fine_dx[k], y + s->fine_dy[k]);
    else
      for (int k = 0; k < s->nfine_px; k++) out[n++] = ts_plane_wrap(pl, x + s->fine_dx[k], y + s->fine_dy[k]);
  }
  while (n < s->nfine_chunks * TS_L1_CHUNK) out[n++] = 0;
  if (s->wc > 0) {
    const ts_plane *f = canvas->fine[0], *c0 = canvas->coarse[0];
    int hc = (s->wc - 1) / 2, half_b = (s->wb - 1) / 2;
    /* Block centre scaled to the coarse canvas: x/2 for even sizes, and a
     * consistent torus mapping for any size. */
    long fx = (x + half_b) % f->w, fy = (y + half_b) % f->h;
    int cx = (int)(fx * c0->w / f->w), cy = (int)(fy * c0->h / f->h);
    for (int p = 0; p < s->nplanes; p++) {
      const ts_plane *pl = canvas->coarse[p];
      for (int dy = -hc; dy <= hc; dy++)
        for (int dx = -hc; dx <= hc; dx++) out[n++] = ts_plane_wrap(pl, cx + dx, cy + dy);
    }
  }
  while (n < ts_shape_bytes(s)) out[n++] = 0;
}

int ts_vecset_build(const ts_shape *s, const ts_refgrid *g,
                    const ts_levelplanes *ref, int c, uint32_t i0,
                    uint32_t i1, ts_l1_set *out) {
  if (i1 < i0 || i1 > g->count[c]) return TS_EINVAL;
  int rc = ts_l1_set_init(out, i1 - i0, s->nchunks);
  if (rc != 0) return rc;
  rc = ts_l1_set_weigh_fine_coarse(out, s->nfine_chunks, s->wfine, s->wcoarse, NULL);
  if (rc != 0) {
    ts_l1_set_free(out);
    return rc;
  }
  uint8_t vec[TS_L1_MAX_CHUNKS * TS_L1_CHUNK];
  for (uint32_t i = i0; i < i1; i++) {
    int x, y;
    ts_refgrid_pos(g, c, i, &x, &y);
    ts_vec_ref(s, ref, x, y, vec);
    ts_l1_set_put(out, i - i0, vec);
  }
  return 0;
}
