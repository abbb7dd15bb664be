/* search_cluster.c - the search backend over the coordinator's pool (see
 * cluster.h): every reference set cut into one slice per worker in
 * proportion to its rate, batches sent to every worker holding a slice,
 * answers merged into the exact global best. This is its face, search.h's
 * operations; search_state.h lists the files that do the work. */
#include <pthread.h>
#include <stdlib.h>

#include "calib.h"
#include "error.h"
#include "search_batch.h"
#include "search_field.h"
#include "search_replica.h"
#include "search_sets.h"

static void cluster_destroy(ts_search *s) {
  cluster_search *cs = (cluster_search *)s;
  for (int i = 0; i < CL_MAX_SETS; i++) cl_set_release(s, i);
  for (int i = 0; i < CL_MAX_IMAGES; i++) cl_image_close(s, i);
  ts_query_scratch_free(&cs->scratch);
  free(cs->best);
  free(cs->ws);
  free(cs);
}

/* The pool's calibrated rate: the ready workers' summed (each measured
 * when it joined), or with none the coordinator's own threads' (measured
 * once, when first asked). */
static double cluster_rate(ts_search *s) {
  ts_cluster *c = ((cluster_search *)s)->c;
  double rate = 0;
  uint64_t pairs, nanos;
  pthread_mutex_lock(&c->lock);
  for (int i = 0; i < c->nw; i++)
    if (c->w[i]->state == TS_WORKER_READY) rate += c->w[i]->calib_rate;
  if (rate == 0 && c->local_rate == 0 && ts_calib_run(c->local_pool, c->simd, CL_LOCAL_CALIB_MILLIS, &pairs, &nanos) == 0)
    c->local_rate = ts_calib_bytes_per_second(pairs, nanos);
  if (rate == 0) rate = c->local_rate;
  pthread_mutex_unlock(&c->lock);
  return rate;
}

static int cluster_session(ts_search *s, ts_search **out, char *err);

static const ts_search_ops cluster_ops = {
    .name = "cluster",
    .prepare = cl_set_prepare,
    .image_open = cl_image_open,
    .image_next = cl_image_next,
    .place = cl_image_place,
    .image_close = cl_image_close,
    .query = cl_query,
    .query_many = cl_query_many,
    .field_pass = cl_field_pass,
    .rate = cluster_rate,
    .release = cl_set_release,
    .destroy = cluster_destroy,
    .session = cluster_session,
};

/* Another search on the pool, as a concurrent job's is: batches lease
 * their workers (cluster_impl.h), so sessions take turns on each
 * connection, and their images and sets are their own. */
static int cluster_session(ts_search *s, ts_search **out, char *err) {
  cluster_search *cs = (cluster_search *)s;
  return ts_search_cluster_create(out, cs->c, cs->cancel, err);
}

int ts_search_cluster_create(ts_search **out, ts_cluster *c, const atomic_int *cancel, char *err) {
  cluster_search *cs = calloc(1, sizeof(*cs));
  if (cs == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  cs->ws = cl_worker_list(c);
  if (cs->ws == NULL) {
    free(cs);
    return ts_error(err, TS_ENOMEM, "out of memory");
  }
  cs->base.ops = &cluster_ops;
  cs->base.simd = c->simd;
  cs->c = c;
  cs->cancel = cancel;
  *out = &cs->base;
  return 0;
}
