/* l1_scalar.c - portable scalar L1 kernel, and the group-at-a-time scan
 * driver it shares with the MMX kernel. */
#include <string.h>

#include "l1_impl.h"

/* Weighs one group's SADs and folds them into the query's best match,
 * vector by vector in index order, so strict improvement alone gives the
 * tie rule. Lane by lane, as the SADs were stored: reading 16 bytes over
 * the MMX kernel's fresh 4-byte stores (a vectorised weighting) stalled on
 * store forwarding and cost that scan 25%. The first two parts, all the
 * MRF has, are unrolled like in l1_tmpl.h: looping over them cost the MMX
 * scan another 7%. */
static void fold_group(const ts_l1_set *set, uint32_t g, const uint32_t sad[][TS_L1_GROUP],
                       const uint32_t *penalty, ts_l1_best *best) {
  const uint32_t np = set->nparts;
  const uint64_t w0 = set->part_weight[0], w1 = np > 1 ? set->part_weight[1] : 0;
  for (uint32_t j = 0; j < TS_L1_GROUP; j++) {
    uint32_t v = g * TS_L1_GROUP + j;
    if (v >= set->nvec) break;
    uint64_t d = penalty != NULL ? penalty[v] : 0;
    d += sad[0][j] * w0 + (np > 1 ? sad[1][j] * w1 : 0);
    for (uint32_t p = 2; p < np; p++) d += (uint64_t)sad[p][j] * set->part_weight[p];
    if (ts__l1_better(d, v, best)) {
      best->dist = d;
      best->index = v;
    }
  }
}

void ts__l1_scan_groups(const ts_l1_set *set, uint32_t g0, uint32_t g1, const uint8_t *queries,
                        const uint8_t *masks, const uint32_t *penalty, uint32_t nq,
                        ts_l1_best *best, int batch, ts__l1_group_fn *fn) {
  size_t vbytes = (size_t)set->nchunks * TS_L1_CHUNK;
  size_t gbytes = vbytes * TS_L1_GROUP;
  if (g1 > set->ngroups) g1 = set->ngroups;
  if (g0 >= g1) return;
  /* Batches revisit an L1-sized block of groups for every query; a single
   * query just streams the range. */
  uint32_t block = g1 - g0;
  if (batch && gbytes < TS_L1_BLOCK_BYTES) block = (uint32_t)(TS_L1_BLOCK_BYTES / gbytes);
  else if (batch) block = 1;
  for (uint32_t b0 = g0; b0 < g1; b0 += block) {
    uint32_t b1 = g1 - b0 < block ? g1 : b0 + block;
    for (uint32_t q = 0; q < nq; q++) {
      const uint8_t *query = queries + q * vbytes;
      const uint8_t *mask = masks != NULL ? masks + q * vbytes : NULL;
      for (uint32_t g = b0; g < b1; g++) {
        uint32_t sad[TS_L1_MAX_PARTS][TS_L1_GROUP];
        fn(set, set->data + g * gbytes, query, mask, sad);
        fold_group(set, g, sad, penalty, best + q);
      }
    }
  }
}

static void scalar_part(const uint8_t *grp, const uint8_t *query, const uint8_t *mask,
                        uint32_t k0, uint32_t k1, uint32_t sad[TS_L1_GROUP]) {
  memset(sad, 0, sizeof(uint32_t) * TS_L1_GROUP);
  for (uint32_t k = k0; k < k1; k++) {
    uint8_t q[TS_L1_CHUNK], m[TS_L1_CHUNK];
    for (int j = 0; j < TS_L1_CHUNK; j++) {
      m[j] = mask != NULL ? mask[k * TS_L1_CHUNK + j] : 0xFF;
      q[j] = query[k * TS_L1_CHUNK + j] & m[j];
    }
    const uint8_t *chunk = grp + (size_t)k * TS_L1_GROUP * TS_L1_CHUNK;
    for (int lane = 0; lane < TS_L1_GROUP; lane++) {
      uint32_t s = 0;
      for (int j = 0; j < TS_L1_CHUNK; j++) {
        int r = chunk[lane * TS_L1_CHUNK + j] & m[j];
        s += (uint32_t)(r > q[j] ? r - q[j] : q[j] - r);
      }
      sad[lane] += s;
    }
  }
}

static void scalar_group(const ts_l1_set *set, const uint8_t *grp, const uint8_t *query,
                         const uint8_t *mask, uint32_t sad[][TS_L1_GROUP]) {
  ts__l1_group_parts(set, grp, query, mask, scalar_part, sad);
}

void ts__l1_scalar_single(const ts_l1_set *set, uint32_t g0, uint32_t g1, const uint8_t *queries,
                          const uint8_t *masks, const uint32_t *penalty, uint32_t nq,
                          ts_l1_best *best) {
  ts__l1_scan_groups(set, g0, g1, queries, masks, penalty, nq, best, 0, scalar_group);
}

void ts__l1_scalar_batch(const ts_l1_set *set, uint32_t g0, uint32_t g1, const uint8_t *queries,
                         const uint8_t *masks, const uint32_t *penalty, uint32_t nq,
                         ts_l1_best *best) {
  ts__l1_scan_groups(set, g0, g1, queries, masks, penalty, nq, best, 1, scalar_group);
}
