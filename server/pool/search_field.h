/* search_field.h - PatchMatch field sets over the pool (search_field.c). */
#ifndef TS_SEARCH_FIELD_H
#define TS_SEARCH_FIELD_H

#include "search_state.h"

/* A field set prepared, a pass (search.h's field_pass), a field set freed. */
int cl_field_prepare(cluster_search *cs, cl_set *st, char *err);
int cl_field_pass(ts_search *s, const ts_field_pass *fp, char *err);
void cl_field_clear(cluster_search *cs, cl_set *st);

#endif
