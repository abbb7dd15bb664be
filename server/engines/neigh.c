/* neigh.c - see neigh.h. */
#include "neigh.h"

#include <math.h>
#include <string.h>

#include "error.h"

int ts_coarse_width(int wn) {
  int c = (wn + 1) / 2; /* ceil(wn / 2) */
  return (c % 2 == 1) ? c : c + 1;
}

static int fine_in_shape(ts_shape_kind kind, int dx, int dy, int wb) {
  if (kind != TS_SHAPE_CAUSAL) return 1;
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

/* Part weights from the pixel counts of the neighbourhood proper (the
 * square without the block, Table 3.1, or the L): D = D_fine + lambda *
 * (n_fine / n_coarse) * D_coarse, scaled by 16 * n_coarse to stay
 * integral; lambda quantised to 1/16 of a pixel ratio. Reduced by the gcd
 * so distances stay small. */
static void set_weights(ts_window_spec *s, ts_shape_kind kind, int wn, int wb, int ncoarse, double coarse_weight) {
  int nfine = kind != TS_SHAPE_CAUSAL ? wn * wn - wb * wb : s->noff[TS_SRC_FINE];
  if (ncoarse == 0) {
    s->part[0].weight = 1;
    return;
  }
  uint64_t wf = 16ull * (uint64_t)ncoarse;
  uint64_t wc = (uint64_t)llround(coarse_weight * 16.0 * nfine);
  uint64_t g = gcd64(wf, wc);
  if (g == 0) g = 1;
  s->part[0].weight = (uint32_t)(wf / g);
  s->part[1].weight = (uint32_t)(wc / g);
}

int ts_neigh_window(ts_window *w, ts_shape_kind kind, int wn, int wb, int has_coarse, int nplanes,
                    double coarse_weight, char *err) {
  memset(w, 0, sizeof(*w));
  if (wb < 1 || wb % 2 == 0 || wn % 2 == 0 || wn < wb + 2 || wn > TS_MAX_WN)
    return ts_error(err, TS_EINVAL, "neighbourhood %d / block %d: need odd sizes with block < window <= %d", wn, wb,
                    TS_MAX_WN);
  if (nplanes < 1 || nplanes > TS_MAX_PLANES)
    return ts_error(err, TS_EINVAL, "%d feature planes: need 1..%d", nplanes, TS_MAX_PLANES);
  if (!(coarse_weight >= 0.0 && coarse_weight <= 1000.0))
    return ts_error(err, TS_EINVAL, "coarse weight %g: need 0..1000", coarse_weight);
  int h = (wn - wb) / 2, wc = has_coarse ? ts_coarse_width(wn) : 0, hc = (wc - 1) / 2;
  int16_t dx[2][TS_MAX_WN * TS_MAX_WN], dy[2][TS_MAX_WN * TS_MAX_WN];
  uint8_t known[TS_MAX_WN * TS_MAX_WN];
  ts_window_spec s;
  memset(&s, 0, sizeof(s));
  for (int y = -h; y < wb + h; y++)
    for (int x = -h; x < wb + h; x++)
      if (fine_in_shape(kind, x, y, wb)) {
        known[s.noff[0]] = kind == TS_SHAPE_SQUARE && fine_in_shape(TS_SHAPE_CAUSAL, x, y, wb);
        dx[0][s.noff[0]] = (int16_t)x;
        dy[0][s.noff[0]++] = (int16_t)y;
      }
  if (kind != TS_SHAPE_CAUSAL) s.known = known; /* the L counts in masked queries, FREE none */
  for (int y = -hc; y <= hc && wc > 0; y++)
    for (int x = -hc; x <= hc; x++) {
      dx[1][s.noff[1]] = (int16_t)x;
      dy[1][s.noff[1]++] = (int16_t)y;
    }
  s.nplanes[TS_SRC_FINE] = nplanes;
  s.nplanes[TS_SRC_COARSE] = wc > 0 ? nplanes : 0;
  for (int src = 0; src < TS_NSRC; src++) {
    s.dx[src] = dx[src];
    s.dy[src] = dy[src];
  }
  s.extent[TS_SRC_FINE] = (ts_box){(int16_t)-h, (int16_t)-h, (int16_t)(wb + h), (int16_t)(wb + h)};
  s.extent[TS_SRC_COARSE] = (ts_box){(int16_t)-hc, (int16_t)-hc, (int16_t)(hc + 1), (int16_t)(hc + 1)};
  s.centre = (wb - 1) / 2;
  s.block = wb;
  s.nparts = wc > 0 ? 2 : 1;
  s.part[0] = (ts_part){TS_SRC_FINE, 0, (uint8_t)nplanes, 0};
  s.part[1] = (ts_part){TS_SRC_COARSE, 0, (uint8_t)nplanes, 0};
  set_weights(&s, kind, wn, wb, wc * wc, coarse_weight);
  return ts_window_init(w, &s, err);
}
