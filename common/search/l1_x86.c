/* l1_x86.c - the x86 SIMD L1 kernels: MMX (inline assembly) and SSE2, AVX2
 * and AVX-512BW (l1_tmpl.h instantiated three times).
 *
 * Like libdeflate, every variant is compiled into every build without -mavx2
 * and friends: each function carries a target attribute, and l1.c only hands
 * out a variant after CPUID and XGETBV said the CPU and OS support it.
 *
 * A SIMD scan is cut three ways: the queries into slices of up to 64 whose
 * per-lane running bests live on the stack; the groups into blocks of about
 * TS_L1_BLOCK_BYTES that stay in L1; and each block into passes, one per
 * sub-vector and run of up to TS_QMAX queries (l1_tmpl.h). Each block is
 * thus read from memory once per slice and from L1 by every pass. */
#include <immintrin.h>
#include <string.h>

#include "l1_impl.h"

#define TS_L1_QBATCH 64     /* queries whose lane states live on the stack */
#define TS_L1_BMAX 64       /* most groups per block */
#define TS_L1_QMBYTES 16384 /* masked queries of a slice, pre-ANDed */

/* Arguments of one pass (see TS_K(pass) in l1_tmpl.h). */
typedef struct {
  const uint8_t *ref;         /* group ga, chunk 0, current sub-vector */
  size_t gstride, vbytes;     /* bytes per group, per vector */
  uint32_t ga, ngr;           /* first group, number of groups */
  uint32_t nchunks, nparts;
  const uint32_t *part_end;   /* the set's parts (l1.h) */
  const uint64_t *weight;     /* their weights, < 2^32: 32x32-bit multiplies */
  const uint8_t *q[6], *m[6]; /* the pass's queries (masked: pre-ANDed) */
  uint64_t *dist[6], *grp[6]; /* their lane states, current sub-vector */
  const uint64_t *pen;        /* widened penalties of group ga, or NULL */
  const char *pf;             /* group ga one block ahead, to prefetch */
  uint32_t pfn;               /* groups to prefetch there (0: none) */
} ts__l1_pass;

typedef void ts__l1_pass_fn(const ts__l1_pass *p);

/* State of one scan call; it lives on the caller's stack (about 28 KB). */
typedef struct {
  const ts_l1_set *set;
  const uint8_t *queries, *masks; /* current slice of the batch */
  uint32_t block;                 /* groups per block */
  uint32_t slice;                 /* queries per slice */
  ts__l1_lanes lanes[TS_L1_QBATCH];
  alignas(64) uint64_t pen[TS_L1_BMAX * TS_L1_GROUP];
  alignas(64) uint8_t qmasked[TS_L1_QMBYTES];
} ts__l1_scan;

static inline uint64_t load64(const uint8_t *p) {
  uint64_t x;
  memcpy(&x, p, sizeof(x));
  return x;
}

static void scan_init(ts__l1_scan *sc, const ts_l1_set *set, const uint8_t *masks) {
  size_t vbytes = (size_t)set->nchunks * TS_L1_CHUNK;
  size_t block = TS_L1_BLOCK_BYTES / (vbytes * TS_L1_GROUP);
  sc->set = set;
  sc->block = (uint32_t)(block < 1 ? 1 : block > TS_L1_BMAX ? TS_L1_BMAX : block);
  sc->slice = TS_L1_QBATCH;
  if (masks != NULL && TS_L1_QMBYTES / vbytes < TS_L1_QBATCH)
    sc->slice = (uint32_t)(TS_L1_QMBYTES / vbytes);
}

/* Starts the slice of queries [qa, qa + qn): lane states reset, masked
 * queries ANDed with their masks once, so passes only mask the reference. */
static void scan_slice(ts__l1_scan *sc, const uint8_t *queries, const uint8_t *masks,
                       uint32_t qa, uint32_t qn) {
  size_t vbytes = (size_t)sc->set->nchunks * TS_L1_CHUNK;
  ts__l1_lanes_reset(sc->lanes, qn);
  sc->queries = queries + qa * vbytes;
  sc->masks = NULL;
  if (masks != NULL) {
    sc->masks = masks + qa * vbytes;
    for (size_t i = 0; i < qn * vbytes; i++) sc->qmasked[i] = sc->queries[i] & sc->masks[i];
    sc->queries = sc->qmasked;
  }
}

