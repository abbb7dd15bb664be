/* neigh.h - the MRF engine's multi-scale block neighbourhoods (seed 002
 * §3.3.2, Table 3.1, §3.4, §3.6.1) as search windows (window.h).
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
 * variable mask of §3.2.6 picks the pixels that count: its known offsets,
 * window.h, are the L, which always counts).
 *
 * As a window: two parts, the fine offsets of every plane and the coarse
 * square of every plane, weighted so that the coarse distance counts
 * lambda * (fine pixels / coarse pixels) as much as the fine one. Both
 * shapes have the square's extents, so they share one set of anchors: the
 * top-left corners of the blocks whose whole W_N window lies in the level
 * (§3.2.3). */
#ifndef TS_NEIGH_H
#define TS_NEIGH_H

#include "window.h"

#define TS_MAX_PLANES 4 /* the MRF's feature planes: luminance, or RGB */
#define TS_MAX_WN 41

/* CAUSAL: the L (full synthesis scans); SQUARE: the whole window, the L
 * always counting (masked queries of full synthesis); FREE: the whole
 * window with no offset always counting - constrained synthesis, where the
 * variable mask of §3.2.6 (the pixel states, window.h) decides every one. */
typedef enum { TS_SHAPE_CAUSAL = 0, TS_SHAPE_SQUARE = 1, TS_SHAPE_FREE = 2 } ts_shape_kind;

/* Coarse window width for a fine window width (Table 3.1). */
int ts_coarse_width(int wn);

/* The neighbourhood window of a shape. coarse_weight is the user's lambda:
 * the coarse distance is weighted by lambda * (fine pixels / coarse
 * pixels), i.e. by area at 1.0 (seed §3.3.2). has_coarse 0 at the coarsest
 * level. */
int ts_neigh_window(ts_window *w, ts_shape_kind kind, int wn, int wb, int has_coarse, int nplanes,
                    double coarse_weight, char *err);

#endif
