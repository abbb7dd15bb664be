/* lbg.c - see lbg.h. The build keeps one class's vectors at a time, one
 * after the other (vbytes each); assignments run on the L1 kernels with
 * the centroids as the scanned set and the vectors as a batch of queries
 * (the centroids stay in L1 cache while every vector passes), medians on
 * byte histograms. */
#include "lbg.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include "error.h"
#include "rng.h"
#include "util.h"

/* Vectors the kernel takes per call in an assignment: a batch whose
 * lane states stay in cache. */
#define ASSIGN_CHUNK 256

void ts_lbg_free(ts_lbg_codebook *cb) {
  free(cb->own);
  memset(cb, 0, sizeof(*cb));
}

int ts_lbg_check(ts_lbg_codebook *cb, int nclass, const uint32_t *count, uint32_t vbytes, char *err) {
  if (cb->mode != TS_LBG_PROBE && cb->mode != TS_LBG_EXACT)
    return ts_error(err, TS_EINVAL, "partitioning mode %u: need %d (probe) or %d (exact)", cb->mode, TS_LBG_PROBE,
                    TS_LBG_EXACT);
  if (cb->nclass != nclass)
    return ts_error(err, TS_EINVAL, "a codebook of %d classes for a set of %d", cb->nclass, nclass);
  if (cb->vbytes != vbytes)
    return ts_error(err, TS_EINVAL, "codebook vectors of %u bytes for a set of %u-byte vectors", cb->vbytes, vbytes);
  if (cb->probe < 1) return ts_error(err, TS_EINVAL, "a codebook probing 0 partitions");
  cb->first[0] = 0;
  for (int c = 0; c < nclass; c++) {
    uint32_t n = cb->npart[c];
    if (n > TS_LBG_MAX_PARTITIONS || n > count[c] || (n == 0 && count[c] > 0))
      return ts_error(err, TS_EINVAL, "%u partitions for class %d's %u vectors: need 1..%u", n, c, count[c],
                      count[c] < TS_LBG_MAX_PARTITIONS ? count[c] : TS_LBG_MAX_PARTITIONS);
    cb->first[c + 1] = cb->first[c] + n;
  }
  return 0;
}

int ts_lbg_centroid_set(ts_l1_set *set, const ts_window *win, const uint8_t *cent, uint32_t n, char *err) {
  int rc = ts_l1_set_init(set, n, win->nchunks);
  if (rc != 0) return ts_error(err, rc, "out of memory for %u centroids", n);
  if ((rc = ts_window_weigh(win, set, err)) != 0) {
    ts_l1_set_free(set);
    return rc;
  }
  uint32_t vbytes = ts_window_bytes(win);
  for (uint32_t k = 0; k < n; k++) ts_l1_set_put(set, k, cent + (size_t)k * vbytes);
  return 0;
}

/* ---- assignment ---------------------------------------------------------- */

typedef struct {
  const ts_l1_set *cent;
  const uint8_t *vecs;
  uint32_t n;
  const ts_l1_impl *simd;
  ts_l1_best *out;
} assign_job;

static void assign_range(void *arg, int w, int nw) {
  const assign_job *j = arg;
  uint32_t i0 = (uint32_t)((uint64_t)j->n * (uint64_t)w / (uint64_t)nw);
  uint32_t i1 = (uint32_t)((uint64_t)j->n * (uint64_t)(w + 1) / (uint64_t)nw);
  size_t vbytes = (size_t)j->cent->nchunks * TS_L1_CHUNK;
  for (uint32_t i = i0; i < i1; i += ASSIGN_CHUNK) {
    uint32_t m = i1 - i < ASSIGN_CHUNK ? i1 - i : ASSIGN_CHUNK;
    ts_l1_best_reset(j->out + i, m);
    j->simd->batch(j->cent, 0, j->cent->ngroups, j->vecs + (size_t)i * vbytes, NULL, NULL, m, j->out + i);
  }
}

