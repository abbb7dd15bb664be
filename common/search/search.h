/* search.h - the one interface the engines use to find best matches.
 *
 * An engine opens a query image (replica.h: the canvas it synthesises,
 * kept by the backend and changed by placements) and prepares a reference
 * set (the planes, shape and grid of one
 * pyramid level: everything needed to build the vectors, never the vectors
 * themselves, so a remote backend ships images, not hundreds of MB), then
 * asks batches of queries - positions in the image - against it. Batch composition and order belong to
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
#include "error.h"
#include "l1.h"
#include "lbg.h"
#include "usage.h"
#include "window.h"

/* What a backend needs to build a reference vector set: the feature set
 * (window, anchors, planes; the label and validity planes the anchors were
 * made from), and the query image its queries read (an id from
 * ts_search_image_open). The pointed-to data must stay alive until the set
 * is released. */
typedef struct {
  int image;
  const ts_window *window;
  const ts_anchors *anchors;
  const ts_levelplanes *ref;
  const ts_plane *labels, *valid; /* NULL: none */
  int usage; /* batches will carry a usage penalty: keep usage replicas */
  /* Where the replicas start (read during prepare only): the counts a
   * level resumed mid-way had at its checkpoint. NULL: all zero. */
  const ts_usage *counts;
  /* 1: a PatchMatch source (patchmatch.h): kept as planes, whole on every
   * holder, asked only field passes (the window a square over fine
   * planes; anchors, labels and usage unused). */
  int field;
  /* NULL: exhaustive search. Else the set is partitioned (lbg.h): the
   * backend builds the codebook from these parameters when it prepares
   * the set (a function of the set and p->seed, wherever it runs) and
   * answers each query from its probed partitions, or exactly with
   * p->exact. lbg_report (may be NULL) gets the build's figures. */
  const ts_lbg_params *lbg;
  ts_lbg_report *lbg_report;
} ts_refset;

/* A usage change: the w x h reference pixels at (x, y) were copied (+1),
 * or such a copy was replaced (-1). Placements on a query image make them
 * (replica.h); they feed the usage replicas of the sets the image queries. */
typedef struct {
  int32_t x, y;
  uint16_t w, h;
  int32_t delta;
} ts_commit;

/* A placed block: its top-left canvas pixel (y * w + x) and the reference
 * pixel it copies from (y * ref_w + x). */
typedef struct {
  uint32_t dst, src;
} ts_place;

/* The state a replica starts from, as pointers the caller keeps alive
 * during ts_replica_init. */
typedef struct {
  int w, h, nplanes; /* the level's image */
  int bounded;       /* 1: not a torus (window.h, ts_vec_query) */
  const uint8_t *fine[TS_WIN_MAX_PLANES];
  int cw, ch; /* coarse planes (nplanes of them), 0 x 0: none */
  const uint8_t *coarse[TS_WIN_MAX_PLANES];
  const uint8_t *done; /* pixel states TS_DONE_* (window.h); NULL: all FREE */
  /* Placements: the block side, the reference planes blocks copy from and
   * the copy map, x then y per pixel (NULL: the image keeps none, so it
   * has no next level and no block is placed twice). block 0: the image
   * takes none. */
  int block, rw, rh;
  const uint8_t *ref[TS_WIN_MAX_PLANES];
  const uint32_t *copy;
} ts_replica_desc;

typedef struct {
  uint32_t nq;
  const uint32_t *pos;  /* pixel (y * w + x) of each query in the set's image */
  int masked;           /* masks from the image's placed pixels (ts_vec_mask) */
  const uint8_t *klass; /* class of each query (anchors.h); NULL = all 0 */
  uint64_t usage_k;     /* penalty factor (usage.h); 0 = no penalty */
} ts_query_batch;

typedef struct {
  uint64_t batches, queries;
  uint64_t pairs; /* query-vector comparisons */
  /* The comparisons exhaustive search would have made: pairs but for
   * partitioned sets, which compare fewer (their centroids not counted). */
  uint64_t full_pairs;
  double scan_seconds;
  /* Remote backends: payload bytes sent and received, and round trips
   * (one per query or query_many call, however many workers answer). */
  uint64_t bytes_out, bytes_in, round_trips;
} ts_search_stats;

