/* anchors.c - see anchors.h. */
#include "anchors.h"

#include <stdlib.h>
#include <string.h>

#include "error.h"

#define TS_ANCHORS_MAX (1u << 31) /* global indices stay below 2^31 */

/* The box of anchors whose fine extent fits w x h and whose coarse extent,
 * around (x + centre) / 2, fits cw x ch. */
static void box_init(ts_anchors *a, const ts_window *win, int w, int h, int cw, int ch) {
  const ts_box *e = &win->spec.extent[TS_SRC_FINE];
  int xmin = -e->dx0, ymin = -e->dy0, xmax = w - e->dx1, ymax = h - e->dy1;
  if (ts_window_has_coarse(win)) {
    const ts_box *c = &win->spec.extent[TS_SRC_COARSE];
    int k = win->spec.centre;
    /* (x + k) / 2 + c->dx0 >= 0  and  (x + k) / 2 + c->dx1 <= cw */
    int cxmin = -2 * c->dx0 - k, cxmax = 2 * (cw - c->dx1) + 1 - k;
    int cymin = -2 * c->dy0 - k, cymax = 2 * (ch - c->dy1) + 1 - k;
    if (cxmin > xmin) xmin = cxmin;
    if (cymin > ymin) ymin = cymin;
    if (cxmax < xmax) xmax = cxmax;
    if (cymax < ymax) ymax = cymax;
  }
  if (xmin < 0) xmin = 0;
  if (ymin < 0) ymin = 0;
  a->w = w;
  a->h = h;
  a->x0 = xmin;
  a->y0 = ymin;
  a->nx = xmax >= xmin ? xmax - xmin + 1 : 0;
  a->ny = ymax >= ymin ? ymax - ymin + 1 : 0;
}

/* Class bases from the counts; refuses an empty or oversized set. */
static int set_bases(ts_anchors *a, char *err) {
  uint64_t total = 0;
  for (int c = 0; c < a->nclass; c++) {
    a->base[c] = (uint32_t)total;
    total += a->count[c];
    if (total > TS_ANCHORS_MAX) break;
  }
  if (total == 0 || total > TS_ANCHORS_MAX)
    return ts_error(err, TS_EINVAL,
                    "reference level %dx%d has %s positions for the window: use a larger reference, fewer "
                    "levels or a smaller window",
                    a->w, a->h, total == 0 ? "no valid" : "too many");
  a->total = (uint32_t)total;
  return 0;
}

static int plane_fits(const ts_plane *p, int w, int h) { return p == NULL || (p->w == w && p->h == h); }

/* Indexes anchor rows [ay0, ay1) from those rows of the planes (w wide,
 * NULL = none). above[c]: class-c anchors above ay0 (NULL = none). With
 * counting, the rows are the whole box and give the counts; else the
 * counts are given and the rows may hold no more than they allow. */
static int index_rows(ts_anchors *a, int ay0, int ay1, const uint8_t *labels, const uint8_t *valid,
                      const uint32_t *above, int counting, char *err) {
  size_t rows = (size_t)(ay1 - ay0);
  a->indexed = 1;
  a->ay0 = ay0;
  a->ay1 = ay1;
  a->index = malloc(sizeof(uint32_t) * (rows * (size_t)a->nx + 1));
  a->before = malloc(sizeof(uint32_t) * (rows + 1) * (size_t)a->nclass);
  if (a->index == NULL || a->before == NULL) return ts_error(err, TS_ENOMEM, "out of memory for the anchors' index");
  uint32_t run[TS_MAX_CLASSES] = {0};
  if (above != NULL) memcpy(run, above, sizeof(uint32_t) * (size_t)a->nclass);
  /* Pass 1: ranks within the class, and the counts above every row. */
  for (size_t r = 0; r <= rows; r++) {
    memcpy(a->before + r * (size_t)a->nclass, run, sizeof(uint32_t) * (size_t)a->nclass);
    if (r == rows) break;
    size_t off = r * (size_t)a->w + (size_t)a->x0;
    for (int i = 0; i < a->nx; i++) {
      uint32_t *slot = &a->index[r * (size_t)a->nx + (size_t)i];
      *slot = TS_NOT_ANCHOR;
      if (valid != NULL && valid[off + (size_t)i] == 0) continue;
      int c = labels != NULL ? labels[off + (size_t)i] : 0;
      if (c >= a->nclass)
        return ts_error(err, TS_EINVAL, "label %d at (%d, %d), but the set has %d classes", c, a->x0 + i,
                        ay0 + (int)r, a->nclass);
      if (!counting && run[c] >= a->count[c])
        return ts_error(err, TS_EINVAL, "rows %d..%d hold more anchors of class %d than its %u", ay0, ay1 - 1, c,
                        a->count[c]);
      *slot = run[c]++;
    }
  }
  if (counting) {
    memcpy(a->count, run, sizeof(uint32_t) * (size_t)a->nclass);
    int rc = set_bases(a, err);
    if (rc != 0) return rc;
  }
  /* Pass 2: ranks become global indices (and, holding them all, the cell
   * of each global index). */
  if (counting && (a->cell = malloc(sizeof(uint32_t) * ((size_t)a->total + 1))) == NULL)
    return ts_error(err, TS_ENOMEM, "out of memory for the anchors' index");
  for (size_t r = 0; r < rows; r++) {
    size_t off = r * (size_t)a->w + (size_t)a->x0;
    for (int i = 0; i < a->nx; i++) {
      size_t k = r * (size_t)a->nx + (size_t)i;
      if (a->index[k] == TS_NOT_ANCHOR) continue;
      a->index[k] += a->base[labels != NULL ? labels[off + (size_t)i] : 0];
      if (a->cell != NULL) a->cell[a->index[k]] = (uint32_t)k;
    }
  }
  return 0;
}

