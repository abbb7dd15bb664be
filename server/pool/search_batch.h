/* search_batch.h - query batches over the pool (search_batch.c): sent to
 * every worker holding a slice, the answers merged into the exact global
 * best, the slicing rebalanced when the measured rates drift. */
#ifndef TS_SEARCH_BATCH_H
#define TS_SEARCH_BATCH_H

#include "search_state.h"

/* search.h's query and query_many. */
int cl_query_many(ts_search *s, const ts_search_req *req, uint32_t nreq, char *err);
int cl_query(ts_search *s, int id, const ts_query_batch *b, ts_l1_best *out, char *err);

#endif
