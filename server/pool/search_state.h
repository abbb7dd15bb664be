/* search_state.h - the cluster search backend's state, shared by its
 * files, each of which calls only into those listed above it:
 *
 *   search_replica.c  query images: the coordinator's replica, the workers'
 *   search_field.c    PatchMatch sources held whole, passes over tiles
 *   search_sets.c     reference sets sliced over the pool
 *   search_batch.c    query batches, answers merged, rebalancing
 *   search_cluster.c  the backend's face (search.h's operations) */
#ifndef TS_SEARCH_STATE_H
#define TS_SEARCH_STATE_H

#include "cluster_impl.h"
#include "patchmatch.h"
#include "replica.h"
#include "slice.h"
#include "usage.h"

typedef struct {
  cl_worker *w;
  uint32_t *i0, *i1; /* per class: into the set's ranges */
  ts_slice_held rows; /* what it holds once loaded */
} cl_slice;

/* A worker's loaded slice of a set: a re-slice keeps its rows, unless
 * the worker has freed its slices since (a drain). */
typedef struct {
  int worker; /* worker id */
  uint32_t unloads; /* its count of unloads when it loaded the slice */
  ts_slice_held rows;
} cl_held;

typedef struct {
  int used;
  uint32_t gid; /* set id on the wire, unique in the cluster */
  uint32_t gen; /* slicing generation */
  uint32_t image; /* its query image's id on the wire */
  ts_refset rs;
  const ts_anchors *grid;
  int with_usage;
  ts_usage usage; /* the coordinator's replica: the counts new slices get */
  uint64_t epoch; /* cluster epoch of the slicing below */
  int sliced;
  cl_slice *slices; /* one per worker holding a part (o.max_workers slots) */
  uint32_t *ranges; /* their class ranges: 2 * nclass per slot */
  int nslices;
  cl_held *held; /* the workers that loaded the last slicing (o.max_workers slots) */
  int nheld;
  int load_losses; /* loads of it that lost workers (cl_ensure_slices) */
  ts_slice *local; /* in-process slice when no worker is ready */
  /* A partitioned set's codebook (rs.lbg), built once when the set is
   * prepared; every slice of the set carries it. */
  ts_lbg_codebook lbg;
  /* What need not travel in its 'N' messages: the fine rows, when they
   * are the reference planes of its query image at image level
   * `image_level` (a worker holding the image has them); the labels,
   * when they repeat a tile (nonzero tile_w). */
  int fine_in_image;
  uint32_t image_level;
  uint8_t tile_w, tile_h, tile[TS_SLICE_MAX_TILE * TS_SLICE_MAX_TILE];
  /* A PatchMatch source (rs.field): held whole by the workers that hold
   * entry `source` of the cluster's sources, or by the coordinator's own
   * field when no worker is ready, whose target is of image local_image at
   * state local_seq. */
  int field;
  int source;
  ts_pm_field *local_field;
  uint32_t local_image;
  uint64_t local_seq;
} cl_set;

/* A query image (replica.h): the coordinator's replica, which new workers
 * are loaded from, and the placements made since the last exchange, which
 * the exchange's first frame to each worker carries. A worker holds the
 * replica's state when it came through every exchange that carried
 * placements since it was loaded: a worker that fails one is dropped, and
 * comes back under a new id, to be loaded again. (A rebalance reloads
 * nobody: the image does not depend on the slicing.) */
#define CL_MAX_IMAGES 4

typedef struct {
  int worker; /* worker id */
  uint64_t seq;
} cl_synced;

typedef struct {
  int used;
  uint32_t gid; /* image id on the wire */
  uint32_t level; /* levels it went through (image_next) */
  ts_replica rep; /* the state before `pending` */
  ts_place *pending;
  uint32_t npending, cap_pending;
  ts_commit *commits; /* scratch: the commits of applying pending */
  cl_synced *synced; /* workers holding rep's state (o.max_workers slots) */
  int nsynced;
} cl_image;

typedef struct {
  ts_search base;
  ts_cluster *c;
  const atomic_int *cancel; /* the job's: set by another thread */
  cl_set sets[CL_MAX_SETS];
  cl_image images[CL_MAX_IMAGES];
  ts_query_scratch scratch; /* query vectors when no worker is ready */
  cl_worker **ws; /* the workers of one request (lock held): o.max_workers slots */
  ts_l1_best *best;
  uint32_t cap_best;
} cluster_search;

static inline int cl_canceled(const cluster_search *cs) { return cs->cancel != NULL && atomic_load(cs->cancel); }

/* A query image or a set by its id, or NULL if there is none. */
static inline cl_image *cl_image_get(cluster_search *cs, int id) {
  if (id < 0 || id >= CL_MAX_IMAGES || !cs->images[id].used) return NULL;
  return &cs->images[id];
}

static inline cl_set *cl_set_get(cluster_search *cs, int id) {
  if (id < 0 || id >= CL_MAX_SETS || !cs->sets[id].used) return NULL;
  return &cs->sets[id];
}

#endif