void ts_lbg_assign(const ts_l1_set *cent, const uint8_t *vecs, uint32_t n, ts_pool *pool, const ts_l1_impl *simd,
                   ts_l1_best *out) {
  assign_job j = {cent, vecs, n, simd, out};
  if (pool != NULL && n >= 2 * ASSIGN_CHUNK) ts_pool_run(pool, assign_range, &j);
  else assign_range(&j, 0, 1);
}

/* ---- distances to every centroid ------------------------------------------ */

/* Sum of |a - b| over bytes [0, n), n a multiple of 8; mask m (NULL: all)
 * applies to b, a is masked already. */
static uint64_t sad_bytes(const uint8_t *a, const uint8_t *b, const uint8_t *m, uint32_t n) {
  uint64_t s = 0;
  uint32_t i = 0;
#ifdef __SSE2__
  __m128i acc = _mm_setzero_si128();
  for (; i + 16 <= n; i += 16) {
    __m128i vb = _mm_loadu_si128((const __m128i *)(b + i));
    if (m != NULL) vb = _mm_and_si128(vb, _mm_loadu_si128((const __m128i *)(m + i)));
    acc = _mm_add_epi64(acc, _mm_sad_epu8(_mm_loadu_si128((const __m128i *)(a + i)), vb));
  }
  if (i < n) { /* one 8-byte chunk left */
    __m128i vb = _mm_loadl_epi64((const __m128i *)(b + i));
    if (m != NULL) vb = _mm_and_si128(vb, _mm_loadl_epi64((const __m128i *)(m + i)));
    acc = _mm_add_epi64(acc, _mm_sad_epu8(_mm_loadl_epi64((const __m128i *)(a + i)), vb));
    i = n;
  }
  s = (uint64_t)_mm_cvtsi128_si64(acc) + (uint64_t)_mm_cvtsi128_si64(_mm_unpackhi_epi64(acc, acc));
#endif
  for (; i < n; i++) {
    int x = a[i], y = m != NULL ? b[i] & m[i] : b[i];
    s += (uint64_t)(x > y ? x - y : y - x);
  }
  return s;
}

/* Weighted distance of a (masked already) to b under mask m. */
static uint64_t weighted(const ts_l1_set *parts, const uint8_t *a, const uint8_t *b, const uint8_t *m) {
  uint64_t d = 0;
  for (uint32_t p = 0, k = 0; p < parts->nparts; k = parts->part_end[p++]) {
    uint32_t o = k * TS_L1_CHUNK, len = (parts->part_end[p] - k) * TS_L1_CHUNK;
    if (parts->part_weight[p] != 0)
      d += sad_bytes(a + o, b + o, m != NULL ? m + o : NULL, len) * parts->part_weight[p];
  }
  return d;
}

void ts_lbg_dists(const ts_l1_set *parts, const uint8_t *cent, uint32_t n, const uint8_t *q, const uint8_t *mask,
                  uint64_t *d) {
  uint32_t vbytes = parts->nchunks * TS_L1_CHUNK;
  uint8_t qm[TS_L1_MAX_CHUNKS * TS_L1_CHUNK];
  const uint8_t *a = q;
  if (mask != NULL) {
    for (uint32_t i = 0; i < vbytes; i++) qm[i] = q[i] & mask[i];
    a = qm;
  }
  for (uint32_t k = 0; k < n; k++) d[k] = weighted(parts, a, cent + (size_t)k * vbytes, mask);
}

/* ---- nearest partitions ------------------------------------------------- */

/* Whether partition a comes before b: nearer, or as near and lower. */
static int before(const uint64_t *d, uint32_t a, uint32_t b) { return d[a] < d[b] || (d[a] == d[b] && a < b); }

static int order_cmp(const void *x, const void *y, void *ctx) {
  uint32_t a = *(const uint32_t *)x, b = *(const uint32_t *)y;
  return before(ctx, a, b) ? -1 : before(ctx, b, a) ? 1 : 0;
}

/* A few out of many (the usual probe): insertion into the short sorted
 * list out[0..k); many: all of them sorted. The order is total either way
 * (ties by index), so both give the same k. */
#define NEAREST_INSERT_MAX 32

