/* search_local.c - the local backend of the search interface: each set is
 * one slice holding every vector (common/search/slice.c, the code workers scan
 * with), scanned by a thread pool on this machine. */
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "error.h"
#include "util.h"
#include "pool.h"
#include "search.h"
#include "slice.h"

#define LOCAL_MAX_SETS 8
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
  int inline_small; /* 0: every batch goes through the pool (tests) */
  ts_slice *sets[LOCAL_MAX_SETS];
  uint32_t count[LOCAL_MAX_SETS][TS_MAX_CLASSES];
} local_search;


static int local_prepare(ts_search *s, const ts_refset *rs, int *id, char *err) {
  local_search *ls = (local_search *)s;
  int slot = 0;
  while (slot < LOCAL_MAX_SETS && ls->sets[slot] != NULL) slot++;
  if (slot == LOCAL_MAX_SETS) return ts_error(err, TS_ENOMEM, "too many reference sets prepared at once");
  static const uint32_t i0[TS_MAX_CLASSES] = {0};
  ts_slice_desc m;
  ts_slice_describe(&m, rs, rs->counts, (uint32_t)slot, 0, i0, rs->anchors->count);
  int rc = ts_slice_load(&ls->sets[slot], &m, ls->pool, err);
  if (rc != 0) return rc;
  memcpy(ls->count[slot], rs->anchors->count, sizeof(ls->count[slot]));
  *id = slot;
  return 0;
}

static ts_slice *set_get(local_search *ls, int id) {
  return id >= 0 && id < LOCAL_MAX_SETS ? ls->sets[id] : NULL;
}

static int local_commit(ts_search *s, int id, const ts_commit *c, uint32_t n, char *err) {
  ts_slice *sl = set_get((local_search *)s, id);
  if (sl == NULL) return ts_error(err, TS_EINVAL, "unknown reference set %d", id);
  return ts_slice_commit(sl, c, n, err);
}

static int local_query(ts_search *s, int id, const ts_query_batch *b, ts_l1_best *out, char *err) {
  local_search *ls = (local_search *)s;
  ts_slice *sl = set_get(ls, id);
  if (sl == NULL) return ts_error(err, TS_EINVAL, "unknown reference set %d", id);
  if (b->nq == 0) return 0;
  /* A small batch costs less than waking the pool: scan it on this thread. */
  uint64_t expect = 0;
  for (uint32_t i = 0; i < b->nq; i++) expect += ls->count[id][b->klass ? b->klass[i] : 0];
  uint64_t limit = ls->inline_small ? inline_threshold(s->simd, ts_slice_vbytes(sl)) : 0;
  uint64_t pairs;
  double t0 = ts_now();
  int rc = ts_slice_scan(sl, ls->pool, expect < limit ? 1 : 0, s->simd, b, out, &pairs, err);
  s->stats.scan_seconds += ts_now() - t0;
  if (rc != 0) return rc;
  s->stats.pairs += pairs;
  s->stats.batches++;
  s->stats.queries += b->nq;
  return 0;
}

static void local_release(ts_search *s, int id) {
  local_search *ls = (local_search *)s;
  if (set_get(ls, id) == NULL) return;
  ts_slice_free(ls->sets[id]);
  ls->sets[id] = NULL;
}

static void local_destroy(ts_search *s) {
  local_search *ls = (local_search *)s;
  for (int i = 0; i < LOCAL_MAX_SETS; i++) ts_slice_free(ls->sets[i]);
  ts_pool_destroy(ls->pool);
  free(ls);
}

static const ts_search_ops local_ops = {
    .name = "local",
    .prepare = local_prepare,
    .commit = local_commit,
    .query = local_query,
    .release = local_release,
    .destroy = local_destroy,
};

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
  ls->inline_small = 1;
  *out = &ls->base;
  return 0;
}
