/* fill_seams.h - the seam cut after a fill (fill.h's seam_cut): where two
 * copies meet, the join moves to where they agree best.
 *
 * Block synthesis places W_B x W_B blocks side by side: each block's copy
 * matches its window, but the pixels on either side of a block edge come
 * from two places of the reference, and that edge shows (bench/
 * tile_seams.py: the mean difference across block edges 1.45x that of the
 * pixel pairs inside a block). Image quilting (Efros & Freeman 2001) lets
 * blocks overlap and cuts the overlap along the path of least error. Here
 * the overlap is had from the copy map: across a seam, each side's copy
 * goes on past the edge (the pixel of its source next to the one it
 * copied), so the up to `reach` pixels on either side of the edge may take
 * the other side's copy, and per seam the cut - one position per row of a
 * vertical seam, per column of a horizontal one - is the one of least cost
 * by dynamic programming. The cost of a pair of neighbours that ends up
 * from two copies is that of graph-cut textures (Kwatra et al. 2003): how
 * far each pixel's copy, gone on by one pixel, is from the other pixel; 0
 * where the copies continue each other.
 *
 * Pixels stay copies of reference pixels (the copy map stays true, colour
 * is still gathered through it); only work pixels change, each to a pixel
 * of its own class's reference that may be copied. Vertical seams are cut
 * left to right, then horizontal ones top to bottom, each against the
 * image as the cuts before it left it: a pure function of the fill's
 * result, computed on the coordinator, so the bytes stay those of any
 * backend. */
#ifndef TS_FILL_SEAMS_H
#define TS_FILL_SEAMS_H

#include <stdint.h>

#include "neigh.h"

#define TS_SEAM_MAX_REACH 3

/* A class's reference at level 0 (fill.c's atlas): its planes, the pixels
 * that may be copied, and the rows of each of its sources (a copy goes on
 * only inside its own source). */
typedef struct {
  int w, h;
  const uint8_t *planes[TS_MAX_PLANES];
  const uint8_t *usable;
  int nsrc;
  const int *y0, *h0;
} ts_seam_ref;

typedef struct {
  int w, h, nplanes;
  uint8_t *planes[TS_MAX_PLANES]; /* the image: changed where a pixel's copy is */
  uint32_t *copy;                 /* per pixel: the reference (x, y) it copies; changed */
  const uint8_t *cls;             /* per pixel: the class (1..) whose reference `copy` is in; 0: none */
  const uint8_t *movable;         /* per pixel: a work pixel, that the cut may change */
  const ts_seam_ref *ref;         /* ref[c - 1]: class c's */
  int reach;                      /* 1..TS_SEAM_MAX_REACH */
} ts_seam_image;

/* Cuts every seam of the image: 0, or TS_ENOMEM (the image unchanged
 * past the seams cut so far, all of them copies still). *moved counts the
 * pixels that took another copy. */
int ts_fill_cut_seams(ts_seam_image *im, uint64_t *moved);

#endif