void ts_lbg_nearest(const uint64_t *d, uint32_t n, uint32_t k, uint32_t *out) {
  if (k > NEAREST_INSERT_MAX) {
    for (uint32_t j = 0; j < n; j++) out[j] = j;
    qsort_r(out, n, sizeof(uint32_t), order_cmp, (void *)d);
    return;
  }
  uint32_t have = 0;
  for (uint32_t j = 0; j < n && k > 0; j++) {
    if (have == k && !before(d, j, out[k - 1])) continue;
    uint32_t at = have < k ? have++ : k - 1;
    while (at > 0 && before(d, j, out[at - 1])) {
      out[at] = out[at - 1];
      at--;
    }
    out[at] = j;
  }
}

/* ---- the build ------------------------------------------------------------ */

/* One class's LBG: its vectors, the centroids, each vector's nearest. */
typedef struct {
  const ts_window *win;
  ts_pool *pool;
  const ts_l1_impl *simd;
  uint32_t vbytes;
  uint8_t *vecs;   /* n vectors */
  uint32_t n;
  uint8_t *cent;   /* k centroids */
  uint32_t k;
  ts_l1_best *near; /* per vector */
  uint32_t *start;  /* k + 1: members of centroid i are order[start[i] .. start[i+1]) */
  uint32_t *order;
  uint32_t *was;     /* per vector: its centroid in the iteration before */
  uint32_t nruns;    /* the bytes parts hold: [run[2i], run[2i + 1]); the rest is padding, 0 in every vector */
  uint32_t run[2 * TS_L1_MAX_PARTS];
  uint8_t *changed;  /* per centroid: its members changed (its median must be taken again) */
  uint32_t *hist;   /* per thread: vbytes x 256 */
  int nthreads;
  ts_l1_set parts;  /* no vectors: the window's weighted parts, for weighted() */
} lbg_class;

/* The class's vectors, by their rank in the class. */
static void class_vectors(lbg_class *lc, const ts_anchors *a, const ts_levelplanes *ref, int c) {
  for (uint32_t i = 0; i < lc->n; i++) {
    int x, y;
    ts_anchors_pos(a, a->base[c] + i, &x, &y);
    ts_vec_ref(lc->win, ref, x, y, lc->vecs + (size_t)i * lc->vbytes);
  }
}

/* The seeds: k vectors drawn without replacement (a partial Fisher-Yates
 * shuffle of the ranks). */
static int draw_seeds(lbg_class *lc, uint64_t seed, int c) {
  uint32_t *idx = malloc(sizeof(uint32_t) * lc->n);
  if (idx == NULL) return TS_ENOMEM;
  for (uint32_t i = 0; i < lc->n; i++) idx[i] = i;
  ts_rng rng;
  ts_rng_seed(&rng, seed, (uint64_t)c);
  for (uint32_t i = 0; i < lc->k; i++) {
    uint32_t j = i + ts_rng_below(&rng, lc->n - i), t = idx[i];
    idx[i] = idx[j];
    idx[j] = t;
    memcpy(lc->cent + (size_t)i * lc->vbytes, lc->vecs + (size_t)idx[i] * lc->vbytes, lc->vbytes);
  }
  free(idx);
  return 0;
}

/* Every vector to its nearest centroid (ties to the lowest), with its
 * distance. (Bounds that spare vectors whose centroid is provably still
 * nearest, as in Elkan's k-means, spared only 6 % of the scans on the
 * Table 3.3 job: in 56 to 72 dimensions a vector is seldom nearer its
 * centroid than half the distance between centroids.) */
static int scan_all(lbg_class *lc, char *err) {
  ts_l1_set set;
  int rc = ts_lbg_centroid_set(&set, lc->win, lc->cent, lc->k, err);
  if (rc != 0) return rc;
  ts_lbg_assign(&set, lc->vecs, lc->n, lc->pool, lc->simd, lc->near);
  ts_l1_set_free(&set);
  return 0;
}

/* Members grouped by centroid (a counting sort, ranks ascending within a
 * centroid), and the centroids whose members changed. */