static int check_classes(int nclass, int labelled, char *err) {
  if (nclass < 1 || nclass > TS_MAX_CLASSES || (!labelled && nclass != 1))
    return ts_error(err, TS_EINVAL, "%d classes %s: need 1..%d with a label plane, 1 without", nclass,
                    labelled ? "with labels" : "without labels", TS_MAX_CLASSES);
  return 0;
}

int ts_anchors_init(ts_anchors *a, const ts_window *win, int w, int h, int cw, int ch, const ts_plane *labels,
                    int nclass, const ts_plane *valid, char *err) {
  memset(a, 0, sizeof(*a));
  int rc = check_classes(nclass, labels != NULL, err);
  if (rc != 0) return rc;
  if (!plane_fits(labels, w, h) || !plane_fits(valid, w, h))
    return ts_error(err, TS_EINVAL, "label or validity plane of another size than the %dx%d level", w, h);
  box_init(a, win, w, h, cw, ch);
  a->nclass = nclass;
  if (labels == NULL && valid == NULL) {
    a->count[0] = (uint64_t)a->nx * (uint64_t)a->ny > TS_ANCHORS_MAX ? TS_ANCHORS_MAX + 1u : (uint32_t)(a->nx * a->ny);
    return set_bases(a, err);
  }
  if (a->ny == 0) return set_bases(a, err);
  size_t first = (size_t)a->y0 * (size_t)w;
  rc = index_rows(a, a->y0, a->y0 + a->ny, labels ? labels->px + first : NULL, valid ? valid->px + first : NULL,
                  NULL, 1, err);
  if (rc != 0) ts_anchors_free(a);
  return rc;
}

int ts_anchors_init_rows(ts_anchors *a, const ts_window *win, int w, int h, int cw, int ch, int nclass,
                         const uint32_t *count, int ay0, int ay1, const uint8_t *label_rows,
                         const uint8_t *valid_rows, const uint32_t *above, char *err) {
  memset(a, 0, sizeof(*a));
  int rc = check_classes(nclass, label_rows != NULL, err);
  if (rc != 0) return rc;
  box_init(a, win, w, h, cw, ch);
  a->nclass = nclass;
  memcpy(a->count, count, sizeof(uint32_t) * (size_t)nclass);
  if ((rc = set_bases(a, err)) != 0) return rc;
  if (label_rows == NULL && valid_rows == NULL) {
    if (a->count[0] != (uint64_t)a->nx * (uint64_t)a->ny)
      return ts_error(err, TS_EINVAL, "%u anchors announced, but the window fits %d x %d in the %dx%d level",
                      a->count[0], a->nx, a->ny, w, h);
    return 0;
  }
  if (ay0 < a->y0 || ay1 <= ay0 || ay1 > a->y0 + a->ny)
    return ts_error(err, TS_EINVAL, "anchor rows %d..%d outside the rows %d..%d the window fits", ay0, ay1 - 1, a->y0,
                    a->y0 + a->ny - 1);
  for (int c = 0; c < nclass; c++)
    if (above[c] > a->count[c])
      return ts_error(err, TS_EINVAL, "%u anchors of class %d above row %d, of %u", above[c], c, ay0, a->count[c]);
  rc = index_rows(a, ay0, ay1, label_rows, valid_rows, above, 0, err);
  if (rc != 0) ts_anchors_free(a);
  return rc;
}

void ts_anchors_free(ts_anchors *a) {
  free(a->index);
  free(a->before);
  free(a->cell);
  a->index = a->before = a->cell = NULL;
}