static void pass_init(ts__l1_pass *p, const ts__l1_scan *sc, uint32_t ga, uint32_t gb) {
  const ts_l1_set *set = sc->set;
  p->vbytes = (size_t)set->nchunks * TS_L1_CHUNK;
  p->gstride = p->vbytes * TS_L1_GROUP;
  p->ga = ga;
  p->ngr = gb - ga;
  p->nchunks = set->nchunks;
  p->nparts = set->nparts;
  p->part_end = set->part_end;
  p->weight = set->part_weight;
  p->pfn = 0;
}

/* Whether, and for how many groups, the pass over [ga, gb) that comes first
 * should prefetch the same groups one block ahead (within the scan's range,
 * up to g1). Only worth it when the block is passed over more than once: the
 * first pass over a block would otherwise wait on DRAM, while a lone pass is
 * a plain stream that the hardware prefetcher handles alone. */
static void pass_prefetch(ts__l1_pass *p, const ts__l1_scan *sc, uint32_t g1, int passes) {
  uint32_t ahead = p->ga + sc->block;
  p->pfn = 0;
  if (passes < 2 || ahead >= g1) return;
  p->pf = (const char *)sc->set->data + ahead * p->gstride;
  p->pfn = g1 - ahead < p->ngr ? g1 - ahead : p->ngr;
}

/* Widens the penalties of groups [b0, b1) to 64 bits (sc->pen) and returns
 * where the full groups end: the padding lanes of a partial last group get
 * TS_L1_INVALID, which routes that group through the penalty kernels. */
static uint32_t block_pen(ts__l1_scan *sc, uint32_t b0, uint32_t b1, const uint32_t *penalty) {
  const ts_l1_set *set = sc->set;
  uint32_t full = b1;
  if (b1 == set->ngroups && set->nvec % TS_L1_GROUP != 0) full = b1 - 1;
  for (uint32_t g = penalty != NULL ? b0 : full; g < b1; g++) {
    for (uint32_t j = 0; j < TS_L1_GROUP; j++) {
      uint32_t v = g * TS_L1_GROUP + j;
      uint64_t pv = v >= set->nvec ? TS_L1_INVALID : penalty != NULL ? penalty[v] : 0;
      sc->pen[(size_t)(g - b0) * TS_L1_GROUP + j] = pv;
    }
  }
  return full;
}

/* ---- SSE2: 2 lanes per register, 16 registers ---- */
#define TS_K(name) ts__l1_sse2_##name
#define TS_TARGET __attribute__((target("sse2")))
#define TS_V __m128i
#define TS_VB 16
#define TS_QMAX 2
#define TS_LOAD(p) _mm_load_si128((const __m128i *)(const void *)(p))
#define TS_STORE(p, v) _mm_store_si128((__m128i *)(void *)(p), v)
#define TS_BCAST(x) _mm_set1_epi64x((long long)(x))
#define TS_ZERO() _mm_setzero_si128()
#define TS_ADD(a, b) _mm_add_epi64(a, b)
#define TS_CHUNK(p) _mm_set1_epi64x((long long)load64(p))
#define TS_ANDCHUNK(v, p) _mm_and_si128(v, TS_CHUNK(p))
#define TS_SAD(a, b) _mm_sad_epu8(a, b)
#define TS_MULW(a, w) _mm_mul_epu32(a, w)
/* No 64-bit compare before SSE4.2: d - best is negative exactly when
 * d < best, as both are below 2^63; spread the sign over the lane. */
#define TS_UPDATE(best, grp, d, gv)                                                     \
  do {                                                                                  \
    __m128i lt_ = _mm_shuffle_epi32(_mm_srai_epi32(_mm_sub_epi64(d, best), 31), 0xF5);  \
    best = _mm_or_si128(_mm_and_si128(lt_, d), _mm_andnot_si128(lt_, best));            \
    grp = _mm_or_si128(_mm_and_si128(lt_, gv), _mm_andnot_si128(lt_, grp));             \
  } while (0)
#include "l1_tmpl.h"

