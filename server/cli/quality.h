/* quality.h - objective checks of a synthesis result.
 *
 * Neighbourhood error: for sampled pixels of an image (read on the torus,
 * as the output tiles), the exact best-match L1 distance of the W x W
 * window around the pixel to every window of the reference, per pixel in
 * grey levels. Windows that straddle the image border (the seam of a 2x2
 * tiling) are reported apart from inner ones, so a seam shows up as a larger
 * error there. The searches go through the search interface, exhaustively.
 *
 * Block shuffle: the baseline a synthesis must beat - an image tiled with
 * reference blocks at random positions. */
#ifndef TS_QUALITY_H
#define TS_QUALITY_H

#include <stdint.h>

#include "plane.h"
#include "search.h"

typedef struct {
  double mean_inner, mean_seam; /* grey levels per window pixel */
  uint32_t n_inner, n_seam;
} ts_quality;

/* samples: inner windows drawn at random, and at most that many seam
 * windows (evenly spaced along the border). */
int ts_quality_measure(ts_search *search, const ts_plane *ref,
                       const ts_plane *img, int wn, uint32_t samples,
                       uint64_t seed, ts_quality *q, char *err);

/* dst (allocated w x h, 1 plane) tiled with random bs x bs blocks of src. */
int ts_shuffle_blocks(const ts_plane *src, int w, int h, int bs, uint64_t seed,
                      uint32_t *copy_map);

#endif
