/* stylit_input.h - a stylization's inputs as the 8-bit planes it searches
 * and votes on (the conversions stylit.h documents), and the pieces of the
 * method that the energy and apply-nnf reuse, so that they measure and
 * vote exactly as the engine does. */
#ifndef TS_STYLIT_INPUT_H
#define TS_STYLIT_INPUT_H

#include "plane.h"
#include "stylit.h"
#include "window.h"

#define TS_STYLIT_MAX_STYLE_CHANNELS 4

typedef struct {
  int nstyle;                        /* style colour planes, searched */
  int nguide[TS_STYLIT_MAX_GUIDES];  /* planes of each guide */
  int nplanes;                       /* nstyle + the guides' */
  /* Source: the style's colour planes, then each guide's source planes.
   * Target: the same order, planes 0..nstyle-1 left empty (the style
   * estimate goes there). */
  ts_plane src[TS_WIN_MAX_PLANES], tgt[TS_WIN_MAX_PLANES];
  int nvote;                                   /* style channels, all voted */
  ts_plane vote[TS_STYLIT_MAX_STYLE_CHANNELS]; /* every style channel, 8-bit */
} ts_stylit_planes;

/* The planes of checked inputs: 0 or TS_ENOMEM. */
int ts_stylit_planes_init(ts_stylit_planes *pl, const ts_stylit_params *p, const ts_image *const *in);
void ts_stylit_planes_free(ts_stylit_planes *pl);

/* The p x p window over pl's planes, anchored at a patch's top-left corner
 * (so the usage block of an anchor is its patch): one part for the style,
 * one per guide, each weighted by its weight per channel. */
int ts_stylit_window(ts_window *win, const ts_stylit_params *p, const ts_stylit_planes *pl, char *err);
/* The query image: n planes of one size with r pixels of border, each the
 * nearest edge pixel, so the patch of every pixel lies inside it; the
 * patch of pixel (x, y) is the window at (x, y). 0 or TS_ENOMEM (the
 * caller frees pad[0..n-1] either way). */
int ts_stylit_pad(const ts_plane *const *t, int n, int r, ts_plane *pad);
/* counts (ncounts, sw wide) = per source pixel, the patches of radius r
 * centred on the n NNF entries (x, y pairs) that cover it. */
void ts_stylit_occurrences(const uint32_t *nnf, size_t n, int r, int sw, uint32_t *counts, size_t ncounts);
/* out[c] (tw x th) = the rounded mean of what the patches covering each
 * pixel bring from src[c] (whose centres the NNF gives), for n planes. */
void ts_stylit_vote(const uint32_t *nnf, int tw, int th, int r, const ts_plane *src, int n, uint8_t *const *out);

#endif
