/* mrf_plan.h - a level's work as one sequence of steps (mrf_plan.c). */
#ifndef TS_MRF_PLAN_H
#define TS_MRF_PLAN_H

#include "mrf_state.h"

/* The blocks a level of w x h searches in all: scan and sweeps. */
uint64_t mrf_level_blocks(const ts_mrf_params *p, int l, int w, int h);
/* Level l's plan: 0, or TS_ENOMEM. */
int mrf_plan_level(level_plan *pl, const ts_mrf_params *p, int l, int w, int h);
void mrf_plan_free(level_plan *pl);
/* Calls fn on every block of the plan's first `steps` steps. */
void mrf_plan_walk(const level_plan *pl, uint64_t steps, void (*fn)(void *ctx, const ts_block *b), void *ctx);

#endif