static int group_members(lbg_class *lc, char *err) {
  memset(lc->start, 0, sizeof(uint32_t) * (lc->k + 1));
  for (uint32_t i = 0; i < lc->n; i++) lc->start[lc->near[i].index + 1]++;
  for (uint32_t i = 0; i < lc->k; i++) lc->start[i + 1] += lc->start[i];
  uint32_t *fill = malloc(sizeof(uint32_t) * lc->k);
  if (fill == NULL) return ts_error(err, TS_ENOMEM, "out of memory for the partitions");
  memcpy(fill, lc->start, sizeof(uint32_t) * lc->k);
  for (uint32_t i = 0; i < lc->n; i++) lc->order[fill[lc->near[i].index]++] = i;
  free(fill);
  /* A centroid whose members are those it had keeps its median: only the
   * clusters a vector left or joined are taken again. */
  memset(lc->changed, 0, lc->k);
  for (uint32_t i = 0; i < lc->n; i++) {
    uint32_t k = lc->near[i].index;
    if (k == lc->was[i]) continue;
    lc->changed[k] = 1;
    if (lc->was[i] != UINT32_MAX) lc->changed[lc->was[i]] = 1;
    lc->was[i] = k;
  }
  return 0;
}

static int assign_all(lbg_class *lc, char *err) {
  int rc = scan_all(lc, err);
  return rc != 0 ? rc : group_members(lc, err);
}

/* The lower median, byte by byte, of centroid i's members into out, from
 * 256 counters per byte (a thread's histograms: in cache, unlike
 * histograms kept per centroid and moved with each vector that changes
 * cluster, which on the Table 3.3 job cost more in cache misses than
 * counting again). */
static void median_of(const lbg_class *lc, uint32_t i, uint32_t *hist, uint8_t *out) {
  uint32_t vb = lc->vbytes, s0 = lc->start[i], n = lc->start[i + 1] - s0;
  memset(hist, 0, sizeof(uint32_t) * 256 * vb);
  for (uint32_t m = s0; m < s0 + n; m++) {
    const uint8_t *v = lc->vecs + (size_t)lc->order[m] * vb;
    for (uint32_t r = 0; r < lc->nruns; r++)
      for (uint32_t b = lc->run[2 * r]; b < lc->run[2 * r + 1]; b++) hist[b * 256 + v[b]]++;
  }
  uint32_t rank = (n - 1) / 2; /* the lower median's */
  memset(out, 0, vb); /* padding */
  for (uint32_t r = 0; r < lc->nruns; r++)
    for (uint32_t b = lc->run[2 * r]; b < lc->run[2 * r + 1]; b++) {
      const uint32_t *h = hist + b * 256;
      uint32_t seen = 0, v = 0;
      while (seen + h[v] <= rank) seen += h[v++];
      out[b] = (uint8_t)v;
    }
}

/* The byte runs the window's parts fill (window.h: a part's planes at its
 * source's offsets, then zeros to the next chunk). */
static void part_runs(lbg_class *lc) {
  const ts_window_spec *sp = &lc->win->spec;
  lc->nruns = 0;
  for (int p = 0, k = 0; p < sp->nparts; k = (int)lc->win->part_end[p++]) {
    uint32_t b0 = (uint32_t)k * TS_L1_CHUNK;
    lc->run[2 * lc->nruns] = b0;
    lc->run[2 * lc->nruns + 1] = b0 + (uint32_t)(sp->part[p].nplanes * sp->noff[sp->part[p].source]);
    lc->nruns++;
  }
}

typedef struct {
  const lbg_class *lc;
  uint8_t *next; /* k new centroids */
} median_job;

static void median_range(void *arg, int w, int nw) {
  const median_job *j = arg;
  const lbg_class *lc = j->lc;
  uint32_t k0 = (uint32_t)((uint64_t)lc->k * (uint64_t)w / (uint64_t)nw);
  uint32_t k1 = (uint32_t)((uint64_t)lc->k * (uint64_t)(w + 1) / (uint64_t)nw);
  uint32_t *hist = lc->hist + (size_t)w * lc->vbytes * 256;
  for (uint32_t i = k0; i < k1; i++) {
    uint8_t *out = j->next + (size_t)i * lc->vbytes;
    if (lc->changed[i] && lc->start[i + 1] > lc->start[i]) median_of(lc, i, hist, out);
    else memcpy(out, lc->cent + (size_t)i * lc->vbytes, lc->vbytes); /* the same members, or empty: stays */
  }
}

