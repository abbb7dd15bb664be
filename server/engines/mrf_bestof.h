/* mrf_bestof.h - passive usage-variance optimisation (seed 002 §3.7.1,
 * mrf_bestof.c): best-of candidate seeds through the coarse levels. */
#ifndef TS_MRF_BESTOF_H
#define TS_MRF_BESTOF_H

#include "mrf_state.h"

/* The work of one candidate down to level `last`, for the progress bar. */
double mrf_candidate_work(const engine *e, int last);
/* Runs the candidates and leaves the engine as the chosen one left the
 * last of their levels; the next level to run in *next. */
int mrf_choose_candidate(engine *e, int *next, char *err);

#endif
