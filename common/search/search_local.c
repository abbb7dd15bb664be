/* search_local.c - the local backend of the search interface: each set is
 * one slice holding every vector (common/search/slice.c, the code workers scan
 * with), scanned by a thread pool on this machine; each query image is a
 * replica (replica.c) the query vectors are read from, as on a worker. */
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "calib.h"
#include "error.h"
#include "patchmatch.h"
#include "util.h"
#include "pool.h"
#include "replica.h"
#include "search.h"
#include "slice.h"

#define LOCAL_MAX_SETS 8
#define LOCAL_MAX_IMAGES 4
/* Below this many comparisons of 56-byte vectors with the AVX-512 kernel
 * (about 0.2 ms of one core) a batch is scanned on the calling thread
 * alone; the threshold shrinks with slower kernels and longer vectors. */
#define LOCAL_INLINE_PAIRS (1u << 19)

/* Rough speed of each kernel variant relative to scalar (bench/results). */
static const uint32_t kVariantSpeed[TS_SIMD_COUNT] = {1, 16, 24, 96, 192};

static uint64_t inline_threshold(const ts_l1_impl *simd, uint32_t vbytes) {
  return (uint64_t)LOCAL_INLINE_PAIRS * kVariantSpeed[simd->id] * 56 /
         (kVariantSpeed[TS_SIMD_AVX512] * (uint64_t)vbytes);
}

typedef struct {
  ts_search base;
  ts_pool *pool;
  int owns_pool; /* 0: a session's, the pool of the search it came from */
  int inline_small; /* 0: every batch goes through the pool (tests) */
  ts_slice *sets[LOCAL_MAX_SETS];
  /* PatchMatch sets, and the image (by generation) whose target each
   * holds packed. */
  ts_pm_field *fields[LOCAL_MAX_SETS];
  uint64_t field_gen[LOCAL_MAX_SETS];
  uint64_t image_gen[LOCAL_MAX_IMAGES], next_gen;
  uint32_t count[LOCAL_MAX_SETS][TS_MAX_CLASSES];
  ts_replica images[LOCAL_MAX_IMAGES];
  int image_used[LOCAL_MAX_IMAGES];
  ts_query_scratch scratch;
  double rate; /* calibrated on first asking, 0 before */
} local_search;

static ts_replica *image_get(local_search *ls, int id) {
  return id >= 0 && id < LOCAL_MAX_IMAGES && ls->image_used[id] ? &ls->images[id] : NULL;
}

static int local_image_open(ts_search *s, const ts_replica_desc *d, int *id, char *err) {
  local_search *ls = (local_search *)s;
  int slot = 0;
  while (slot < LOCAL_MAX_IMAGES && ls->image_used[slot]) slot++;
  if (slot == LOCAL_MAX_IMAGES) return ts_error(err, TS_ENOMEM, "too many query images open at once");
  int rc = ts_replica_init(&ls->images[slot], d, err);
  if (rc != 0) return rc;
  ls->image_used[slot] = 1;
  ls->image_gen[slot] = ++ls->next_gen;
  *id = slot;
  return 0;
}

static int local_image_next(ts_search *s, int id, int w, int h, int rw, int rh, const uint8_t *const *ref,
                            char *err) {
  ts_replica *r = image_get((local_search *)s, id);
  if (r == NULL) return ts_error(err, TS_EINVAL, "unknown query image %d", id);
  return ts_replica_next_level(r, w, h, rw, rh, ref, err);
}

static void local_image_close(ts_search *s, int id) {
  local_search *ls = (local_search *)s;
  ts_replica *r = image_get(ls, id);
  if (r == NULL) return;
  ts_replica_free(r);
  ls->image_used[id] = 0;
}

/* Placements change the image and, through their commits, the usage
 * replicas of every set that queries it. */
