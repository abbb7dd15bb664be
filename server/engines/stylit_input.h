/* stylit_input.h - a stylization's inputs as the 8-bit planes it searches
 * and votes on (the conversions stylit.h documents), and the pieces of the
 * method that the energy and apply-nnf reuse, so that they measure and
 * vote exactly as the engine does. */
#ifndef TS_STYLIT_INPUT_H
#define TS_STYLIT_INPUT_H

#include "image.h"
#include "plane.h"
#include "stylit_params.h"
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

/* Every problem with the parameters and inputs (sizes, channels, ranges,
 * the pyramid against the patch), one per line: 0 or TS_EINVAL. */
int ts_stylit_check(const ts_stylit_params *p, const ts_image *const *in, char *msg, size_t len);
/* The levels a job runs: p->levels, or when 0 the most (up to 6) that
 * leave the coarsest source and target at least 4 patches on each side
 * (at least 1). */
int ts_stylit_levels(const ts_stylit_params *p, const ts_image *const *in);

#endif
