/* l1.c - see l1.h. Reference sets, best-match bookkeeping, the plain
 * reference distance and run-time selection of the SIMD variant. The kernels
 * live in l1_scalar.c and l1_x86.c. */
#include "l1.h"

#include <cpuid.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "l1_impl.h"

static size_t set_offset(const ts_l1_set *set, uint32_t v, uint32_t k) {
  return (((size_t)(v / TS_L1_GROUP) * set->nchunks + k) * TS_L1_GROUP + v % TS_L1_GROUP) *
         TS_L1_CHUNK;
}

int ts_l1_set_init(ts_l1_set *set, uint32_t nvec, uint32_t nchunks) {
  memset(set, 0, sizeof(*set));
  if (nchunks == 0 || nchunks > TS_L1_MAX_CHUNKS) return TS_EINVAL;
  uint32_t ngroups = (uint32_t)(((uint64_t)nvec + TS_L1_GROUP - 1) / TS_L1_GROUP);
  size_t bytes = (size_t)ngroups * nchunks * TS_L1_GROUP * TS_L1_CHUNK;
  if (bytes > 0) {
    /* bytes is a multiple of 64, as aligned_alloc requires. */
    set->data = aligned_alloc(TS_L1_ALIGN, bytes);
    if (set->data == NULL) return TS_ENOMEM;
    memset(set->data, 0, bytes);
  }
  set->nvec = nvec;
  set->ngroups = ngroups;
  set->nchunks = nchunks;
  set->nparts = 1;
  set->part_end[0] = nchunks;
  set->part_weight[0] = 1;
  return 0;
}

int ts_l1_set_weigh(ts_l1_set *set, uint32_t nparts, const uint32_t *part_end,
                    const uint64_t *weight, char *err) {
  if (nparts == 0 || nparts > TS_L1_MAX_PARTS)
    return ts_error(err, TS_EINVAL, "%u weighted parts: need 1..%d", nparts, TS_L1_MAX_PARTS);
  for (uint32_t p = 0, begin = 0; p < nparts; begin = part_end[p++]) {
    if (part_end[p] <= begin || part_end[p] > set->nchunks)
      return ts_error(err, TS_EINVAL,
                      "weighted part %u ends at chunk %u: parts must be non-empty, in order "
                      "and within the vector's %u chunks (previous part ends at %u)",
                      p, part_end[p], set->nchunks, begin);
    if (weight[p] > TS_L1_MAX_WEIGHT)
      return ts_error(err, TS_EINVAL,
                      "weighted part %u: weight %llu is above the largest, %llu (2^32 - 1); "
                      "scale the weights down",
                      p, (unsigned long long)weight[p], (unsigned long long)TS_L1_MAX_WEIGHT);
  }
  if (part_end[nparts - 1] != set->nchunks)
    return ts_error(err, TS_EINVAL,
                    "weighted parts end at chunk %u, but the vectors have %u chunks: the last "
                    "part must end at the last chunk",
                    part_end[nparts - 1], set->nchunks);
  set->nparts = nparts;
  memcpy(set->part_end, part_end, nparts * sizeof(*part_end));
  memcpy(set->part_weight, weight, nparts * sizeof(*weight));
  return 0;
}

int ts_l1_set_weigh_fine_coarse(ts_l1_set *set, uint32_t nfine, uint64_t wfine,
                                uint64_t wcoarse, char *err) {
  uint32_t end[2] = {nfine, set->nchunks};
  uint64_t weight[2] = {wfine, wcoarse};
  if (nfine > set->nchunks)
    return ts_error(err, TS_EINVAL, "%u fine chunks, but the vectors have only %u", nfine,
                    set->nchunks);
  /* An empty part is left out, weight and all: all fine is one part, all
   * coarse too. */
  if (nfine == 0) return ts_l1_set_weigh(set, 1, end + 1, weight + 1, err);
  return ts_l1_set_weigh(set, nfine == set->nchunks ? 1 : 2, end, weight, err);
}

void ts_l1_set_free(ts_l1_set *set) {
  free(set->data);
  memset(set, 0, sizeof(*set));
}