/* ---- AVX2: 4 lanes per register, 16 registers ---- */
#define TS_K(name) ts__l1_avx2_##name
#define TS_TARGET __attribute__((target("avx2")))
#define TS_V __m256i
#define TS_VB 32
#define TS_QMAX 3
#define TS_LOAD(p) _mm256_load_si256((const __m256i *)(const void *)(p))
#define TS_STORE(p, v) _mm256_store_si256((__m256i *)(void *)(p), v)
#define TS_BCAST(x) _mm256_set1_epi64x((long long)(x))
#define TS_ZERO() _mm256_setzero_si256()
#define TS_ADD(a, b) _mm256_add_epi64(a, b)
#define TS_CHUNK(p) _mm256_set1_epi64x((long long)load64(p))
#define TS_ANDCHUNK(v, p) _mm256_and_si256(v, TS_CHUNK(p))
#define TS_SAD(a, b) _mm256_sad_epu8(a, b)
#define TS_MULW(a, w) _mm256_mul_epu32(a, w)
/* Signed compare is exact: all distances are below 2^63. */
#define TS_UPDATE(best, grp, d, gv)                   \
  do {                                                \
    __m256i lt_ = _mm256_cmpgt_epi64(best, d);        \
    best = _mm256_blendv_epi8(best, d, lt_);          \
    grp = _mm256_blendv_epi8(grp, gv, lt_);           \
  } while (0)
#include "l1_tmpl.h"

/* ---- AVX-512BW: a whole group chunk per register, 32 registers ---- */
#define TS_K(name) ts__l1_avx512_##name
#define TS_TARGET __attribute__((target("avx512f,avx512bw")))
#define TS_V __m512i
#define TS_VB 64
#define TS_QMAX 6
#define TS_LOAD(p) _mm512_load_si512((const void *)(p))
#define TS_STORE(p, v) _mm512_store_si512((void *)(p), v)
#define TS_BCAST(x) _mm512_set1_epi64((long long)(x))
#define TS_ZERO() _mm512_setzero_si512()
#define TS_ADD(a, b) _mm512_add_epi64(a, b)
#define TS_CHUNK(p) _mm512_set1_epi64((long long)load64(p))
#define TS_ANDCHUNK(v, p) _mm512_and_si512(v, TS_CHUNK(p))
#define TS_SAD(a, b) _mm512_sad_epu8(a, b)
#define TS_MULW(a, w) _mm512_mul_epu32(a, w)
/* vpminuq carries the distance chain (1-cycle latency); the compare only
 * feeds the index blend. A compare + masked-move chain measured ~8 cycles
 * per group on Zen 5, longer than a group's psadbw work. */
#define TS_UPDATE(best, grp, d, gv)                            \
  do {                                                         \
    __mmask8 lt_ = _mm512_cmplt_epu64_mask(d, best);           \
    best = _mm512_min_epu64(best, d);                          \
    grp = _mm512_mask_mov_epi64(grp, lt_, gv);                 \
  } while (0)
#include "l1_tmpl.h"

/* ---- MMX: psadbw on 8-byte MMX registers, one lane at a time ----
 *
 * Written in assembly because GCC implements the MMX intrinsics with SSE
 * registers on x86-64; this keeps the variant what it claims to be (the
 * 2004 kernel) with both compilers. Each call sums n chunks for 4
 * consecutive lanes of a group into out[0..3]; n >= 1. */
static void mmx_sad4(const uint8_t *ref, const uint8_t *query, uint32_t n, uint32_t out[4]) {
  __asm__ volatile(
      "pxor %%mm0, %%mm0\n\t"
      "pxor %%mm1, %%mm1\n\t"
      "pxor %%mm2, %%mm2\n\t"
      "pxor %%mm3, %%mm3\n"
      "1:\n\t"
      "movq (%[q]), %%mm4\n\t"
      "movq (%[r]), %%mm5\n\t"
      "movq 8(%[r]), %%mm6\n\t"
      "psadbw %%mm4, %%mm5\n\t"
      "psadbw %%mm4, %%mm6\n\t"
      "paddd %%mm5, %%mm0\n\t"
      "paddd %%mm6, %%mm1\n\t"
      "movq 16(%[r]), %%mm5\n\t"
      "movq 24(%[r]), %%mm6\n\t"
      "psadbw %%mm4, %%mm5\n\t"
      "psadbw %%mm4, %%mm6\n\t"
      "paddd %%mm5, %%mm2\n\t"
      "paddd %%mm6, %%mm3\n\t"
      "add $8, %[q]\n\t"
      "add $64, %[r]\n\t"
      "dec %[n]\n\t"
      "jnz 1b\n\t"
      "movd %%mm0, 0(%[out])\n\t"
      "movd %%mm1, 4(%[out])\n\t"
      "movd %%mm2, 8(%[out])\n\t"
      "movd %%mm3, 12(%[out])"
      : [q] "+r"(query), [r] "+r"(ref), [n] "+r"(n)
      : [out] "r"(out)
      : "mm0", "mm1", "mm2", "mm3", "mm4", "mm5", "mm6", "memory", "cc");
}