int64_t ts_anchors_index(const ts_anchors *a, int x, int y) {
  if (x < a->x0 || y < a->y0 || x >= a->x0 + a->nx || y >= a->y0 + a->ny) return -1;
  if (!a->indexed) return (int64_t)(y - a->y0) * a->nx + (x - a->x0);
  if (y < a->ay0 || y >= a->ay1) return -1;
  uint32_t v = a->index[(size_t)(y - a->ay0) * (size_t)a->nx + (size_t)(x - a->x0)];
  return v == TS_NOT_ANCHOR ? -1 : (int64_t)v;
}

int ts_anchors_class(const ts_anchors *a, uint32_t global) {
  /* The last class whose base is <= global: never an empty one (its base
   * equals the next class's). */
  int lo = 0, hi = a->nclass - 1;
  while (lo < hi) {
    int mid = (lo + hi + 1) / 2;
    if (a->base[mid] <= global) lo = mid;
    else hi = mid - 1;
  }
  return lo;
}

uint32_t ts_anchors_above(const ts_anchors *a, int c, int y) {
  if (!a->indexed) return (uint32_t)(y - a->y0) * (uint32_t)a->nx;
  return a->before[(size_t)(y - a->ay0) * (size_t)a->nclass + (size_t)c];
}

void ts_anchors_pos(const ts_anchors *a, uint32_t global, int *x, int *y) {
  if (!a->indexed) {
    *x = a->x0 + (int)(global % (uint32_t)a->nx);
    *y = a->y0 + (int)(global / (uint32_t)a->nx);
    return;
  }
  if (a->cell != NULL) {
    uint32_t k = a->cell[global];
    *x = a->x0 + (int)(k % (uint32_t)a->nx);
    *y = a->ay0 + (int)(k / (uint32_t)a->nx);
    return;
  }
  int c = ts_anchors_class(a, global);
  uint32_t rank = global - a->base[c];
  /* The last held row with at most rank anchors of class c above it. */
  int lo = a->ay0, hi = a->ay1 - 1;
  while (lo < hi) {
    int mid = (lo + hi + 1) / 2;
    if (ts_anchors_above(a, c, mid) <= rank) lo = mid;
    else hi = mid - 1;
  }
  const uint32_t *row = a->index + (size_t)(lo - a->ay0) * (size_t)a->nx;
  int i = 0;
  while (i < a->nx - 1 && row[i] != global) i++;
  *x = a->x0 + i;
  *y = lo;
}

void ts_anchors_rows(const ts_anchors *a, int c, uint32_t i0, uint32_t i1, int *y0, int *y1) {
  int x, ya, yb;
  ts_anchors_pos(a, a->base[c] + i0, &x, &ya);
  ts_anchors_pos(a, a->base[c] + i1 - 1, &x, &yb);
  *y0 = ya;
  *y1 = yb + 1;
}

void ts_window_rows(const ts_window *win, int ay0, int ay1, int *fy0, int *fy1, int *cy0, int *cy1) {
  const ts_box *e = &win->spec.extent[TS_SRC_FINE];
  *fy0 = ay0 + e->dy0;
  *fy1 = ay1 - 1 + e->dy1;
  *cy0 = *cy1 = 0;
  if (ts_window_has_coarse(win)) {
    const ts_box *c = &win->spec.extent[TS_SRC_COARSE];
    int k = win->spec.centre;
    *cy0 = (ay0 + k) / 2 + c->dy0;
    *cy1 = (ay1 - 1 + k) / 2 + c->dy1;
  }
}

int ts_anchors_valid_from_mask(const ts_plane *mask, const ts_box *extent, ts_plane *valid) {
  int w = mask->w, h = mask->h;
  /* holes[y][x]: undefined pixels in [0, x) x [0, y). */
  uint32_t *holes = calloc((size_t)(w + 1) * (size_t)(h + 1), sizeof(uint32_t));
  if (holes == NULL || ts_plane_alloc(valid, w, h) != 0) {
    free(holes);
    return TS_ENOMEM;
  }
  size_t stride = (size_t)w + 1;
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++)
      holes[(size_t)(y + 1) * stride + (size_t)x + 1] = holes[(size_t)y * stride + (size_t)x + 1] +
                                                         holes[(size_t)(y + 1) * stride + (size_t)x] -
                                                         holes[(size_t)y * stride + (size_t)x] +
                                                         (ts_plane_at(mask, x, y) == 0);
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      int xa = x + extent->dx0, xb = x + extent->dx1, ya = y + extent->dy0, yb = y + extent->dy1;
      int inside = xa >= 0 && ya >= 0 && xb <= w && yb <= h;
      uint32_t n = inside ? holes[(size_t)yb * stride + (size_t)xb] - holes[(size_t)ya * stride + (size_t)xb] -
                                holes[(size_t)yb * stride + (size_t)xa] + holes[(size_t)ya * stride + (size_t)xa]
                          : 1;
      valid->px[(size_t)y * (size_t)w + (size_t)x] = n == 0;
    }
  free(holes);
  return 0;
}
