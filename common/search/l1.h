/* l1.h - exact weighted L1 (sum of absolute differences) nearest-neighbour
 * scans over a set of uint8 feature vectors, with SIMD variants chosen at run
 * time (scalar, MMX, SSE2, AVX2, AVX-512BW).
 *
 * Why the layout below: a neighbourhood vector is short (24..600 bytes), so a
 * "one vector per SIMD register" scan spends most of its time on horizontal
 * reductions. Instead the reference set is stored *interleaved*: vectors are
 * grouped by TS_L1_GROUP (8), and for every 8-byte chunk k the group stores
 * chunk k of its 8 vectors side by side (64 bytes). One `psadbw` over those
 * 64 bytes against the query's chunk k broadcast to all lanes yields 8 partial
 * distances, one per reference vector, with no horizontal work at all. MMX
 * handles one lane per instruction, SSE2 two, AVX2 four, AVX-512 eight.
 *
 * A vector has `nchunks` 8-byte chunks, cut into `nparts` consecutive
 * *parts*, each with its own integer weight: fine and coarse neighbourhood
 * (seed 002 §3.3.2: two distances added with a weight), or the style and
 * each guide of a StyLit-style job, one weight per guide. Part p covers
 * chunks [part_end[p-1], part_end[p]), with part_end[-1] read as 0 and
 * part_end[nparts-1] == nchunks. ("Part", not "group": a group is the 8
 * interleaved vectors above.) The distance of query q to reference vector j
 * is
 *
 *   D(q, j) = sum over parts p of part_weight[p] * SAD(chunks of p)
 *             + penalty[j]                         (penalty optional)
 *
 * computed exactly in 64-bit integers, so every variant returns the same
 * result. The best match is the smallest D; ties go to the lowest index.
 * A weight of 0 makes its part count for nothing.
 *
 * Why weights stop at TS_L1_MAX_WEIGHT (2^32 - 1): the kernels sum a part's
 * chunks in 64-bit lanes and multiply once per part with a 32x32->64-bit
 * multiply (pmuludq), so a weight must fit 32 bits. That is also enough for
 * exactness: a chunk's SAD is at most 8 * 255 = 2040, a whole vector's at
 * most 2040 * TS_L1_MAX_CHUNKS < 2^20, hence sum_p weight_p * SAD_p <
 * 2^32 * 2^20 = 2^52 whatever the split into parts, and with a 32-bit
 * penalty D < 2^53, far from overflowing 64 bits (l1_impl.h keeps 2^62 and
 * up for its own markers).
 *
 * Masked scans take one mask per query, same length as the query, each byte
 * 0xFF (component used) or 0x00 (component ignored); ignored components add
 * nothing, whatever the query and reference hold there. */
#ifndef TS_L1_H
#define TS_L1_H

#include <stddef.h>
#include <stdint.h>

#define TS_L1_GROUP 8  /* vectors per interleaved group */
#define TS_L1_CHUNK 8  /* bytes per chunk */
#define TS_L1_ALIGN 64 /* alignment of set data */
#define TS_L1_MAX_CHUNKS 512
#define TS_L1_MAX_PARTS 32              /* weighted parts per vector */
#define TS_L1_MAX_WEIGHT 0xFFFFFFFFull /* largest part weight, 2^32 - 1 */

/* Interleaved reference set. Byte j of chunk k of vector v lives at
 *   data[((v / 8) * nchunks + k) * 64 + (v % 8) * 8 + j].
 * Lanes of the last group beyond nvec are zero and never reported. The
 * parts are set with ts_l1_set_weigh (or ts_l1_set_weigh_fine_coarse),
 * which checks them; the kernels trust them. */
typedef struct {
  uint8_t *data;    /* ngroups * nchunks * 64 bytes, 64-byte aligned */
  uint32_t nvec;    /* number of vectors */
  uint32_t ngroups; /* ceil(nvec / 8) */
  uint32_t nchunks; /* chunks per vector, 1..TS_L1_MAX_CHUNKS */
  uint32_t nparts;  /* weighted parts, 1..TS_L1_MAX_PARTS */
  uint32_t part_end[TS_L1_MAX_PARTS];    /* strictly increasing, last == nchunks */
  uint64_t part_weight[TS_L1_MAX_PARTS]; /* each <= TS_L1_MAX_WEIGHT */
} ts_l1_set;

