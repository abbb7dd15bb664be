/* neigh.h - multi-scale block neighbourhoods as feature vectors (seed 002
 * §3.3.2, Table 3.1, §3.4, §3.6.1).
 *
 * A block of W_B x W_B pixels is described by its neighbourhood: the fine
 * part, W_N x W_N pixels around the block at level l without the block
 * itself, and the coarse part, the full W_C x W_C square around the matching
 * position at level l+1 (W_C = smallest odd >= W_N/2; none at the coarsest
 * level). Full synthesis uses the causal L-shaped fine part: the
 * (W_N-W_B)/2 rows above the block across the whole window width and the
 * (W_N-W_B)/2 columns left of it in the block rows (the seed leaves the
 * shape open for W_B > 1; this is the digest's reading). The square shape
 * is the whole W_N x W_N window, block included, for masked queries (the
 * variable mask of §3.2.6 picks the pixels that count).
 *
 * Vector layout: [fine part, plane by plane | zero pad to 8 bytes]
 * [coarse part, plane by plane | zero pad to 8 bytes], so the L1 kernels see
 * fine and coarse as separate chunks and weight them (l1.h). Worker and
 * coordinator build identical vectors from the same planes and geometry, so
 * only images and parameters travel, never vectors. */
#ifndef TS_NEIGH_H
#define TS_NEIGH_H

#include <stdint.h>

#include "l1.h"
#include "plane.h"

#define TS_MAX_PLANES 4
#define TS_MAX_WN 41

typedef enum { TS_SHAPE_CAUSAL = 0, TS_SHAPE_SQUARE = 1 } ts_shape_kind;

typedef struct {
  int wn, wb, wc; /* fine window, block and coarse window widths; wc 0 = none */
  ts_shape_kind kind;
  int nplanes;
  int nfine_px, ncoarse_px; /* pixels per plane in each part */
  int16_t *fine_dx, *fine_dy; /* fine offsets from the block's top-left */
  uint32_t nchunks, nfine_chunks;
  uint32_t wfine, wcoarse; /* integer weights of the two parts */
  double coarse_weight;     /* the lambda they came from (remote rebuilds) */
} ts_shape;

/* Coarse window width for a fine window width (Table 3.1). */
int ts_coarse_width(int wn);

/* Builds a shape. coarse_weight is the user's lambda: the coarse distance is
 * weighted by lambda * (fine pixels / coarse pixels), i.e. by area at 1.0
 * (seed §3.3.2). has_coarse 0 at the coarsest level. */
int ts_shape_init(ts_shape *s, ts_shape_kind kind, int wn, int wb,
                  int has_coarse, int nplanes, double coarse_weight,
                  char *err);
void ts_shape_free(ts_shape *s);
static inline uint32_t ts_shape_bytes(const ts_shape *s) {
  return s->nchunks * TS_L1_CHUNK;
}

/* Valid reference block positions at one level and their global order.
 * A position is valid when the whole W_N window lies in the reference level
 * and the coarse window in the next coarser one (§3.2.3). With parity
 * control (§3.3.3) the positions split into four classes by (x&1, y&1),
 * stored class after class; global index = class base + row-major rank. */
typedef struct {
  int w, h;           /* reference level size */
  int x0, y0, nx, ny; /* valid top-left corners: x0..x0+nx-1, y0..y0+ny-1 */
  int parity;
  int nclass;
  uint32_t count[4];
  uint32_t base[4];
  uint32_t total;
} ts_refgrid;

int ts_refgrid_init(ts_refgrid *g, const ts_shape *s, int w, int h, int cw,
                    int ch, int parity, char *err);
/* Class of a block at (x, y): of a reference or a synthesis position. */
static inline int ts_refgrid_class(const ts_refgrid *g, int x, int y) {
  return g->parity ? ((x & 1) | ((y & 1) << 1)) : 0;
}
/* Position of the i-th vector of class c. */
void ts_refgrid_pos(const ts_refgrid *g, int c, uint32_t i, int *x, int *y);
/* Global index of the valid position (x, y), or -1. */
int64_t ts_refgrid_index(const ts_refgrid *g, int x, int y);
/* Class and in-class rank of a global index. */
void ts_refgrid_split(const ts_refgrid *g, uint32_t global, int *c,
                      uint32_t *i);

/* Rows that vectors [i0, i1) of class c read (i1 > i0): fine rows
 * [*fy0, *fy1) of the level, coarse rows [*cy0, *cy1) of the coarser one
 * (0, 0 without a coarse part). A worker needs only these rows. */
void ts_refgrid_rows(const ts_shape *s, const ts_refgrid *g, int c,
                     uint32_t i0, uint32_t i1, int *fy0, int *fy1, int *cy0,
                     int *cy1);

/* Planes at one level: the level itself and the next coarser one. */
typedef struct {
  int nplanes;
  const ts_plane *fine[TS_MAX_PLANES];
  const ts_plane *coarse[TS_MAX_PLANES]; /* unused without a coarse part */
} ts_levelplanes;

/* Reference vector of the block at (x, y) (a valid position). */
void ts_vec_ref(const ts_shape *s, const ts_levelplanes *ref, int x, int y,
                uint8_t *out);
/* Query vector of the synthesis block at (x, y) on the torus; the coarse
 * position is the block centre scaled to the coarse canvas. */
void ts_vec_query(const ts_shape *s, const ts_levelplanes *canvas, int x,
                  int y, uint8_t *out);

/* Builds vectors [i0, i1) of class c into a fresh set (its vector 0 is the
 * class's vector i0), with the shape's weights. */
int ts_vecset_build(const ts_shape *s, const ts_refgrid *g,
                    const ts_levelplanes *ref, int c, uint32_t i0,
                    uint32_t i1, ts_l1_set *out);

#endif
