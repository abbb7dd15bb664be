/* lbg.h - vector-space partitioning of a reference set (seed 002 §3.6.5):
 * an LBG codebook per class, each vector's partition, and what a
 * two-stage search needs: the distances of a query to the centroids, the
 * partitions nearest to it, and the bound that lets an exact search skip
 * a partition.
 *
 * Two-stage search. A query is compared with the centroids of its class
 * and scans only the vectors of its `probe` nearest partitions. That is
 * lossy: the nearest vector may lie in another partition (the seed saw up
 * to a third of the pixels change). The exact variant (digest §5.4) goes
 * on to every other partition k unless
 *
 *     d(q, c_k) - r_k > best so far,    r_k = max over v in k of d(v, c_k).
 *
 * Why that is exact: the weighted L1 of l1.h is a sum of weighted absolute
 * differences, so the triangle inequality gives d(q, v) >= d(q, c_k) -
 * d(v, c_k) >= d(q, c_k) - r_k for every v of k. A query's mask drops the
 * same components from d(q, v) and d(q, c_k) and can only shrink d(v, c_k)
 * (still <= r_k); the usage penalty only adds to d(q, v). A partition is
 * skipped only when its bound is strictly above the best, so no vector
 * that could tie is skipped either, and ties still go to the lowest global
 * index: the results are those of exhaustive search, bit for bit.
 *
 * The codebook is LBG (Linde, Buzo, Gray 1980) as the seed runs it, per
 * class (parity classes are separate search spaces), with the component-
 * wise median as a cluster's representative, which minimises the summed
 * L1 distance of its members (the seed moves seeds to the mean, L2's
 * optimum; digest §5.4):
 *   1. P seeds drawn without replacement from the class's vectors (ts_rng
 *      from the seed parameter, one stream per class);
 *   2. every vector to its nearest seed under the search's weighted L1,
 *      ties to the lowest seed;
 *   3. every seed to the median of its cluster (the lower median, byte by
 *      byte; an empty cluster keeps its seed);
 *   4. 2-3 again until the seeds' summed movement (weighted L1) is 0 or
 *      changes by less than 2 % from the iteration before (the seed's
 *      "1.02"), or max_iter iterations.
 * A vector's partition is then its nearest centroid (ties to the lowest):
 * a function of the vector and the codebook alone, which a worker computes
 * for its slice and gets the coordinator's answer. Centroids nearest to no
 * vector are dropped, which moves no vector. All of it is integer
 * arithmetic on the kernels of l1.h: the same codebook on every machine. */
#ifndef TS_LBG_H
#define TS_LBG_H

#include <stdint.h>

#include "anchors.h"
#include "l1.h"
#include "pool.h"
#include "window.h"

#define TS_LBG_MAX_PARTITIONS 65536 /* per class */
/* Default iteration limit. On the Table 3.3 job's level 0 (63504 vectors
 * a parity class, 256 partitions) the movement rule had not stopped by 30
 * iterations (the movement wavers by 5-10 % from one to the next), while
 * the summed distortion was within 0.6 % of its 24th iteration's by the
 * 12th; an iteration costs about 1 % of the level's exhaustive search. */
#define TS_LBG_MAX_ITER 12

enum { TS_LBG_OFF = 0, TS_LBG_PROBE = 1, TS_LBG_EXACT = 2 };

/* What a set's partitioning is built with. */
typedef struct {
  uint32_t partitions; /* P per class, 1..TS_LBG_MAX_PARTITIONS (fewer when a class has fewer vectors) */
  uint32_t probe;      /* partitions scanned first (lossy: only), >= 1 */
  int exact;           /* then every partition the bound does not rule out */
  uint64_t seed;       /* the seeds' draw */
  uint32_t max_iter;   /* 0: TS_LBG_MAX_ITER */
} ts_lbg_params;

/* How the build went, over all classes. */
typedef struct {
  uint32_t partitions; /* centroids kept */
  uint32_t iterations; /* the most any class took */
  int converged;       /* every class stopped on the 2 % rule, not max_iter */
  double seconds;
  uint32_t size_min, size_median, size_max; /* vectors per partition */
} ts_lbg_report;

/* A codebook: per class npart[c] centroids of vbytes bytes (a vector's
 * layout, padding zero), class after class from cent; first[c] is class
 * c's first centroid. A built codebook owns its bytes (own); one read
 * from a message points into it. */
typedef struct {
  uint8_t mode; /* TS_LBG_PROBE or TS_LBG_EXACT */
  uint32_t probe;
  uint32_t vbytes;
  int nclass;
  uint32_t npart[TS_MAX_CLASSES];
  uint32_t first[TS_MAX_CLASSES + 1];
  const uint8_t *cent;
  uint8_t *own;
} ts_lbg_codebook;

/* Builds the codebook of the set (window, anchors, planes) with p, on the
 * threads of pool (NULL: this thread; the pool must be idle) and the
 * kernel simd. rep (may be NULL) gets the build's figures. 0, or
 * TS_EINVAL / TS_ENOMEM with a message. */
int ts_lbg_build(ts_lbg_codebook *cb, const ts_window *win, const ts_anchors *a, const ts_levelplanes *ref,
                 const ts_lbg_params *p, ts_pool *pool, const ts_l1_impl *simd, ts_lbg_report *rep, char *err);
void ts_lbg_free(ts_lbg_codebook *cb);

/* Checks a codebook against a set of `nclass` classes of count[c]
 * vectors of vbytes bytes (what a worker checks a received one against)
 * and fills first[]: 0, or TS_EINVAL with a message. */
int ts_lbg_check(ts_lbg_codebook *cb, int nclass, const uint32_t *count, uint32_t vbytes, char *err);

/* Centroids [0, n) at cent as a kernel set weighted by the window. */
int ts_lbg_centroid_set(ts_l1_set *set, const ts_window *win, const uint8_t *cent, uint32_t n, char *err);

/* The nearest centroid of each of n vectors (vbytes each, one after the
 * other): out[i] = its distance and index, ties to the lowest index. On
 * the pool's threads (NULL: this thread). */
void ts_lbg_assign(const ts_l1_set *cent, const uint8_t *vecs, uint32_t n, ts_pool *pool, const ts_l1_impl *simd,
                   ts_l1_best *out);

/* The distance of query q (mask: NULL or as l1.h's) to each of the n
 * centroids at cent (vbytes each), weighted by the parts of `parts` (a
 * set of the window: ts_l1_set_weigh), into d[0..n). */
void ts_lbg_dists(const ts_l1_set *parts, const uint8_t *cent, uint32_t n, const uint8_t *q, const uint8_t *mask,
                  uint64_t *d);

/* The k partitions (k <= n) of smallest d, nearest first, ties to the
 * lower index, into out[0..k). out has room for n (a large k sorts them
 * all there). */
void ts_lbg_nearest(const uint64_t *d, uint32_t n, uint32_t k, uint32_t *out);

/* Whether a partition whose centroid lies at distance dc from the query
 * and whose vectors lie within radius of it can hold nothing as good as
 * best (see the top of this file): strictly above, so ties are scanned. */
static inline int ts_lbg_skips(uint64_t dc, uint64_t radius, uint64_t best) {
  return dc > radius && dc - radius > best;
}

#endif