/* Best match so far for one query. Scans only replace it with a strictly
 * better candidate (smaller dist, or equal dist and smaller index), so the
 * results of scans over disjoint ranges merge by calling them in any order on
 * the same ts_l1_best array. Initialise with ts_l1_best_reset. */
typedef struct {
  uint64_t dist;
  uint32_t index; /* vector index within the set */
  uint32_t pad_;
} ts_l1_best;

void ts_l1_best_reset(ts_l1_best *best, size_t n);
/* Merges `from` into `into` with the tie rule above. */
void ts_l1_best_merge(ts_l1_best *into, const ts_l1_best *from, size_t n);

/* Allocates a zeroed set for nvec vectors of nchunks chunks (0 or TS_ENOMEM /
 * TS_EINVAL), with one part of weight 1 over all chunks. */
int ts_l1_set_init(ts_l1_set *set, uint32_t nvec, uint32_t nchunks);
/* Sets the weighted parts: part p ends before chunk part_end[p] and has
 * weight weight[p] (see the top of this file). The ends must increase
 * strictly and the last be nchunks; weights are at most TS_L1_MAX_WEIGHT
 * (they are taken as uint64_t so that callers computing them in 64 bits get
 * an error, not a silent truncation). Returns 0, or TS_EINVAL with a
 * message, leaving the set unchanged. */
int ts_l1_set_weigh(ts_l1_set *set, uint32_t nparts, const uint32_t *part_end,
                    const uint64_t *weight, char *err);
/* The two-part case: chunks [0, nfine) weighted by wfine, [nfine, nchunks) by
 * wcoarse; an empty part is left out (its weight unused and
 * unchecked). Same errors. */
int ts_l1_set_weigh_fine_coarse(ts_l1_set *set, uint32_t nfine, uint64_t wfine,
                                uint64_t wcoarse, char *err);
void ts_l1_set_free(ts_l1_set *set);
/* Stores / reads vector v as nchunks*8 contiguous bytes. */
void ts_l1_set_put(ts_l1_set *set, uint32_t v, const uint8_t *vec);
void ts_l1_set_get(const ts_l1_set *set, uint32_t v, uint8_t *vec);

/* Exact distance of one query to vector v (reference for tests). */
uint64_t ts_l1_distance(const ts_l1_set *set, uint32_t v, const uint8_t *query,
                        const uint8_t *mask, const uint32_t *penalty);

/* Scan groups [g0, g1) of the set (vectors 8*g0 .. min(8*g1, nvec)-1).
 *   queries: nq queries, each nchunks*8 contiguous bytes
 *   masks:   NULL, or nq masks laid out like queries
 *   penalty: NULL, or one uint32 per vector of the set (indexed by vector
 *            index, at least ngroups*8 entries)
 *   best:    nq entries, updated in place (see ts_l1_best)
 * `single` handles nq == 1 (it is also called with larger nq and then loops);
 * `batch` streams each reference group once against all nq queries. */
typedef void ts_l1_scan_fn(const ts_l1_set *set, uint32_t g0, uint32_t g1,
                           const uint8_t *queries, const uint8_t *masks,
                           const uint32_t *penalty, uint32_t nq,
                           ts_l1_best *best);

typedef enum {
  TS_SIMD_SCALAR = 0,
  TS_SIMD_MMX,
  TS_SIMD_SSE2,
  TS_SIMD_AVX2,
  TS_SIMD_AVX512,
  TS_SIMD_COUNT
} ts_simd;

typedef struct {
  ts_simd id;
  const char *name; /* "scalar", "mmx", "sse2", "avx2", "avx512" */
  ts_l1_scan_fn *single;
  ts_l1_scan_fn *batch;
} ts_l1_impl;

/* The variant `id` if this CPU (and OS) supports it, else NULL. */
const ts_l1_impl *ts_l1_impl_get(ts_simd id);
/* Parses a variant name; returns TS_SIMD_COUNT when unknown. */
ts_simd ts_simd_from_name(const char *name);
/* The variant to use: the one named by the TEXSYN_SIMD environment variable
 * if set, else the best one the CPU supports. Returns 0, or TS_EINVAL /
 * TS_ENOTSUP with a message when TEXSYN_SIMD names an unknown or unsupported
 * variant. */
int ts_l1_select(const ts_l1_impl **out, char *err);

#endif