/* Same with a mask: query and reference bytes are ANDed with it. */
static void mmx_sad4_masked(const uint8_t *ref, const uint8_t *query, const uint8_t *mask,
                            uint32_t n, uint32_t out[4]) {
  __asm__ volatile(
      "pxor %%mm0, %%mm0\n\t"
      "pxor %%mm1, %%mm1\n\t"
      "pxor %%mm2, %%mm2\n\t"
      "pxor %%mm3, %%mm3\n"
      "1:\n\t"
      "movq (%[m]), %%mm7\n\t"
      "movq (%[q]), %%mm4\n\t"
      "pand %%mm7, %%mm4\n\t"
      "movq (%[r]), %%mm5\n\t"
      "movq 8(%[r]), %%mm6\n\t"
      "pand %%mm7, %%mm5\n\t"
      "pand %%mm7, %%mm6\n\t"
      "psadbw %%mm4, %%mm5\n\t"
      "psadbw %%mm4, %%mm6\n\t"
      "paddd %%mm5, %%mm0\n\t"
      "paddd %%mm6, %%mm1\n\t"
      "movq 16(%[r]), %%mm5\n\t"
      "movq 24(%[r]), %%mm6\n\t"
      "pand %%mm7, %%mm5\n\t"
      "pand %%mm7, %%mm6\n\t"
      "psadbw %%mm4, %%mm5\n\t"
      "psadbw %%mm4, %%mm6\n\t"
      "paddd %%mm5, %%mm2\n\t"
      "paddd %%mm6, %%mm3\n\t"
      "add $8, %[q]\n\t"
      "add $8, %[m]\n\t"
      "add $64, %[r]\n\t"
      "dec %[n]\n\t"
      "jnz 1b\n\t"
      "movd %%mm0, 0(%[out])\n\t"
      "movd %%mm1, 4(%[out])\n\t"
      "movd %%mm2, 8(%[out])\n\t"
      "movd %%mm3, 12(%[out])"
      : [q] "+r"(query), [m] "+r"(mask), [r] "+r"(ref), [n] "+r"(n)
      : [out] "r"(out)
      : "mm0", "mm1", "mm2", "mm3", "mm4", "mm5", "mm6", "mm7", "memory", "cc");
}

/* Chunks [k0, k1) of one group, as two runs of 4 lanes (ts__l1_part_fn). */
static void mmx_part(const uint8_t *grp, const uint8_t *query, const uint8_t *mask, uint32_t k0,
                     uint32_t k1, uint32_t sad[TS_L1_GROUP]) {
  const uint8_t *q = query + (size_t)k0 * TS_L1_CHUNK;
  for (uint32_t h = 0; h < 2; h++) {
    const uint8_t *r = grp + (size_t)k0 * 64 + 32 * h;
    if (mask == NULL)
      mmx_sad4(r, q, k1 - k0, sad + 4 * h);
    else
      mmx_sad4_masked(r, q, mask + (size_t)k0 * TS_L1_CHUNK, k1 - k0, sad + 4 * h);
  }
}

static void mmx_group(const ts_l1_set *set, const uint8_t *grp, const uint8_t *query,
                      const uint8_t *mask, uint32_t sad[][TS_L1_GROUP]) {
  ts__l1_group_parts(set, grp, query, mask, mmx_part, sad);
}

/* The driver between two groups is integer C code, so one emms when the
 * scan is over is enough to hand the x87 state back. */
void ts__l1_mmx_single(const ts_l1_set *set, uint32_t g0, uint32_t g1, const uint8_t *queries,
                       const uint8_t *masks, const uint32_t *penalty, uint32_t nq,
                       ts_l1_best *best) {
  ts__l1_scan_groups(set, g0, g1, queries, masks, penalty, nq, best, 0, mmx_group);
  __asm__ volatile("emms");
}

void ts__l1_mmx_batch(const ts_l1_set *set, uint32_t g0, uint32_t g1, const uint8_t *queries,
                      const uint8_t *masks, const uint32_t *penalty, uint32_t nq,
                      ts_l1_best *best) {
  ts__l1_scan_groups(set, g0, g1, queries, masks, penalty, nq, best, 1, mmx_group);
  __asm__ volatile("emms");
}