void ts_l1_set_put(ts_l1_set *set, uint32_t v, const uint8_t *vec) {
  if (v >= set->nvec) return;
  for (uint32_t k = 0; k < set->nchunks; k++)
    memcpy(set->data + set_offset(set, v, k), vec + (size_t)k * TS_L1_CHUNK, TS_L1_CHUNK);
}

void ts_l1_set_get(const ts_l1_set *set, uint32_t v, uint8_t *vec) {
  if (v >= set->nvec) return;
  for (uint32_t k = 0; k < set->nchunks; k++)
    memcpy(vec + (size_t)k * TS_L1_CHUNK, set->data + set_offset(set, v, k), TS_L1_CHUNK);
}

void ts_l1_best_reset(ts_l1_best *best, size_t n) {
  for (size_t i = 0; i < n; i++) {
    best[i].dist = UINT64_MAX;
    best[i].index = UINT32_MAX;
    best[i].pad_ = 0;
  }
}

void ts_l1_best_merge(ts_l1_best *into, const ts_l1_best *from, size_t n) {
  for (size_t i = 0; i < n; i++)
    if (ts__l1_better(from[i].dist, from[i].index, &into[i])) into[i] = from[i];
}

void ts__l1_lanes_reset(ts__l1_lanes *lanes, size_t n) {
  for (size_t i = 0; i < n; i++) {
    for (int j = 0; j < TS_L1_GROUP; j++) {
      lanes[i].dist[j] = TS_L1_NONE;
      lanes[i].grp[j] = 0;
    }
  }
}

void ts__l1_lanes_reduce(const ts__l1_lanes *lanes, size_t n, ts_l1_best *best) {
  for (size_t i = 0; i < n; i++) {
    for (uint32_t j = 0; j < TS_L1_GROUP; j++) {
      uint64_t d = lanes[i].dist[j];
      uint32_t index = (uint32_t)lanes[i].grp[j] * TS_L1_GROUP + j;
      /* Padding lanes carry TS_L1_INVALID; untouched lanes TS_L1_NONE. */
      if (d < TS_L1_INVALID && ts__l1_better(d, index, &best[i])) {
        best[i].dist = d;
        best[i].index = index;
      }
    }
  }
}

uint64_t ts_l1_distance(const ts_l1_set *set, uint32_t v, const uint8_t *query,
                        const uint8_t *mask, const uint32_t *penalty) {
  uint64_t d = penalty != NULL ? penalty[v] : 0;
  for (uint32_t p = 0, k = 0; p < set->nparts; p++) {
    uint64_t sad = 0;
    for (; k < set->part_end[p]; k++) {
      const uint8_t *ref = set->data + set_offset(set, v, k);
      for (uint32_t j = 0; j < TS_L1_CHUNK; j++) {
        size_t at = (size_t)k * TS_L1_CHUNK + j;
        int m = mask != NULL ? mask[at] : 0xFF;
        int a = ref[j] & m, b = query[at] & m;
        sad += (uint64_t)(a > b ? a - b : b - a);
      }
    }
    d += sad * set->part_weight[p];
  }
  return d;
}

/* ---- variant table and CPU detection ---- */

static const ts_l1_impl impls[TS_SIMD_COUNT] = {
    {TS_SIMD_SCALAR, "scalar", ts__l1_scalar_single, ts__l1_scalar_batch},
    {TS_SIMD_MMX, "mmx", ts__l1_mmx_single, ts__l1_mmx_batch},
    {TS_SIMD_SSE2, "sse2", ts__l1_sse2_single, ts__l1_sse2_batch},
    {TS_SIMD_AVX2, "avx2", ts__l1_avx2_single, ts__l1_avx2_batch},
    {TS_SIMD_AVX512, "avx512", ts__l1_avx512_single, ts__l1_avx512_batch},
};

ts_simd ts_simd_from_name(const char *name) {
  for (int i = 0; i < TS_SIMD_COUNT; i++)
    if (name != NULL && strcmp(name, impls[i].name) == 0) return (ts_simd)i;
  return TS_SIMD_COUNT;
}

/* XCR0: which register states the OS saves on context switch. Without the
 * YMM (and for AVX-512 the opmask/ZMM) bits set the instructions fault or
 * lose state even when CPUID lists them. */
