/* search_local.c - the local backend of the search interface: every class
 * (parity) sub-set is cut into one contiguous slice of groups per thread;
 * each thread scans its slice for all queries of the batch (so each slice is
 * streamed once per batch, SMP as in seed 002 §3.6.3) and the per-thread
 * minima are merged with the lowest-index tie rule. */
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "error.h"
#include "pool.h"
#include "search.h"
#include "usage.h"

#define LOCAL_MAX_SETS 8
/* Below this many comparisons of 56-byte vectors with the AVX-512 kernel
 * (about 0.2 ms of one core) a batch is scanned on the calling thread
 * alone; the threshold shrinks with slower kernels and longer vectors. */
#define LOCAL_INLINE_PAIRS (1u << 19)

/* Rough speed of each kernel variant relative to scalar (bench/results). */
static const uint32_t kVariantSpeed[TS_SIMD_COUNT] = {1, 16, 24, 96, 192};

static uint64_t inline_threshold(const ts_l1_impl *simd, uint32_t nchunks) {
  return (uint64_t)LOCAL_INLINE_PAIRS * kVariantSpeed[simd->id] * 7 /
         (kVariantSpeed[TS_SIMD_AVX512] * (uint64_t)nchunks);
}

typedef struct {
  int used;
  ts_refgrid grid;
  ts_l1_set cls[4];
  uint32_t *penalty[4]; /* per class, indexed like the class set */
  ts_usage usage;
} local_set;

typedef struct {
  ts_search base;
  ts_pool *pool;
  int inline_small; /* 0: every batch goes through the pool (tests) */
  local_set sets[LOCAL_MAX_SETS];
  /* Per-batch scratch, grown on demand. */
  uint32_t cap_q, cap_bytes;
  uint8_t *qbuf, *mbuf;
  uint32_t *order;
  ts_l1_best *tbest; /* nthreads x cap_q */
  /* The batch being scanned (read by the pool workers). */
  const local_set *cur;
  uint32_t nq, qstart[5];
  uint32_t vbytes;
  uint64_t usage_k;
  int masked;
} local_search;