/* Moves every centroid to its members' median; the summed movement. */
static double move_centroids(lbg_class *lc, uint8_t *next) {
  median_job j = {lc, next};
  if (lc->pool != NULL && lc->nthreads > 1) ts_pool_run(lc->pool, median_range, &j);
  else median_range(&j, 0, 1);
  double moved = 0;
  for (uint32_t i = 0; i < lc->k; i++)
    moved += (double)weighted(&lc->parts, lc->cent + (size_t)i * lc->vbytes, next + (size_t)i * lc->vbytes, NULL);
  memcpy(lc->cent, next, (size_t)lc->k * lc->vbytes);
  return moved;
}

/* Iterates until the movement stops changing by 2 % (or is 0), at most
 * max_iter times; then assigns once more to the final centroids. The
 * movements are summed in doubles (in a fixed order: the same sum
 * everywhere), which no weight can overflow. */
static int iterate(lbg_class *lc, uint32_t max_iter, uint32_t *iters, int *converged, char *err) {
  uint8_t *next = malloc((size_t)lc->k * lc->vbytes);
  int rc = next != NULL ? 0 : ts_error(err, TS_ENOMEM, "out of memory for the centroids");
  double before_move = 0;
  *converged = 0;
  *iters = 0;
  while (rc == 0 && !*converged && *iters < max_iter) {
    if ((rc = assign_all(lc, err)) != 0) break;
    double moved = move_centroids(lc, next);
    ++*iters;
    *converged = moved == 0 || (*iters > 1 && fabs(moved - before_move) < 0.02 * before_move);
    before_move = moved;
  }
  if (rc == 0) rc = assign_all(lc, err);
  free(next);
  return rc;
}

/* Keeps the centroids some vector is nearest to, appended to *all; their
 * sizes appended to sizes. Returns how many. */
static uint32_t keep_used(const lbg_class *lc, uint8_t *all, uint32_t *sizes) {
  uint32_t kept = 0;
  for (uint32_t i = 0; i < lc->k; i++) {
    uint32_t n = lc->start[i + 1] - lc->start[i];
    if (n == 0) continue;
    memcpy(all + (size_t)kept * lc->vbytes, lc->cent + (size_t)i * lc->vbytes, lc->vbytes);
    sizes[kept++] = n;
  }
  return kept;
}

static void class_free(lbg_class *lc) {
  free(lc->vecs);
  free(lc->cent);
  free(lc->near);
  free(lc->start);
  free(lc->order);
  free(lc->was);
  free(lc->changed);
}

/* Runs class c's LBG; its kept centroids are appended at cb->own from
 * centroid cb->first[c] on, their sizes to sizes. */
static int build_class(lbg_class *lc, ts_lbg_codebook *cb, const ts_anchors *a, const ts_levelplanes *ref,
                       const ts_lbg_params *p, int c, uint32_t *sizes, ts_lbg_report *rep, char *err) {
  lc->n = a->count[c];
  lc->k = p->partitions < lc->n ? p->partitions : lc->n;
  cb->npart[c] = 0;
  if (lc->n == 0) return 0;
  lc->vecs = malloc((size_t)lc->n * lc->vbytes);
  lc->cent = malloc((size_t)lc->k * lc->vbytes);
  lc->near = malloc(sizeof(ts_l1_best) * lc->n);
  lc->start = malloc(sizeof(uint32_t) * (lc->k + 1));
  lc->order = malloc(sizeof(uint32_t) * lc->n);
  lc->was = malloc(sizeof(uint32_t) * lc->n);
  lc->changed = malloc(lc->k);
  int rc = 0;
  if (lc->vecs == NULL || lc->cent == NULL || lc->near == NULL || lc->start == NULL || lc->order == NULL ||
      lc->was == NULL || lc->changed == NULL)
    rc = ts_error(err, TS_ENOMEM, "out of memory for the %u vectors of class %d", lc->n, c);
  if (rc == 0) {
    class_vectors(lc, a, ref, c);
    memset(lc->was, 0xFF, sizeof(uint32_t) * lc->n); /* no centroid yet */
  }
  if (rc == 0 && draw_seeds(lc, p->seed, c) != 0) rc = ts_error(err, TS_ENOMEM, "out of memory");
  uint32_t iters = 0;
  int converged = 0;
  if (rc == 0) rc = iterate(lc, p->max_iter ? p->max_iter : TS_LBG_MAX_ITER, &iters, &converged, err);
  if (rc == 0) {
    cb->npart[c] = keep_used(lc, cb->own + (size_t)cb->first[c] * lc->vbytes, sizes + cb->first[c]);
    if (iters > rep->iterations) rep->iterations = iters;
    rep->converged = rep->converged && converged;
  }
  class_free(lc);
  return rc;
}

