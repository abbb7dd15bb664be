/* segment_post.h - the pieces of a segmentation after the search
 * (segment_post.c): level weights, fusion, upsampling, regions, noise
 * reduction and accuracy counts. */
#ifndef TS_SEGMENT_POST_H
#define TS_SEGMENT_POST_H

#include <stddef.h>
#include <stdint.h>

#include "segment_input.h"

/* ---- the pieces after the search (segment_post.c) ----------------------
 *
 * Class maps are bytes (class indices), row-major. */

/* The level-l pixel nearest to level-0 coordinate x0 on a level of n
 * pixels: round(x0 / 2^l), clamped. */
static inline int ts_seg_nearest(int x0, int l, int n) {
  int x = l > 0 ? (x0 + (1 << (l - 1))) >> l : x0;
  return x < n ? x : n - 1;
}

/* rate and weight (levels x nclass, level-major) from the self-segmentation
 * counts: rate = correct / total (-1 where total is 0: no pixel of the
 * class at that level), weight = rate / sum over levels of the rates
 * (missing rates as 0; all levels equal when that sum is 0). */
void ts_seg_weights(int levels, int nclass, const uint64_t *correct, const uint64_t *total, double *rate,
                    double *weight);
/* out (w x h) = the weighted vote of the levels' maps lab[l] (lw[l] x
 * lh[l]), weights as ts_seg_weights makes them; ties to the lower class. */
void ts_seg_fuse(int levels, int nclass, const uint8_t *const *lab, const int *lw, const int *lh, const double *weight,
                 int w, int h, uint8_t *out);
/* out (w x h) = level l's map (lw x lh) at level 0, nearest pixel. */
void ts_seg_upsample(const uint8_t *lab, int lw, int lh, int l, int w, int h, uint8_t *out);

/* 4-connected regions of equal class: comp[i] = the region of pixel i,
 * regions numbered in the raster order of their first pixel; *n their
 * count. 0 or TS_ENOMEM. */
int ts_seg_components(const uint8_t *lab, int w, int h, uint32_t *comp, uint32_t *n);

typedef struct {
  uint32_t merged; /* regions given to a neighbour */
  uint32_t passes;
} ts_seg_denoise_stats;

/* Noise reduction in place: regions (as above) of fewer than min_area
 * pixels take the class their border touches most. A pass numbers the
 * regions, then takes the small ones smallest first (ties: the first in
 * raster order); a region next to one already changed in this pass waits
 * for the next (its size or its border may have changed), so every change
 * sees exact regions. Each change joins a region to a neighbour, so the
 * passes end; a region with no border (the whole image) stays. 0 or
 * TS_ENOMEM. */
int ts_seg_denoise(uint8_t *lab, int w, int h, uint32_t min_area, ts_seg_denoise_stats *st);

/* Per class: pixels[k] += truth pixels of class k, correct[k] += those pred
 * labels k too (n pixels). */
void ts_seg_count(const uint8_t *pred, const uint8_t *truth, size_t n, uint64_t *pixels, uint64_t *correct);

#endif
