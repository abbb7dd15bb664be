/* search_sets.h - reference sets over the pool (search_sets.c): every
 * set cut into one slice per ready worker in proportion to its rate. */
#ifndef TS_SEARCH_SETS_H
#define TS_SEARCH_SETS_H

#include "search_state.h"

/* search.h's prepare and release. */
int cl_set_prepare(ts_search *s, const ts_refset *rs, int *id, char *err);
void cl_set_release(ts_search *s, int id);
/* Makes the set's slicing match the current pool (lock held). */
int cl_ensure_slices(cluster_search *cs, cl_set *st, char *err);

#endif
