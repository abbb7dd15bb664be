/* search.h - the one interface the engines use to find best matches.
 *
 * An engine prepares a reference set (the planes, shape and grid of one
 * pyramid level: everything needed to build the vectors, never the vectors
 * themselves, so a remote backend ships images, not hundreds of MB), then
 * asks batches of queries against it. Batch composition and order belong to
 * the engine; a backend returns, for every query, the exact global minimum
 * with ties to the lowest global index, so results never depend on the
 * backend, its thread count or how it slices the set.
 *
 * Backends: local (a thread pool on this machine, search_local.c); the
 * cluster backend implements the same operations over the network. */
#ifndef TS_SEARCH_H
#define TS_SEARCH_H

#include <stdint.h>

#include "anchors.h"
#include "l1.h"
#include "usage.h"
#include "window.h"

/* What a backend needs to build a reference vector set: the feature set
 * (window, anchors, planes; the label and validity planes the anchors were
 * made from). The pointed-to data must stay alive until the set is
 * released. */
typedef struct {
  const ts_window *window;
  const ts_anchors *anchors;
  const ts_levelplanes *ref;
  const ts_plane *labels, *valid; /* NULL: none */
  int usage; /* batches will carry a usage penalty: keep usage replicas */
  /* Where the replicas start (read during prepare only): the counts a
   * level resumed mid-way had at its checkpoint. NULL: all zero. */
  const ts_usage *counts;
} ts_refset;

/* Source blocks copied since the last batch: feeds the backend's replica of
 * the usage counters (usage.h). */
typedef struct {
  int32_t x, y;  /* reference level coordinates of the copied pixels */
  uint16_t w, h; /* copied size (blocks at the canvas edge are clipped) */
  int32_t delta; /* +1 copied, -1 replaced by a refinement sweep */
} ts_commit;

typedef struct {
  uint32_t nq;
  const uint8_t *queries; /* nq vectors of ts_window_bytes(window) bytes */
  const uint8_t *masks;   /* NULL, or nq masks laid out like queries */
  const uint8_t *klass;   /* class of each query (anchors.h); NULL = all 0 */
  uint64_t usage_k;       /* penalty factor (usage.h); 0 = no penalty */
} ts_query_batch;

typedef struct {
  uint64_t batches, queries;
  uint64_t pairs; /* query-vector comparisons */
  double scan_seconds;
  /* Remote backends: payload bytes sent and received, and round trips
   * (one per query or query_many call, however many workers answer). */
  uint64_t bytes_out, bytes_in, round_trips;
} ts_search_stats;

/* One batch of a ts_search_query_many call. */
typedef struct {
  int id;              /* set */
  ts_query_batch b;
  ts_l1_best *out;     /* b.nq results */
} ts_search_req;

typedef struct ts_search ts_search;

typedef struct {
  const char *name;
  /* Builds a set; *id identifies it in later calls. */
  int (*prepare)(ts_search *s, const ts_refset *set, int *id, char *err);
  /* Records copied blocks in the set's usage replica (a no-op for a set
   * prepared without usage). */
  int (*commit)(ts_search *s, int id, const ts_commit *c, uint32_t n,
                char *err);
  /* Answers a batch: out[i] = best match of query i, global index. */
  int (*query)(ts_search *s, int id, const ts_query_batch *b, ts_l1_best *out,
               char *err);
  /* Optional: answers independent batches (no commit between them) at
   * once - a remote backend in one round trip. NULL = one query each. */
  int (*query_many)(ts_search *s, const ts_search_req *r, uint32_t n, char *err);
  void (*release)(ts_search *s, int id);
  void (*destroy)(ts_search *s);
} ts_search_ops;

struct ts_search {
  const ts_search_ops *ops;
  const ts_l1_impl *simd; /* kernel variant in use (for reports) */
  ts_search_stats stats;
};

static inline int ts_search_prepare(ts_search *s, const ts_refset *set,
                                    int *id, char *err) {
  return s->ops->prepare(s, set, id, err);
}
static inline int ts_search_commit(ts_search *s, int id, const ts_commit *c,
                                   uint32_t n, char *err) {
  return s->ops->commit(s, id, c, n, err);
}
static inline int ts_search_query(ts_search *s, int id,
                                  const ts_query_batch *b, ts_l1_best *out,
                                  char *err) {
  return s->ops->query(s, id, b, out, err);
}
static inline int ts_search_query_many(ts_search *s, const ts_search_req *r,
                                       uint32_t n, char *err) {
  if (s->ops->query_many != NULL) return s->ops->query_many(s, r, n, err);
  for (uint32_t i = 0; i < n; i++) {
    int rc = s->ops->query(s, r[i].id, &r[i].b, r[i].out, err);
    if (rc != 0) return rc;
  }
  return 0;
}
static inline void ts_search_release(ts_search *s, int id) {
  s->ops->release(s, id);
}
static inline void ts_search_destroy(ts_search *s) {
  if (s != NULL) s->ops->destroy(s);
}

/* Local backend on nthreads threads (>= 1) with the given kernel variant
 * (NULL = ts_l1_select). */
int ts_search_local_create(ts_search **out, int nthreads,
                           const ts_l1_impl *simd, char *err);
/* Small batches (about 0.2 ms of work) run on the calling thread unless
 * disabled (tests disable it to drive every batch through the pool). */
void ts_search_local_set_inline(ts_search *s, int enabled);

#endif