static uint64_t read_xcr0(void) {
  uint32_t lo, hi;
  __asm__ volatile("xgetbv" : "=a"(lo), "=d"(hi) : "c"(0));
  return ((uint64_t)hi << 32) | lo;
}

#define XCR0_SSE_AVX 0x06u /* XMM | YMM */
#define XCR0_AVX512 0xE6u  /* XMM | YMM | opmask | ZMM_Hi256 | Hi16_ZMM */

static int cpu_supports(ts_simd id) {
  unsigned a, b, c, d;
  if (id == TS_SIMD_SCALAR) return 1;
  if (!__get_cpuid(1, &a, &b, &c, &d)) return 0;
  /* The MMX kernel needs psadbw on MMX registers, which came with SSE
   * (AMD: MMX extensions), not with plain MMX. */
  if (id == TS_SIMD_MMX) return (d & bit_MMX) && (d & bit_SSE);
  if (id == TS_SIMD_SSE2) return (d & bit_SSE2) != 0;
  if (!(c & bit_OSXSAVE) || !(c & bit_AVX)) return 0;
  uint64_t xcr0 = read_xcr0();
  unsigned b7, c7, d7;
  if (!__get_cpuid_count(7, 0, &a, &b7, &c7, &d7)) return 0;
  if (id == TS_SIMD_AVX2) return (xcr0 & XCR0_SSE_AVX) == XCR0_SSE_AVX && (b7 & bit_AVX2);
  if (id == TS_SIMD_AVX512)
    return (xcr0 & XCR0_AVX512) == XCR0_AVX512 && (b7 & bit_AVX512F) && (b7 & bit_AVX512BW);
  return 0;
}

/* Bit i set when variant i runs here. Computed once: in a VM every CPUID
 * exits to the hypervisor. Racing first calls store the same value. */
static unsigned supported_set(void) {
  static _Atomic unsigned cached = 0; /* bit 31 marks "computed" */
  unsigned set = atomic_load_explicit(&cached, memory_order_relaxed);
  if (set == 0) {
    set = 1u << 31;
    for (int i = 0; i < TS_SIMD_COUNT; i++)
      if (cpu_supports((ts_simd)i)) set |= 1u << i;
    atomic_store_explicit(&cached, set, memory_order_relaxed);
  }
  return set;
}

static int supported(ts_simd id) { return (supported_set() >> id) & 1; }

const ts_l1_impl *ts_l1_impl_get(ts_simd id) {
  if ((int)id < 0 || id >= TS_SIMD_COUNT || !supported(id)) return NULL;
  return &impls[id];
}

/* Appends the names of all variants (or only the supported ones). */
static void list_names(char *buf, size_t len, int supported_only) {
  size_t at = 0;
  buf[0] = '\0';
  for (int i = 0; i < TS_SIMD_COUNT && at < len; i++) {
    if (supported_only && !supported((ts_simd)i)) continue;
    int n = snprintf(buf + at, len - at, "%s%s", at > 0 ? ", " : "", impls[i].name);
    if (n < 0) break;
    at += (size_t)n;
  }
}

int ts_l1_select(const ts_l1_impl **out, char *err) {
  char names[128];
  const char *env = getenv("TEXSYN_SIMD");
  if (env == NULL || env[0] == '\0') {
    int i = TS_SIMD_COUNT - 1;
    while (i > TS_SIMD_SCALAR && !supported((ts_simd)i)) i--;
    *out = &impls[i];
    return 0;
  }
  *out = NULL;
  ts_simd id = ts_simd_from_name(env);
  if (id == TS_SIMD_COUNT) {
    list_names(names, sizeof(names), 0);
    return ts_error(err, TS_EINVAL, "TEXSYN_SIMD=\"%s\" names no SIMD variant; valid names: %s",
                    env, names);
  }
  if (!supported(id)) {
    list_names(names, sizeof(names), 1);
    return ts_error(err, TS_ENOTSUP,
                    "TEXSYN_SIMD=%s: this CPU or OS does not support it; supported here: %s",
                    env, names);
  }
  *out = &impls[id];
  return 0;
}