static int u32_cmp(const void *x, const void *y) {
  uint32_t a = *(const uint32_t *)x, b = *(const uint32_t *)y;
  return a < b ? -1 : a > b;
}

/* The report's size figures from the kept partitions' sizes. */
static void size_figures(ts_lbg_report *rep, uint32_t *sizes, uint32_t n) {
  rep->partitions = n;
  if (n == 0) return;
  qsort(sizes, n, sizeof(uint32_t), u32_cmp);
  rep->size_min = sizes[0];
  rep->size_median = sizes[(n - 1) / 2];
  rep->size_max = sizes[n - 1];
}

int ts_lbg_build(ts_lbg_codebook *cb, const ts_window *win, const ts_anchors *a, const ts_levelplanes *ref,
                 const ts_lbg_params *p, ts_pool *pool, const ts_l1_impl *simd, ts_lbg_report *rep, char *err) {
  double t0 = ts_now();
  memset(cb, 0, sizeof(*cb));
  ts_lbg_report local;
  if (rep == NULL) rep = &local;
  memset(rep, 0, sizeof(*rep));
  rep->converged = 1;
  if (p->partitions < 1 || p->partitions > TS_LBG_MAX_PARTITIONS || p->probe < 1)
    return ts_error(err, TS_EINVAL, "%u partitions probed %u at a time: need 1..%d partitions, probing >= 1",
                    p->partitions, p->probe, TS_LBG_MAX_PARTITIONS);
  cb->mode = p->exact ? TS_LBG_EXACT : TS_LBG_PROBE;
  cb->probe = p->probe;
  cb->vbytes = ts_window_bytes(win);
  cb->nclass = a->nclass;
  uint64_t most = 0; /* centroids at most, over all classes */
  for (int c = 0; c < a->nclass; c++) most += a->count[c] < p->partitions ? a->count[c] : p->partitions;
  lbg_class lc = {.win = win, .pool = pool, .simd = simd, .vbytes = cb->vbytes,
                  .nthreads = pool ? ts_pool_size(pool) : 1};
  part_runs(&lc);
  if (ts_l1_set_init(&lc.parts, 0, win->nchunks) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
  int rc = ts_window_weigh(win, &lc.parts, err);
  if (rc != 0) return rc;
  cb->own = malloc(most * cb->vbytes + 1);
  uint32_t *sizes = malloc(sizeof(uint32_t) * most + 1);
  lc.hist = malloc((size_t)lc.nthreads * cb->vbytes * 256 * sizeof(uint32_t));
  rc = cb->own && sizes && lc.hist ? 0 : ts_error(err, TS_ENOMEM, "out of memory for a codebook");
  for (int c = 0; rc == 0 && c < a->nclass; c++) {
    rc = build_class(&lc, cb, a, ref, p, c, sizes, rep, err);
    cb->first[c + 1] = cb->first[c] + cb->npart[c];
  }
  if (rc == 0) size_figures(rep, sizes, cb->first[a->nclass]);
  free(sizes);
  free(lc.hist);
  ts_l1_set_free(&lc.parts);
  if (rc != 0) ts_lbg_free(cb);
  cb->cent = cb->own;
  rep->seconds = ts_now() - t0;
  return rc;
}