static double now_seconds(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void set_clear(local_set *st) {
  for (int c = 0; c < 4; c++) {
    if (st->cls[c].data != NULL) ts_l1_set_free(&st->cls[c]);
    free(st->penalty[c]);
  }
  ts_usage_free(&st->usage);
  memset(st, 0, sizeof(*st));
}

static int local_prepare(ts_search *s, const ts_refset *rs, int *id,
                         char *err) {
  local_search *ls = (local_search *)s;
  int slot = 0;
  while (slot < LOCAL_MAX_SETS && ls->sets[slot].used) slot++;
  if (slot == LOCAL_MAX_SETS)
    return ts_error(err, TS_ENOMEM, "too many reference sets prepared at once");
  local_set *st = &ls->sets[slot];
  memset(st, 0, sizeof(*st));
  st->grid = *rs->grid;
  int rc = rs->usage ? ts_usage_init(&st->usage, rs->grid, rs->shape->wb, 1) : 0;
  for (int c = 0; rc == 0 && c < rs->grid->nclass; c++) {
    rc = ts_vecset_build(rs->shape, rs->grid, rs->ref, c, 0, rs->grid->count[c], &st->cls[c]);
    if (rc == 0) {
      st->penalty[c] = calloc((size_t)st->cls[c].ngroups * TS_L1_GROUP, sizeof(uint32_t));
      if (st->penalty[c] == NULL) rc = TS_ENOMEM;
    }
  }
  if (rc != 0) {
    set_clear(st);
    return ts_error(err, rc, "cannot build the reference vectors: %s", ts_strerror(rc));
  }
  st->used = 1;
  *id = slot;
  return 0;
}

static local_set *set_get(local_search *ls, int id) {
  if (id < 0 || id >= LOCAL_MAX_SETS || !ls->sets[id].used) return NULL;
  return &ls->sets[id];
}

static int local_commit(ts_search *s, int id, const ts_commit *c, uint32_t n,
                        char *err) {
  local_set *st = set_get((local_search *)s, id);
  if (st == NULL) return ts_error(err, TS_EINVAL, "unknown reference set %d", id);
  if (st->usage.count == NULL) return 0;
  for (uint32_t i = 0; i < n; i++) {
    if (c[i].x < 0 || c[i].y < 0 || c[i].x + c[i].w > st->grid.w || c[i].y + c[i].h > st->grid.h)
      return ts_error(err, TS_EINVAL, "commit outside the reference");
    if (c[i].delta != 1 && c[i].delta != -1) return ts_error(err, TS_EINVAL, "commit delta %d", (int)c[i].delta);
    ts_usage_commit(&st->usage, c[i].x, c[i].y, c[i].w, c[i].h, c[i].delta);
  }
  return 0;
}

static int ensure_scratch(local_search *ls, uint32_t nq, uint32_t vbytes) {
  int nt = ts_pool_size(ls->pool);
  if (nq <= ls->cap_q && (uint64_t)nq * vbytes <= ls->cap_bytes) return 0;
  uint32_t cap = nq > 2 * ls->cap_q ? nq : 2 * ls->cap_q;
  uint64_t bytes = (uint64_t)cap * vbytes;
  if (bytes > UINT32_MAX) return TS_ENOMEM;
  free(ls->qbuf);
  free(ls->mbuf);
  free(ls->order);
  free(ls->tbest);
  ls->qbuf = malloc(bytes);
  ls->mbuf = malloc(bytes);
  ls->order = malloc(sizeof(uint32_t) * cap);
  ls->tbest = malloc(sizeof(ts_l1_best) * cap * (size_t)nt);
  ls->cap_q = cap;
  ls->cap_bytes = (uint32_t)bytes;
  if (ls->qbuf == NULL || ls->mbuf == NULL || ls->order == NULL || ls->tbest == NULL) {
    ls->cap_q = ls->cap_bytes = 0;
    return TS_ENOMEM;
  }
  return 0;
}

/* Pool job: worker w scans its slice of every class that has queries. */
static void scan_slices(void *arg, int w, int nw) {
  local_search *ls = arg;
  const local_set *st = ls->cur;
  ts_l1_best *best = ls->tbest + (size_t)w * ls->cap_q;
  ts_l1_best_reset(best, ls->nq);
  for (int c = 0; c < st->grid.nclass; c++) {
    uint32_t q0 = ls->qstart[c], nq = ls->qstart[c + 1] - q0;
    if (nq == 0) continue;
    const ts_l1_set *set = &st->cls[c];
    uint32_t g0 = (uint32_t)((uint64_t)set->ngroups * w / nw);
    uint32_t g1 = (uint32_t)((uint64_t)set->ngroups * (w + 1) / nw);
    if (g0 == g1) continue;
    const uint32_t *pen = NULL;
    if (ls->usage_k != 0) {
      uint32_t *p = st->penalty[c];
      uint32_t v1 = g1 * TS_L1_GROUP < set->nvec ? g1 * TS_L1_GROUP : set->nvec;
      for (uint32_t v = g0 * TS_L1_GROUP; v < v1; v++)
        p[v] = ts_usage_penalty(st->usage.u[st->grid.base[c] + v], ls->usage_k);
      pen = p;
    }
    const uint8_t *q = ls->qbuf + (size_t)q0 * ls->vbytes;
    const uint8_t *m = ls->masked ? ls->mbuf + (size_t)q0 * ls->vbytes : NULL;
    ts_l1_scan_fn *fn = nq == 1 ? ls->base.simd->single : ls->base.simd->batch;
    fn(set, g0, g1, q, m, pen, nq, best + q0);
  }
}

static int local_query(ts_search *s, int id, const ts_query_batch *b,
                       ts_l1_best *out, char *err) {
  local_search *ls = (local_search *)s;
  local_set *st = set_get(ls, id);
  if (st == NULL) return ts_error(err, TS_EINVAL, "unknown reference set %d", id);
  if (b->nq == 0) return 0;
  if (b->usage_k != 0 && st->usage.u == NULL)
    return ts_error(err, TS_EINVAL, "a usage penalty on a set prepared without usage");
  uint32_t vbytes = st->cls[0].nchunks * TS_L1_CHUNK;
  if (ensure_scratch(ls, b->nq, vbytes) != 0)
    return ts_error(err, TS_ENOMEM, "out of memory for a batch of %u queries", b->nq);
  /* Group the queries by class, keeping their order within a class. */
  uint32_t fill[5] = {0};
  for (uint32_t i = 0; i < b->nq; i++) {
    int c = b->klass ? b->klass[i] : 0;
    if (c >= st->grid.nclass) return ts_error(err, TS_EINVAL, "query %u has class %d of %d", i, c, st->grid.nclass);
    fill[c + 1]++;
  }
  for (int c = 0; c < 4; c++) fill[c + 1] += fill[c];
  memcpy(ls->qstart, fill, sizeof(fill));
  for (uint32_t i = 0; i < b->nq; i++) {
    int c = b->klass ? b->klass[i] : 0;
    uint32_t r = fill[c]++;
    ls->order[r] = i;
    memcpy(ls->qbuf + (size_t)r * vbytes, b->queries + (size_t)i * vbytes, vbytes);
    if (b->masks) memcpy(ls->mbuf + (size_t)r * vbytes, b->masks + (size_t)i * vbytes, vbytes);
  }
  ls->cur = st;
  ls->nq = b->nq;
  ls->vbytes = vbytes;
  ls->usage_k = b->usage_k;
  ls->masked = b->masks != NULL;
  /* A small batch costs less than waking the pool: scan it on this thread. */
  uint64_t pairs = 0;
  for (int c = 0; c < st->grid.nclass; c++) pairs += (uint64_t)(ls->qstart[c + 1] - ls->qstart[c]) * st->grid.count[c];
  uint64_t limit = ls->inline_small ? inline_threshold(s->simd, st->cls[0].nchunks) : 0;
  int nt = pairs < limit ? 1 : ts_pool_size(ls->pool);
  double t0 = now_seconds();
  if (nt == 1) scan_slices(ls, 0, 1);
  else ts_pool_run(ls->pool, scan_slices, ls);
  s->stats.scan_seconds += now_seconds() - t0;
  for (int c = 0; c < st->grid.nclass; c++) {
    for (uint32_t r = ls->qstart[c]; r < ls->qstart[c + 1]; r++) {
      ts_l1_best best = ls->tbest[r];
      for (int w = 1; w < nt; w++) ts_l1_best_merge(&best, &ls->tbest[(size_t)w * ls->cap_q + r], 1);
      best.index += st->grid.base[c];
      out[ls->order[r]] = best;
    }
    s->stats.pairs += (uint64_t)(ls->qstart[c + 1] - ls->qstart[c]) * st->grid.count[c];
  }
  s->stats.batches++;
  s->stats.queries += b->nq;
  return 0;
}

static void local_release(ts_search *s, int id) {
  local_set *st = set_get((local_search *)s, id);
  if (st != NULL) set_clear(st);
}

static void local_destroy(ts_search *s) {
  local_search *ls = (local_search *)s;
  for (int i = 0; i < LOCAL_MAX_SETS; i++)
    if (ls->sets[i].used) set_clear(&ls->sets[i]);
  ts_pool_destroy(ls->pool);
  free(ls->qbuf);
  free(ls->mbuf);
  free(ls->order);
  free(ls->tbest);
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

void ts_search_local_set_inline(ts_search *s, int enabled) {
  ((local_search *)s)->inline_small = enabled;
}

int ts_search_local_create(ts_search **out, int nthreads,
                           const ts_l1_impl *simd, char *err) {
  *out = NULL;
  if (nthreads < 1 || nthreads > 1024)
    return ts_error(err, TS_EINVAL, "--threads %d: need 1..1024", nthreads);
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