/* A PatchMatch pass (patchmatch.h) against a field set: the field of
 * query image `image` (tw x th patches, the image (tw + p - 1) x
 * (th + p - 1)) improved from in to out. usage_k: the penalty factor
 * (usage.h), the occurrences counted from in; 0: none. */
typedef struct {
  int set, image;
  int tw, th;
  const uint32_t *in;
  uint32_t *out;
  uint64_t usage_k;
  uint64_t seed;
  uint32_t pass;
} ts_field_pass;

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
  /* A query image: its initial state, then each level's (predicted from
   * the one before: replica.h), then the blocks placed on it, which also
   * reach the usage replicas of the sets that query it. */
  int (*image_open)(ts_search *s, const ts_replica_desc *d, int *id, char *err);
  int (*image_next)(ts_search *s, int id, int w, int h, int rw, int rh,
                    const uint8_t *const *ref, char *err);
  int (*place)(ts_search *s, int id, const ts_place *p, uint32_t n, char *err);
  void (*image_close)(ts_search *s, int id);
  /* Answers a batch: out[i] = best match of query i, global index. */
  int (*query)(ts_search *s, int id, const ts_query_batch *b, ts_l1_best *out,
               char *err);
  /* Optional: answers independent batches (no commit between them) at
   * once - a remote backend in one round trip. NULL = one query each. */
  int (*query_many)(ts_search *s, const ts_search_req *r, uint32_t n, char *err);
  /* Optional: a PatchMatch pass; NULL = the backend has none. */
  int (*field_pass)(ts_search *s, const ts_field_pass *fp, char *err);
  /* Optional: bytes of vectors the backend compares a second, from the
   * standard calibration (calib.h): what exact search costs on it. 0 or
   * NULL: unknown. */
  double (*rate)(ts_search *s);
  void (*release)(ts_search *s, int id);
  void (*destroy)(ts_search *s);
  /* Optional: a new search on the same backend (the same threads, the
   * same pool of workers) for another thread of the job to use at the
   * same time as s - its own images, sets and statistics, answers as
   * exact as s's. Destroyed before s. NULL: s serves one thread only. */
  int (*session)(ts_search *s, ts_search **out, char *err);
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
static inline int ts_search_image_open(ts_search *s, const ts_replica_desc *d,
                                       int *id, char *err) {
  return s->ops->image_open(s, d, id, err);
}
static inline int ts_search_image_next(ts_search *s, int id, int w, int h,
                                       int rw, int rh,
                                       const uint8_t *const *ref, char *err) {
  return s->ops->image_next(s, id, w, h, rw, rh, ref, err);
}
static inline int ts_search_place(ts_search *s, int id, const ts_place *p,
                                  uint32_t n, char *err) {
  return s->ops->place(s, id, p, n, err);
}
static inline void ts_search_image_close(ts_search *s, int id) {
  s->ops->image_close(s, id);
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
static inline int ts_search_field_pass(ts_search *s, const ts_field_pass *fp, char *err) {
  if (s->ops->field_pass == NULL) return ts_error(err, TS_ENOTSUP, "the %s search backend runs no patchmatch", s->ops->name);
  return s->ops->field_pass(s, fp, err);
}
static inline double ts_search_rate(ts_search *s) {
  return s->ops->rate != NULL ? s->ops->rate(s) : 0.0;
}
static inline void ts_search_release(ts_search *s, int id) {
  s->ops->release(s, id);
}
/* A search for another thread (ts_search_ops.session), or TS_ENOTSUP. */
static inline int ts_search_session(ts_search *s, ts_search **out, char *err) {
  *out = NULL;
  if (s->ops->session == NULL) return ts_error(err, TS_ENOTSUP, "the %s search backend serves one thread", s->ops->name);
  return s->ops->session(s, out, err);
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
