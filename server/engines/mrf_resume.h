/* mrf_resume.h - a synthesis resumed from a checkpoint (mrf_resume.c). */
#ifndef TS_MRF_RESUME_H
#define TS_MRF_RESUME_H

#include "mrf_state.h"

/* Goes on from hooks->resume when it fits the job: *first is the level to
 * run first, and *inside the checkpoint to start it from when it was taken
 * inside that level. One that does not fit fails the synthesis, or, with a
 * `refused` hook, is reported and synthesis starts from noise. */
int mrf_take_resume(engine *e, int *first, const ts_mrf_checkpoint **inside, char *err);

#endif
