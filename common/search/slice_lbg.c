/* slice_lbg.c - partitioned slices (lbg.h).
 *
 * Layout: each class's vectors sorted by partition, every partition from a
 * group boundary, ranks ascending within it. A partition is then one run
 * of groups the kernels stream, and the lowest lane of a tie is the lowest
 * rank. (The seed insists on the re-sort: scattered access to a partition
 * costs about as much as a full search.)
 *
 * A batch, in two stages: every query row picks the partitions it scans,
 * by its distances to its class's centroids; the (row, partition) pairs are
 * sorted by partition, and each partition is streamed once against all
 * the rows that picked it, its groups shared out among the threads. The
 * exact variant then scans, for every row, each other partition its bound
 * does not rule out given the best found so far. The candidates of a row
 * depend only on the codebook and the query, never on how the set is
 * sliced: every worker scans its share of the same partitions. */
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "slice_impl.h"

/* Vectors read back and assigned at a time when a slice is sorted. */
#define PARTITION_CHUNK 4096

/* A partition a batch scans: class, partition, its pairs [p0, p1). */
typedef struct lbg_active {
  uint32_t c, k;
  uint32_t p0, p1;
} active;

int ts__slice_lbg_take(ts_slice *s, const ts_slice_desc *m, char *err) {
  s->lbg = m->lbg;
  s->lbg.own = NULL;
  int rc = ts_lbg_check(&s->lbg, s->nclass, m->count, ts_window_bytes(&s->window), err);
  if (rc != 0) return rc;
  size_t bytes = (size_t)s->lbg.first[s->nclass] * s->lbg.vbytes;
  s->lbg.own = malloc(bytes + 1);
  s->part = calloc((size_t)s->nclass, sizeof(*s->part));
  if (s->lbg.own == NULL || s->part == NULL) return ts_error(err, TS_ENOMEM, "out of memory for the codebook");
  if (bytes > 0) memcpy(s->lbg.own, m->lbg.cent, bytes);
  s->lbg.cent = s->lbg.own;
  return 0;
}

/* The nearest centroid of each of class c's vectors, read back from the
 * class's set a chunk at a time. */
static int nearest_of_class(ts_slice *s, int c, ts_pool *pool, const ts_l1_impl *simd, ts_l1_best *near, char *err) {
  uint32_t nv = s->i1[c] - s->i0[c], vb = ts_window_bytes(&s->window);
  uint8_t *buf = malloc((size_t)(nv < PARTITION_CHUNK ? nv : PARTITION_CHUNK) * vb + 1);
  if (buf == NULL) return ts_error(err, TS_ENOMEM, "out of memory for the partitions");
  for (uint32_t i = 0; i < nv; i += PARTITION_CHUNK) {
    uint32_t n = nv - i < PARTITION_CHUNK ? nv - i : PARTITION_CHUNK;
    for (uint32_t v = 0; v < n; v++) ts_l1_set_get(&s->cls[c], i + v, buf + (size_t)v * vb);
    ts_lbg_assign(&s->part[c].cset, buf, n, pool, simd, near + i);
  }
  free(buf);
  return 0;
}

/* Partition sizes, radii and group starts of class c from its vectors'
 * nearest centroids. */
static void size_partitions(slice_part *sp, const ts_l1_best *near, uint32_t nv) {
  for (uint32_t v = 0; v < nv; v++) {
    uint32_t k = near[v].index;
    sp->n[k]++;
    if (near[v].dist > sp->radius[k]) sp->radius[k] = near[v].dist;
  }
  sp->g0[0] = 0;
  for (uint32_t k = 0; k < sp->npart; k++) sp->g0[k + 1] = sp->g0[k] + (sp->n[k] + TS_L1_GROUP - 1) / TS_L1_GROUP;
}