static int local_place(ts_search *s, int id, const ts_place *p, uint32_t n, char *err) {
  local_search *ls = (local_search *)s;
  ts_replica *r = image_get(ls, id);
  if (r == NULL) return ts_error(err, TS_EINVAL, "unknown query image %d", id);
  ts_commit *c = malloc(sizeof(ts_commit) * 2 * (n ? n : 1));
  if (c == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  uint32_t nc;
  int rc = ts_replica_place(r, p, n, c, &nc, err);
  for (int k = 0; rc == 0 && k < LOCAL_MAX_SETS; k++)
    if (ls->sets[k] != NULL && ts_slice_image(ls->sets[k]) == (uint32_t)id) rc = ts_slice_commit(ls->sets[k], c, nc, err);
  free(c);
  return rc;
}


static int prepare_field(local_search *ls, const ts_refset *rs, int slot, char *err) {
  ts_pm_field *f = calloc(1, sizeof(*f));
  if (f == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  int rc = ts_pm_field_init(f, rs->window, rs->ref->fine, ts_pool_size(ls->pool), err);
  if (rc != 0) {
    free(f);
    return rc;
  }
  ls->fields[slot] = f;
  ls->field_gen[slot] = 0;
  return 0;
}

static int local_prepare(ts_search *s, const ts_refset *rs, int *id, char *err) {
  local_search *ls = (local_search *)s;
  int slot = 0;
  while (slot < LOCAL_MAX_SETS && (ls->sets[slot] != NULL || ls->fields[slot] != NULL)) slot++;
  if (slot == LOCAL_MAX_SETS) return ts_error(err, TS_ENOMEM, "too many reference sets prepared at once");
  if (rs->field) {
    int rc = prepare_field(ls, rs, slot, err);
    if (rc == 0) *id = slot;
    return rc;
  }
  static const uint32_t i0[TS_MAX_CLASSES] = {0};
  if (image_get(ls, rs->image) == NULL) return ts_error(err, TS_EINVAL, "unknown query image %d", rs->image);
  /* A partitioned set: the codebook, then a slice of every vector loaded
   * with it as a worker's would be (the slice keeps a copy). */
  ts_lbg_codebook cb = {0};
  int rc = rs->lbg == NULL ? 0
                           : ts_lbg_build(&cb, rs->window, rs->anchors, rs->ref, rs->lbg, ls->pool, s->simd,
                                          rs->lbg_report, err);
  if (rc != 0) return rc;
  ts_slice_desc m;
  ts_slice_describe(&m, rs, rs->counts, (uint32_t)slot, 0, (uint32_t)rs->image, i0, rs->anchors->count, NULL);
  if (rs->lbg != NULL) ts_slice_describe_lbg(&m, &cb);
  rc = ts_slice_load(&ls->sets[slot], &m, NULL, ls->pool, err);
  ts_lbg_free(&cb);
  if (rc != 0) return rc;
  memcpy(ls->count[slot], rs->anchors->count, sizeof(ls->count[slot]));
  *id = slot;
  return 0;
}

static ts_slice *set_get(local_search *ls, int id) {
  return id >= 0 && id < LOCAL_MAX_SETS ? ls->sets[id] : NULL;
}

static int local_query(ts_search *s, int id, const ts_query_batch *b, ts_l1_best *out, char *err) {
  local_search *ls = (local_search *)s;
  ts_slice *sl = set_get(ls, id);
  if (sl == NULL) return ts_error(err, TS_EINVAL, "unknown reference set %d", id);
  if (b->nq == 0) return 0;
  /* A small batch costs less than waking the pool: scan it on this thread. */
  uint64_t expect = 0, full = 0;
  for (uint32_t i = 0; i < b->nq; i++) {
    int c = b->klass ? b->klass[i] : 0;
    full += ls->count[id][c];
    expect += ts_slice_query_cost(sl, c);
  }
  uint64_t limit = ls->inline_small ? inline_threshold(s->simd, ts_slice_vbytes(sl)) : 0;
  uint64_t pairs;
  double t0 = ts_now();
  ts_vec_batch vb;
  const ts_replica *r = image_get(ls, (int)ts_slice_image(sl));
  if (r == NULL) return ts_error(err, TS_EINVAL, "the query image of set %d is closed", id);
  int rc = ts_query_vectors(&ls->scratch, r, ts_slice_window(sl), b, &vb, err);
  if (rc == 0) rc = ts_slice_scan(sl, ls->pool, expect < limit ? 1 : 0, s->simd, &vb, out, &pairs, err);
  s->stats.scan_seconds += ts_now() - t0;
  if (rc != 0) return rc;
  s->stats.pairs += pairs;
  s->stats.full_pairs += full;
  s->stats.batches++;
  s->stats.queries += b->nq;
  return 0;
}

/* A pass over every tile on the pool; the target is packed once per
 * image opened. */
static int local_field_pass(ts_search *s, const ts_field_pass *fp, char *err) {
  local_search *ls = (local_search *)s;
  ts_pm_field *f = fp->set >= 0 && fp->set < LOCAL_MAX_SETS ? ls->fields[fp->set] : NULL;
  if (f == NULL) return ts_error(err, TS_EINVAL, "unknown patchmatch set %d", fp->set);
  const ts_replica *r = image_get(ls, fp->image);
  if (r == NULL) return ts_error(err, TS_EINVAL, "unknown query image %d", fp->image);
  double t0 = ts_now();
  int rc = 0;
  if (ls->field_gen[fp->set] != ls->image_gen[fp->image]) {
    const ts_plane *t[TS_WIN_MAX_PLANES];
    for (int k = 0; k < r->nplanes; k++) t[k] = &r->fine[k];
    rc = ts_pm_field_target(f, t, err);
    ls->field_gen[fp->set] = rc == 0 ? ls->image_gen[fp->image] : 0;
  }
  ts_pm_job j = {fp->tw, fp->th, fp->in, fp->usage_k, fp->seed, fp->pass, s->simd->id == TS_SIMD_SCALAR};
  if (rc == 0) rc = ts_pm_field_pass(f, &j, NULL, 0, ls->pool, fp->out, err);
  s->stats.scan_seconds += ts_now() - t0;
  if (rc == 0) {
    s->stats.batches++;
    s->stats.queries += (uint64_t)fp->tw * (uint64_t)fp->th;
  }
  return rc;
}

static void local_release(ts_search *s, int id) {
  local_search *ls = (local_search *)s;
  if (id >= 0 && id < LOCAL_MAX_SETS && ls->fields[id] != NULL) {
    ts_pm_field_free(ls->fields[id]);
    free(ls->fields[id]);
    ls->fields[id] = NULL;
  }
  if (set_get(ls, id) == NULL) return;
  ts_slice_free(ls->sets[id]);
  ls->sets[id] = NULL;
}

static void local_destroy(ts_search *s) {
  local_search *ls = (local_search *)s;
  for (int i = 0; i < LOCAL_MAX_SETS; i++) local_release(s, i);
  for (int i = 0; i < LOCAL_MAX_IMAGES; i++) ts_replica_free(&ls->images[i]);
  ts_query_scratch_free(&ls->scratch);
  if (ls->owns_pool) ts_pool_destroy(ls->pool);
  free(ls);
}

/* Calibrated once, when first asked (most jobs never ask). */
#define LOCAL_CALIB_MILLIS 50

static double local_rate(ts_search *s) {
  local_search *ls = (local_search *)s;
  uint64_t pairs, nanos;
  if (ls->rate == 0 && ts_calib_run(ls->pool, s->simd, LOCAL_CALIB_MILLIS, &pairs, &nanos) == 0)
    ls->rate = ts_calib_bytes_per_second(pairs, nanos);
  return ls->rate;
}

static int local_session(ts_search *s, ts_search **out, char *err);

static const ts_search_ops local_ops = {
    .name = "local",
    .prepare = local_prepare,
    .image_open = local_image_open,
    .image_next = local_image_next,
    .place = local_place,
    .image_close = local_image_close,
    .query = local_query,
    .field_pass = local_field_pass,
    .rate = local_rate,
    .release = local_release,
    .destroy = local_destroy,
    .session = local_session,
};

/* A session scans on the same threads: its sets and images are its own,
 * small batches run on its caller's thread, and the pool takes the big
 * ones of all sessions in turns (pool.h). */
static int local_session(ts_search *s, ts_search **out, char *err) {
  local_search *from = (local_search *)s, *ls = calloc(1, sizeof(*ls));
  *out = NULL;
  if (ls == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  ls->base.ops = &local_ops;
  ls->base.simd = s->simd;
  ls->pool = from->pool;
  ls->inline_small = from->inline_small;
  *out = &ls->base;
  return 0;
}

void ts_search_local_set_inline(ts_search *s, int enabled) { ((local_search *)s)->inline_small = enabled; }

int ts_search_local_create(ts_search **out, int nthreads, const ts_l1_impl *simd, char *err) {
  *out = NULL;
  if (nthreads < 1 || nthreads > 1024) return ts_error(err, TS_EINVAL, "--threads %d: need 1..1024", nthreads);
  if (simd == NULL) {
    int rc = ts_l1_select(&simd, err);
    if (rc != 0) return rc;
  }
  local_search *ls = calloc(1, sizeof(*ls));
  if (ls == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  int rc = ts_pool_create(&ls->pool, nthreads);
  if (rc != 0) {
    free(ls);
    return ts_error(err, rc, "cannot start %d search threads", nthreads);
  }
  ls->base.ops = &local_ops;
  ls->base.simd = simd;
  ls->owns_pool = 1;
  ls->inline_small = 1;
  *out = &ls->base;
  return 0;
}
