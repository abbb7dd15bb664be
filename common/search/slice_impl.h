/* slice_impl.h - the inside of a slice (slice.h), shared by slice.c (rows,
 * vectors, exhaustive scans) and slice_lbg.c (partitioned slices: their
 * layout and two-stage scans); not part of the interface. */
#ifndef TS_SLICE_IMPL_H
#define TS_SLICE_IMPL_H

#include <stddef.h>
#include <stdint.h>

#include "lbg.h"
#include "slice.h"
#include "usage.h"

/* One class's partitions in a partitioned slice. The class's vector set
 * holds partition k's n[k] vectors (of the slice's range) at groups
 * [g0[k], g0[k + 1]), ranks ascending, lanes past n[k] unused; rank[j] is
 * the rank (minus i0) of the vector in lane j, radius[k] the largest
 * distance of partition k's vectors to its centroid. */
typedef struct {
  uint32_t npart;
  const uint8_t *cent; /* the class's centroids, in the slice's codebook */
  ts_l1_set cset;      /* the same as a kernel set: nearest of a probe of 1 */
  uint32_t *g0;        /* npart + 1 */
  uint32_t *n;
  uint64_t *radius;
  uint32_t *rank;
} slice_part;

/* A partitioned batch: per query row its centroid distances (stride
 * entries a row) and picked partitions, the (row, partition) pairs to
 * scan and the partitions they list, the pairs' queries and masks one
 * after the other, the per-thread bests of the pairs, each row's best so
 * far; grown on demand (cap_*: elements allocated). */
typedef struct {
  uint32_t stride, npairs, nact;
  uint64_t *dist;
  uint32_t *pick;
  ts_l1_best *near; /* the kernel's nearest centroid of each row */
  uint8_t *mark;    /* partitions the row at hand picked; kept all 0 */
  uint64_t *pairs;  /* partition (numbered across classes) << 32 | row */
  struct lbg_active *act;
  uint8_t *pq, *pm;
  ts_l1_best *tbest; /* threads x npairs */
  ts_l1_best *best;
  size_t cap_dist, cap_pick, cap_near, cap_mark, cap_pairs, cap_act, cap_pq, cap_pm, cap_tbest,
      cap_best;
} lbg_scratch;

struct ts_slice {
  uint32_t set, gen, image;
  ts_window window;
  ts_anchors anchors;
  int nclass;
  uint32_t i0[TS_MAX_CLASSES], i1[TS_MAX_CLASSES];
  ts_plane fine[TS_WIN_MAX_PLANES], coarse[TS_WIN_MAX_PLANES]; /* while building */
  /* The rows it read, kept for the next slice of the set (a re-slice
   * sends only the rows it lacks): fine rows [fy0, fy1) and coarse rows
   * [cy0, cy1) of every plane, label and validity rows [ay0, ay1). */
  ts_slice_held held;
  int cw;
  uint8_t *rows_fine[TS_WIN_MAX_PLANES], *rows_coarse[TS_WIN_MAX_PLANES];
  uint8_t *rows_labels, *rows_valid;
  ts_l1_set *cls;      /* nclass vector sets */
  uint32_t **penalty;  /* per class, indexed like the class set */
  int with_usage;
  ts_usage usage;
  /* Per-batch scratch, grown on demand. */
  uint32_t cap_q;
  size_t cap_bytes;
  uint8_t *qbuf, *mbuf;
  uint32_t *order;
  ts_l1_best *tbest; /* threads x cap_q */
  int cap_threads;
  /* The batch being scanned (read by the pool threads). */
  const ts_l1_impl *simd;
  uint32_t nq, qstart[TS_MAX_CLASSES + 1], vbytes;
  uint64_t usage_k;
  int masked;
  /* Partitioned (lbg.mode != TS_LBG_OFF): the codebook (centroids owned),
   * per class its partitions (cls[c] then holds them one after the other,
   * each from a group boundary), and the scratch of a two-stage batch. */
  ts_lbg_codebook lbg;
  slice_part *part;
  lbg_scratch lx;
};

/* slice_lbg.c: takes m's codebook (checked against the slice's set, its
 * centroids copied); sorts the slice's vectors, once built, by partition;
 * scans a batch gathered in qbuf/mbuf by class, each row's best into
 * lx.best. */
int ts__slice_lbg_take(ts_slice *s, const ts_slice_desc *m, char *err);
int ts__slice_partition(ts_slice *s, ts_pool *pool, char *err);
int ts__slice_scan_lbg(ts_slice *s, ts_pool *pool, int threads, uint64_t *pairs, char *err);
void ts__slice_lbg_free(ts_slice *s);

#endif