/* Class c's vectors moved into a set laid out by partition. */
static int sort_class(ts_slice *s, int c, const ts_l1_best *near, char *err) {
  slice_part *sp = &s->part[c];
  uint32_t nv = s->i1[c] - s->i0[c], slots = sp->g0[sp->npart] * TS_L1_GROUP;
  ts_l1_set sorted;
  int rc = ts_l1_set_init(&sorted, slots, s->window.nchunks);
  if (rc != 0) return ts_error(err, rc, "out of memory for the partitioned vectors of class %d", c);
  uint32_t *fill = malloc(sizeof(uint32_t) * sp->npart + 1);
  sp->rank = malloc(sizeof(uint32_t) * slots + 1);
  if (fill == NULL || sp->rank == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory for the partitions");
  if (rc == 0) rc = ts_window_weigh(&s->window, &sorted, err);
  if (rc != 0) {
    free(fill);
    ts_l1_set_free(&sorted);
    return rc;
  }
  uint8_t vec[TS_L1_MAX_CHUNKS * TS_L1_CHUNK];
  for (uint32_t k = 0; k < sp->npart; k++) fill[k] = sp->g0[k] * TS_L1_GROUP;
  for (uint32_t v = 0; v < nv; v++) { /* ranks ascending: so within each partition */
    uint32_t slot = fill[near[v].index]++;
    ts_l1_set_get(&s->cls[c], v, vec);
    ts_l1_set_put(&sorted, slot, vec);
    sp->rank[slot] = v;
  }
  free(fill);
  ts_l1_set_free(&s->cls[c]);
  s->cls[c] = sorted;
  if (s->with_usage) { /* penalties are indexed like the set */
    free(s->penalty[c]);
    s->penalty[c] = calloc((size_t)slots + 1, sizeof(uint32_t));
    if (s->penalty[c] == NULL) return ts_error(err, TS_ENOMEM, "out of memory for the slice's penalties");
  }
  return 0;
}

static int partition_class(ts_slice *s, int c, ts_pool *pool, const ts_l1_impl *simd, char *err) {
  slice_part *sp = &s->part[c];
  uint32_t np = s->lbg.npart[c], nv = s->i1[c] - s->i0[c];
  sp->npart = np;
  sp->cent = s->lbg.cent + (size_t)s->lbg.first[c] * s->lbg.vbytes;
  sp->g0 = calloc((size_t)np + 1, sizeof(uint32_t));
  sp->n = calloc((size_t)np + 1, sizeof(uint32_t));
  sp->radius = calloc((size_t)np + 1, sizeof(uint64_t));
  ts_l1_best *near = malloc(sizeof(ts_l1_best) * nv + 1);
  int rc = sp->g0 && sp->n && sp->radius && near ? 0 : ts_error(err, TS_ENOMEM, "out of memory for the partitions");
  if (rc == 0) rc = ts_lbg_centroid_set(&sp->cset, &s->window, sp->cent, np, err);
  if (rc == 0) rc = nearest_of_class(s, c, pool, simd, near, err);
  if (rc == 0) size_partitions(sp, near, nv);
  if (rc == 0) rc = sort_class(s, c, near, err);
  free(near);
  return rc;
}

int ts__slice_partition(ts_slice *s, ts_pool *pool, char *err) {
  const ts_l1_impl *simd; /* any variant finds the same partitions */
  int rc = ts_l1_select(&simd, err);
  for (int c = 0; rc == 0 && c < s->nclass; c++) rc = partition_class(s, c, pool, simd, err);
  return rc;
}

void ts__slice_lbg_free(ts_slice *s) {
  for (int c = 0; s->part != NULL && c < s->nclass; c++) {
    slice_part *sp = &s->part[c];
    ts_l1_set_free(&sp->cset);
    free(sp->g0);
    free(sp->n);
    free(sp->radius);
    free(sp->rank);
  }
  free(s->part);
  free(s->lbg.own);
  lbg_scratch *x = &s->lx;
  free(x->dist);
  free(x->pick);
  free(x->mark);
  free(x->pairs);
  free(x->act);
  free(x->pq);
  free(x->pm);
  free(x->tbest);
  free(x->near);
  free(x->best);
}

/* ---- a batch ------------------------------------------------------------- */

/* Grows the array p (cap elements) to hold need elements, at least
 * doubling it: 0 or TS_ENOMEM. */
#define GROW(p, cap, need) ((size_t)(need) <= (cap) ? 0 : grow_array((void *)&(p), &(cap), (need), sizeof(*(p))))

static int grow_array(void *pp, size_t *cap, size_t need, size_t elem) {
  void *old;
  memcpy(&old, pp, sizeof(old));
  size_t n = need > 2 * *cap ? need : 2 * *cap;
  void *q = realloc(old, n * elem);
  if (q == NULL) return TS_ENOMEM;
  memcpy(pp, &q, sizeof(q));
  *cap = n;
  return 0;
}

static uint32_t max_parts(const ts_slice *s) {
  uint32_t mp = 1;
  for (int c = 0; c < s->nclass; c++)
    if (s->part[c].npart > mp) mp = s->part[c].npart;
  return mp;
}

/* Partitions class c's rows probe first. */
static uint32_t probe_of(const ts_slice *s, int c) {
  return s->lbg.probe < s->part[c].npart ? s->lbg.probe : s->part[c].npart;
}

/* Whether rows pick by all their centroid distances (kept for the
 * bounds), or by the kernel's nearest centroid alone (a lossy probe of 1). */
static int needs_dists(const ts_slice *s) { return s->lbg.mode == TS_LBG_EXACT || s->lbg.probe > 1; }

/* Pool job: thread w picks the partitions of its share of the rows. */
static void pick_rows(void *arg, int w, int nw) {
  ts_slice *s = arg;
  lbg_scratch *x = &s->lx;
  uint32_t r0 = (uint32_t)((uint64_t)s->nq * (uint64_t)w / (uint64_t)nw);
  uint32_t r1 = (uint32_t)((uint64_t)s->nq * (uint64_t)(w + 1) / (uint64_t)nw), mp = x->stride;
  for (int c = 0; c < s->nclass; c++) {
    uint32_t a = s->qstart[c] > r0 ? s->qstart[c] : r0, b = s->qstart[c + 1] < r1 ? s->qstart[c + 1] : r1;
    const slice_part *sp = &s->part[c];
    if (a >= b || sp->npart == 0) continue;
    const uint8_t *q = s->qbuf + (size_t)a * s->vbytes, *m = s->masked ? s->mbuf + (size_t)a * s->vbytes : NULL;
    if (!needs_dists(s)) {
      ts_l1_best_reset(x->near + a, b - a);
      (b - a == 1 ? s->simd->single : s->simd->batch)(&sp->cset, 0, sp->cset.ngroups, q, m, NULL, b - a, x->near + a);
      for (uint32_t r = a; r < b; r++) x->pick[r] = x->near[r].index;
      continue;
    }
    for (uint32_t r = a; r < b; r++) {
      size_t o = (size_t)(r - a) * s->vbytes;
      ts_lbg_dists(&sp->cset, sp->cent, sp->npart, q + o, m ? m + o : NULL, x->dist + (size_t)r * mp);
      ts_lbg_nearest(x->dist + (size_t)r * mp, sp->npart, probe_of(s, c), x->pick + (size_t)r * mp);
    }
  }
}

/* The pairs of every row with the partitions it picked (those this slice
 * holds vectors of), sorted by partition. */
static void pair_up(const ts_slice *s, const lbg_scratch *x, uint32_t *n) {
  *n = 0;
  uint32_t stride = needs_dists(s) ? x->stride : 1;
  for (int c = 0; c < s->nclass; c++)
    for (uint32_t r = s->qstart[c]; r < s->qstart[c + 1]; r++)
      for (uint32_t i = 0; i < probe_of(s, c); i++) {
        uint32_t k = x->pick[(size_t)r * stride + i];
        if (s->part[c].n[k] > 0) x->pairs[(*n)++] = (uint64_t)(s->lbg.first[c] + k) << 32 | r;
      }
}

/* The pairs of every row with each partition it did not pick whose bound
 * does not rule it out (lbg.h), given the row's best so far. */
static void pair_up_bounded(const ts_slice *s, lbg_scratch *x, uint32_t *n) {
  *n = 0;
  uint32_t mp = x->stride;
  for (int c = 0; c < s->nclass; c++) {
    const slice_part *sp = &s->part[c];
    for (uint32_t r = s->qstart[c]; r < s->qstart[c + 1]; r++) {
      const uint32_t *pick = x->pick + (size_t)r * mp;
      const uint64_t *d = x->dist + (size_t)r * mp;
      for (uint32_t i = 0; i < probe_of(s, c); i++) x->mark[pick[i]] = 1;
      for (uint32_t k = 0; k < sp->npart; k++)
        if (!x->mark[k] && sp->n[k] > 0 && !ts_lbg_skips(d[k], sp->radius[k], x->best[r].dist))
          x->pairs[(*n)++] = (uint64_t)(s->lbg.first[c] + k) << 32 | r;
      for (uint32_t i = 0; i < probe_of(s, c); i++) x->mark[pick[i]] = 0;
    }
  }
}

static int u64_cmp(const void *a, const void *b) {
  uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
  return x < y ? -1 : x > y;
}

/* The class of a partition numbered across classes (codebook order). */
static int class_of(const ts_slice *s, uint32_t g) {
  int c = 0;
  while (g >= s->lbg.first[c + 1]) c++;
  return c;
}

/* Sorts the pairs, lists the partitions they scan and lays their rows'
 * queries (and masks) out pair by pair. */
static void group_pairs(ts_slice *s, uint32_t n) {
  lbg_scratch *x = &s->lx;
  qsort(x->pairs, n, sizeof(uint64_t), u64_cmp);
  x->nact = 0;
  for (uint32_t p = 0; p < n; p++) {
    uint32_t g = (uint32_t)(x->pairs[p] >> 32), r = (uint32_t)x->pairs[p];
    if (p == 0 || (uint32_t)(x->pairs[p - 1] >> 32) != g) {
      int c = class_of(s, g);
      x->act[x->nact++] = (active){(uint32_t)c, g - s->lbg.first[c], p, p};
    }
    x->act[x->nact - 1].p1 = p + 1;
    memcpy(x->pq + (size_t)p * s->vbytes, s->qbuf + (size_t)r * s->vbytes, s->vbytes);
    if (s->masked) memcpy(x->pm + (size_t)p * s->vbytes, s->mbuf + (size_t)r * s->vbytes, s->vbytes);
  }
}

/* Groups [g0, g1) of the set, as a set of their own holding n vectors. */
static ts_l1_set run_of(const ts_l1_set *set, uint32_t g0, uint32_t n) {
  ts_l1_set v = *set;
  v.data = set->data + (size_t)g0 * set->nchunks * TS_L1_GROUP * TS_L1_CHUNK;
  v.nvec = n;
  v.ngroups = (n + TS_L1_GROUP - 1) / TS_L1_GROUP;
  return v;
}

/* Pool job: thread w scans its share of the groups of every listed
 * partition against the partition's pairs, the usage penalties of those
 * groups first. */
static void scan_active(void *arg, int w, int nw) {
  ts_slice *s = arg;
  lbg_scratch *x = &s->lx;
  ts_l1_best *best = x->tbest + (size_t)w * x->npairs;
  ts_l1_best_reset(best, x->npairs);
  for (uint32_t i = 0; i < x->nact; i++) {
    const active *a = &x->act[i];
    const slice_part *sp = &s->part[a->c];
    uint32_t first = sp->g0[a->k], ng = sp->g0[a->k + 1] - first, nk = sp->n[a->k];
    uint32_t ga = (uint32_t)((uint64_t)ng * (uint64_t)w / (uint64_t)nw);
    uint32_t gb = (uint32_t)((uint64_t)ng * (uint64_t)(w + 1) / (uint64_t)nw);
    if (ga == gb) continue;
    const uint32_t *pen = NULL;
    if (s->usage_k != 0) {
      uint32_t *p = s->penalty[a->c] + (size_t)first * TS_L1_GROUP;
      const uint32_t *uj = s->usage.u + s->anchors.base[a->c] + s->i0[a->c];
      const uint32_t *rank = sp->rank + (size_t)first * TS_L1_GROUP;
      uint32_t v1 = gb * TS_L1_GROUP < nk ? gb * TS_L1_GROUP : nk;
      for (uint32_t v = ga * TS_L1_GROUP; v < v1; v++) p[v] = ts_usage_penalty(uj[rank[v]], s->usage_k);
      pen = p;
    }
    ts_l1_set run = run_of(&s->cls[a->c], first, nk);
    uint32_t nq = a->p1 - a->p0;
    const uint8_t *m = s->masked ? x->pm + (size_t)a->p0 * s->vbytes : NULL;
    (nq == 1 ? s->simd->single : s->simd->batch)(&run, ga, gb, x->pq + (size_t)a->p0 * s->vbytes, m, pen, nq,
                                                 best + a->p0);
  }
}

/* Each pair's best over the threads, as a global index, into its row's
 * best; the vectors compared. */
static uint64_t merge_pairs(ts_slice *s, int threads) {
  lbg_scratch *x = &s->lx;
  uint64_t compared = 0;
  for (uint32_t i = 0; i < x->nact; i++) {
    const active *a = &x->act[i];
    const slice_part *sp = &s->part[a->c];
    uint32_t slot0 = sp->g0[a->k] * TS_L1_GROUP, base = s->anchors.base[a->c] + s->i0[a->c];
    compared += (uint64_t)sp->n[a->k] * (a->p1 - a->p0);
    for (uint32_t p = a->p0; p < a->p1; p++) {
      ts_l1_best *row = &x->best[(uint32_t)x->pairs[p]];
      for (int w = 0; w < threads; w++) {
        ts_l1_best b = x->tbest[(size_t)w * x->npairs + p];
        if (b.index == UINT32_MAX) continue;
        b.index = base + sp->rank[slot0 + b.index];
        ts_l1_best_merge(row, &b, 1);
      }
    }
  }
  return compared;
}

/* Room for n pairs and their queries on `threads` threads. */
static int pairs_room(ts_slice *s, uint32_t n, int threads) {
  lbg_scratch *x = &s->lx;
  size_t qbytes = (size_t)n * s->vbytes;
  if (GROW(x->pq, x->cap_pq, qbytes) != 0 || GROW(x->pm, x->cap_pm, qbytes) != 0 ||
      GROW(x->tbest, x->cap_tbest, (size_t)n * (size_t)threads) != 0)
    return TS_ENOMEM;
  return 0;
}

/* Scans the n pairs in x->pairs. */
static int scan_pairs(ts_slice *s, ts_pool *pool, int threads, uint32_t n, uint64_t *pairs, char *err) {
  lbg_scratch *x = &s->lx;
  if (n == 0) return 0;
  if (pairs_room(s, n, threads) != 0) return ts_error(err, TS_ENOMEM, "out of memory for a batch of %u pairs", n);
  x->npairs = n;
  group_pairs(s, n);
  if (threads == 1) scan_active(s, 0, 1);
  else ts_pool_run(pool, scan_active, s);
  *pairs += merge_pairs(s, threads);
  return 0;
}

/* Room for a batch's rows: picks, distances, pairs, marks, bests. */
static int rows_room(ts_slice *s) {
  lbg_scratch *x = &s->lx;
  size_t nq = s->nq, mp = x->stride;
  size_t most = nq * (s->lbg.mode == TS_LBG_EXACT || s->lbg.probe > mp ? mp : s->lbg.probe);
  int d = needs_dists(s);
  if (GROW(x->best, x->cap_best, nq) != 0 || GROW(x->near, x->cap_near, nq) != 0 ||
      GROW(x->pick, x->cap_pick, d ? nq * mp : nq) != 0 || (d && GROW(x->dist, x->cap_dist, nq * mp) != 0) ||
      GROW(x->pairs, x->cap_pairs, most) != 0 || GROW(x->act, x->cap_act, most) != 0)
    return TS_ENOMEM;
  if (mp > x->cap_mark) { /* marks are kept clear between rows */
    free(x->mark);
    x->cap_mark = 0;
    if ((x->mark = calloc(mp, 1)) == NULL) return TS_ENOMEM;
    x->cap_mark = mp;
  }
  return 0;
}

int ts__slice_scan_lbg(ts_slice *s, ts_pool *pool, int threads, uint64_t *pairs, char *err) {
  lbg_scratch *x = &s->lx;
  x->stride = max_parts(s);
  if (rows_room(s) != 0) return ts_error(err, TS_ENOMEM, "out of memory for a batch of %u queries", s->nq);
  ts_l1_best_reset(x->best, s->nq);
  if (threads == 1) pick_rows(s, 0, 1);
  else ts_pool_run(pool, pick_rows, s);
  uint32_t n;
  pair_up(s, x, &n);
  int rc = scan_pairs(s, pool, threads, n, pairs, err);
  if (rc != 0 || s->lbg.mode != TS_LBG_EXACT) return rc;
  pair_up_bounded(s, x, &n);
  return scan_pairs(s, pool, threads, n, pairs, err);
}
