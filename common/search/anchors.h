/* anchors.h - the reference positions of a feature set, their classes and
 * their global order.
 *
 * An anchor (x, y) of a reference level is a reference vector when its
 * window's extents fit the level (and the coarser level, window.h) and, if
 * the set has a validity plane, that plane is non-zero at (x, y). With a
 * label plane, the label at (x, y) is the anchor's class (< nclass <= 256);
 * without, every anchor is of class 0. A query of class c is compared with
 * the vectors of class c only: the MRF's parity control (seed 002 §3.3.3)
 * is the label plane (x & 1) | (y & 1) << 1, a class map's land-use classes
 * are its labels, and a hole's edge is a validity plane
 * (ts_anchors_valid_from_mask).
 *
 * Global order: class after class; within a class, row-major. So global
 * index = base[class] + rank of the anchor among its class's anchors in
 * row-major order. Results are global indices, and ties go to the lowest.
 *
 * A worker holds only the anchor rows its slice needs: it is built from
 * those rows of the label and validity planes and, per class, the number of
 * that class's anchors in the rows above them (ts_anchors_init_rows). Sets
 * without labels or validity need none of that: their order is arithmetic. */
#ifndef TS_ANCHORS_H
#define TS_ANCHORS_H

#include <stdint.h>

#include "plane.h"
#include "window.h"

#define TS_MAX_CLASSES 256
#define TS_NOT_ANCHOR UINT32_MAX

typedef struct {
  int w, h;           /* level size */
  int x0, y0, nx, ny; /* box of the anchors whose extents fit */
  int nclass;
  uint32_t count[TS_MAX_CLASSES], base[TS_MAX_CLASSES], total;
  /* With labels or validity: the global index of every held anchor. */
  int indexed;
  int ay0, ay1;     /* anchor rows held, [ay0, ay1) within the box */
  uint32_t *index;  /* (ay1 - ay0) x nx, TS_NOT_ANCHOR where there is none */
  uint32_t *before; /* (ay1 - ay0) x nclass: class-c anchors above each held row */
  uint32_t *cell;   /* ts_anchors_init only: the index cell of every global
                       index, so an engine finds a result's position at once;
                       NULL in a worker's rows (they search the row) */
} ts_anchors;

/* All anchors of a level (w x h; coarser level cw x ch, 0 x 0 without a
 * coarse source). labels: NULL (nclass must be 1) or a w x h plane whose
 * values are below nclass at every anchor; valid: NULL or a w x h plane.
 * Refuses a level without anchors, or with more than 2^31, with a message
 * naming the window. */
int ts_anchors_init(ts_anchors *a, const ts_window *win, int w, int h, int cw, int ch, const ts_plane *labels,
                    int nclass, const ts_plane *valid, char *err);
/* A worker's anchors: rows [ay0, ay1) of the box, with the set's class
 * counts, those rows of the planes (w wide; NULL as above) and the class-c
 * anchors above row ay0 (above[c]; NULL without planes). Checks that the
 * rows hold no more anchors of a class than the counts allow. */
int ts_anchors_init_rows(ts_anchors *a, const ts_window *win, int w, int h, int cw, int ch, int nclass,
                         const uint32_t *count, int ay0, int ay1, const uint8_t *label_rows,
                         const uint8_t *valid_rows, const uint32_t *above, char *err);
void ts_anchors_free(ts_anchors *a);

/* Global index of the anchor at (x, y), or -1 (not an anchor, not held). */
int64_t ts_anchors_index(const ts_anchors *a, int x, int y);
/* Class of a global index (< total). */
int ts_anchors_class(const ts_anchors *a, uint32_t global);
/* Position of a held global index. */
void ts_anchors_pos(const ts_anchors *a, uint32_t global, int *x, int *y);
/* Class-c anchors in the rows above y (a held row, or ay1). */
uint32_t ts_anchors_above(const ts_anchors *a, int c, int y);
/* Anchor rows [*y0, *y1) of vectors [i0, i1) of class c (i1 > i0). */
void ts_anchors_rows(const ts_anchors *a, int c, uint32_t i0, uint32_t i1, int *y0, int *y1);
/* Plane rows the anchors of rows [ay0, ay1) read: fine [*fy0, *fy1), coarse
 * [*cy0, *cy1) (0, 0 without a coarse source). */
void ts_window_rows(const ts_window *win, int ay0, int ay1, int *fy0, int *fy1, int *cy0, int *cy1);

/* A validity plane from a mask of the defined area: non-zero at the anchors
 * whose fine extent lies wholly where mask is non-zero. 0 or TS_ENOMEM. */
int ts_anchors_valid_from_mask(const ts_plane *mask, const ts_box *extent, ts_plane *valid);

#endif
