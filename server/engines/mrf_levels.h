/* mrf_levels.h - what mrf.c offers the MRF engine's other files. */
#ifndef TS_MRF_LEVELS_H
#define TS_MRF_LEVELS_H

#include "mrf_state.h"

/* Feature planes of a reference with `channels` (luma, or the colours). */
int mrf_nplanes_for(const ts_mrf_params *p, int channels);
/* Sizes of `levels` levels from w x h, halving (rounding up with ceil_mode). */
void mrf_level_sizes(int w, int h, int levels, int *lw, int *lh, int ceil_mode);
int mrf_build_reference(engine *e, const ts_image *ref, int levels, ts_plane pyr[][TS_MRF_MAX_LEVELS]);
/* Which levels use partitioned sets: 0, or TS_ENOMEM. */
int mrf_lbg_decide(engine *e);
/* Runs levels `from` down to `to`, the first from `inside` when that is a
 * checkpoint taken inside it. */
int mrf_run_levels(engine *e, int from, int to, const ts_mrf_checkpoint *inside, char *err);
/* Frees the state of the level above before a level starts. */
void mrf_drop_previous_level(engine *e);
/* After a level but the output's: its checkpoint, and a stop if asked. */
int mrf_level_end(engine *e, int l, char *err);
int mrf_gather_output(engine *e, const ts_image *ref, ts_mrf_result *res, char *err);
void mrf_engine_free(engine *e);

#endif
