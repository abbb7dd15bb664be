/* l1_impl.h - internals shared by the L1 kernel files (l1.c, l1_scalar.c,
 * l1_x86.c); not part of the public interface. */
#ifndef TS_L1_IMPL_H
#define TS_L1_IMPL_H

#include <stdalign.h>
#include <stddef.h>
#include <stdint.h>

#include "l1.h"

/* Any real distance is below 2^53 (see l1.h: the weighted SADs sum to less
 * than 2^52, plus a 32-bit penalty). Padding lanes of the last group get TS_L1_INVALID added,
 * so they never beat a real vector and are recognised when lanes are
 * reduced. TS_L1_NONE marks a lane that has seen nothing; both stay below
 * 2^63, which lets the AVX2 and SSE2 kernels compare with signed 64-bit ops. */
#define TS_L1_INVALID ((uint64_t)1 << 62)
#define TS_L1_NONE ((uint64_t)INT64_MAX)

/* Running best of one query per lane: lane j has seen vectors 8*g + j and
 * keeps the smallest distance and the first group g that reached it. */
typedef struct {
  alignas(64) uint64_t dist[TS_L1_GROUP];
  uint64_t grp[TS_L1_GROUP];
} ts__l1_lanes;

/* True when (dist, index) beats *best under the "smallest distance, then
 * smallest index" rule. */
static inline int ts__l1_better(uint64_t dist, uint32_t index, const ts_l1_best *best) {
  return dist < best->dist || (dist == best->dist && index < best->index);
}

void ts__l1_lanes_reset(ts__l1_lanes *lanes, size_t n);
/* Reduces each query's lanes to one candidate and merges it into best. */
void ts__l1_lanes_reduce(const ts__l1_lanes *lanes, size_t n, ts_l1_best *best);

/* SADs of one query to the 8 vectors of one group over chunks [k0, k1)
 * (one weighted part), k0 < k1. `grp` points at the group; `query` and
 * `mask` (NULL: none) at the whole vector. */
typedef void ts__l1_part_fn(const uint8_t *grp, const uint8_t *query, const uint8_t *mask,
                            uint32_t k0, uint32_t k1, uint32_t sad[TS_L1_GROUP]);

/* SADs of one query to the 8 vectors of the group at `grp`, part by part
 * (sad[p] for part p): `part` once per part. Inline, so that each kernel's
 * group function (below) calls its part function directly. */
static inline void ts__l1_group_parts(const ts_l1_set *set, const uint8_t *grp,
                                      const uint8_t *query, const uint8_t *mask,
                                      ts__l1_part_fn *part, uint32_t sad[][TS_L1_GROUP]) {
  for (uint32_t p = 0, k = 0; p < set->nparts; k = set->part_end[p++])
    part(grp, query, mask, k, set->part_end[p], sad[p]);
}

/* ts__l1_group_parts with the kernel's part function filled in. */
typedef void ts__l1_group_fn(const ts_l1_set *set, const uint8_t *grp, const uint8_t *query,
                             const uint8_t *mask, uint32_t sad[][TS_L1_GROUP]);
/* Scan driver for the kernels that work one group at a time (scalar, MMX);
 * `batch` picks the cache-blocked loop order. */
void ts__l1_scan_groups(const ts_l1_set *set, uint32_t g0, uint32_t g1, const uint8_t *queries,
                        const uint8_t *masks, const uint32_t *penalty, uint32_t nq,
                        ts_l1_best *best, int batch, ts__l1_group_fn *fn);

/* Reference sets are walked in blocks of about this many bytes, small enough
 * to stay in L1 while every query of a batch passes over them, next to the
 * queries and lane states, also on CPUs with a 32 KB L1 (32 KB blocks were
 * only ~2% faster on Zen 5's 48 KB L1). */
#define TS_L1_BLOCK_BYTES 16384

ts_l1_scan_fn ts__l1_scalar_single, ts__l1_scalar_batch;
ts_l1_scan_fn ts__l1_mmx_single, ts__l1_mmx_batch;
ts_l1_scan_fn ts__l1_sse2_single, ts__l1_sse2_batch;
ts_l1_scan_fn ts__l1_avx2_single, ts__l1_avx2_batch;
ts_l1_scan_fn ts__l1_avx512_single, ts__l1_avx512_batch;

#endif
