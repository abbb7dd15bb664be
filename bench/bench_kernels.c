/* bench_kernels.c - throughput of the L1 scan kernels (common/search/l1.h).
 *
 * For every SIMD variant this CPU supports, measures single-query scans and
 * batched scans (32 and 128 queries), over a reference set that fits in L2
 * (256 KB, "cache") and one that does not fit in any cache (256 MB, "mem"),
 * for three vector shapes: 7 chunks with 3 fine (W_N = 7: fine L 20 B +
 * coarse 25 B, padded), 12 chunks with 5 fine, and 20 chunks in 5 weighted
 * parts (StyLit-like: style and four guides), which takes the kernels' loop
 * over parts beyond the second. It also measures the machine's
 * memory read bandwidth (streaming sum over 512 MB, 1 and 2 threads), so the
 * "mem" rows can be read against it.
 *
 * Units: GB/s counts nchunks*8 bytes of reference data per vector *per
 * query* (a batch of 32 scanning 1 GB counts 32 GB); pairs/s counts
 * vector-query comparisons; B/cycle divides bytes/s by the core clock,
 * measured with a calibrated busy loop (a chain of dependent integer adds,
 * one per cycle, timed with clock_gettime) right before every repetition,
 * since the clock of a shared or boosting machine moves. The TSC rate is
 * printed too; it is not the core clock on boosting CPUs. Every number is
 * the median of 5 repetitions.
 *
 * Usage: bench_kernels [--quick] [--csv FILE] [--variant NAME] */
#include <immintrin.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "error.h"
#include "l1.h"
#include "rng.h"

#define REPS 5
#define CACHE_BYTES (256u << 10)
#define MEM_BYTES (256u << 20)
#define STREAM_BYTES (512u << 20)
/* Consecutive "mem" repetitions start this far apart, more than the last
 * level cache, so every repetition reads cold data. */
#define MEM_STRIDE (64u << 20)

typedef struct {
  int quick;
  const char *csv;
  int only; /* variant index or -1 */
  double core_hz, tsc_hz;
  FILE *out;
} bench;

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + (double)t.tv_nsec * 1e-9;
}

static int cmp_double(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return x < y ? -1 : x > y;
}

static double median(double *v, int n) {
  qsort(v, (size_t)n, sizeof(double), cmp_double);
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/* ---- clock ---- */

/* 8 dependent adds per iteration: one cycle each on every x86 core, while
 * the loop counter runs alongside. */
static double busy_loop_hz(uint64_t iters) {
  uint64_t x = 0;
  double t0 = now();
  __asm__ volatile(
      "1:\n\t"
      "add $1, %0\n\tadd $1, %0\n\tadd $1, %0\n\tadd $1, %0\n\t"
      "add $1, %0\n\tadd $1, %0\n\tadd $1, %0\n\tadd $1, %0\n\t"
      "dec %1\n\tjnz 1b"
      : "+r"(x), "+r"(iters)
      :
      : "cc");
  double t1 = now();
  return (double)x / (t1 - t0);
}

static void measure_clock(bench *b) {
  double hz[REPS], tsc[REPS];
  busy_loop_hz(20000000); /* let the clock ramp up */
  for (int i = 0; i < REPS; i++) {
    double t0 = now();
    uint64_t c0 = __rdtsc();
    hz[i] = busy_loop_hz(5000000);
    uint64_t c1 = __rdtsc();
    tsc[i] = (double)(c1 - c0) / (now() - t0);
  }
  b->core_hz = median(hz, REPS);
  b->tsc_hz = median(tsc, REPS);
}

/* The core clock right now (about 2 ms). */
static double clock_now(void) { return busy_loop_hz(1000000); }

/* Medians over the repetitions of one table row. */
typedef struct {
  double bytes[REPS], pairs[REPS], per_cycle[REPS];
} row;

static void row_add(row *r, int i, double bytes_per_s, double pairs_per_s, double hz) {
  r->bytes[i] = bytes_per_s;
  r->pairs[i] = pairs_per_s;
  r->per_cycle[i] = bytes_per_s / hz;
}

/* ---- memory read bandwidth ---- */

__attribute__((target("avx512f"))) static uint64_t read_avx512(const uint8_t *p, size_t n) {
  __m512i s0 = _mm512_setzero_si512(), s1 = s0, s2 = s0, s3 = s0;
  for (size_t i = 0; i < n; i += 256) {
    s0 = _mm512_add_epi64(s0, _mm512_load_si512((const void *)(p + i)));
    s1 = _mm512_add_epi64(s1, _mm512_load_si512((const void *)(p + i + 64)));
    s2 = _mm512_add_epi64(s2, _mm512_load_si512((const void *)(p + i + 128)));
    s3 = _mm512_add_epi64(s3, _mm512_load_si512((const void *)(p + i + 192)));
  }
  return (uint64_t)_mm512_reduce_add_epi64(
      _mm512_add_epi64(_mm512_add_epi64(s0, s1), _mm512_add_epi64(s2, s3)));
}

__attribute__((target("avx2"))) static uint64_t read_avx2(const uint8_t *p, size_t n) {
  __m256i s0 = _mm256_setzero_si256(), s1 = s0, s2 = s0, s3 = s0;
  for (size_t i = 0; i < n; i += 128) {
    s0 = _mm256_add_epi64(s0, _mm256_load_si256((const __m256i *)(const void *)(p + i)));
    s1 = _mm256_add_epi64(s1, _mm256_load_si256((const __m256i *)(const void *)(p + i + 32)));
    s2 = _mm256_add_epi64(s2, _mm256_load_si256((const __m256i *)(const void *)(p + i + 64)));
    s3 = _mm256_add_epi64(s3, _mm256_load_si256((const __m256i *)(const void *)(p + i + 96)));
  }
  __m256i s = _mm256_add_epi64(_mm256_add_epi64(s0, s1), _mm256_add_epi64(s2, s3));
  return (uint64_t)_mm256_extract_epi64(s, 0) + (uint64_t)_mm256_extract_epi64(s, 3);
}

static uint64_t read_sse2(const uint8_t *p, size_t n) {
  __m128i s0 = _mm_setzero_si128(), s1 = s0, s2 = s0, s3 = s0;
  for (size_t i = 0; i < n; i += 64) {
    s0 = _mm_add_epi64(s0, _mm_load_si128((const __m128i *)(const void *)(p + i)));
    s1 = _mm_add_epi64(s1, _mm_load_si128((const __m128i *)(const void *)(p + i + 16)));
    s2 = _mm_add_epi64(s2, _mm_load_si128((const __m128i *)(const void *)(p + i + 32)));
    s3 = _mm_add_epi64(s3, _mm_load_si128((const __m128i *)(const void *)(p + i + 48)));
  }
  __m128i s = _mm_add_epi64(_mm_add_epi64(s0, s1), _mm_add_epi64(s2, s3));
  return (uint64_t)_mm_cvtsi128_si64(s);
}

typedef uint64_t read_fn(const uint8_t *p, size_t n);

typedef struct {
  read_fn *fn;
  const uint8_t *p;
  size_t n;
  uint64_t sum;
} reader;

static void *reader_main(void *arg) {
  reader *r = arg;
  r->sum = r->fn(r->p, r->n);
  return NULL;
}

/* Streams buf with `threads` threads; returns bytes per second (0 if a
 * thread could not be started). */
static double stream_once(read_fn *fn, const uint8_t *buf, size_t n, int threads) {
  pthread_t tid[2];
  reader r[2];
  int started = 0;
  double t0 = now();
  for (int i = 0; i < threads; i++) {
    r[i] = (reader){fn, buf + n / threads * i, n / threads, 0};
    if (threads == 1) {
      reader_main(&r[i]);
    } else if (pthread_create(&tid[i], NULL, reader_main, &r[i]) == 0) {
      started++;
    } else {
      fprintf(stderr, "bench_kernels: cannot start a reader thread\n");
      break;
    }
  }
  for (int i = 0; i < started; i++) pthread_join(tid[i], NULL);
  double t = now() - t0;
  volatile uint64_t sink = r[0].sum;
  (void)sink;
  return threads > 1 && started < threads ? 0 : (double)n / t;
}

static void emit(bench *b, const char *variant, const char *kind, const char *where, int nq,
                 int nchunks, row *r) {
  double bytes = median(r->bytes, REPS), pairs = median(r->pairs, REPS);
  double bpc = median(r->per_cycle, REPS);
  double ppc = nchunks > 0 ? bpc / (nchunks * TS_L1_CHUNK) : 0;
  printf("%-7s %-11s %-6s %4d %8d %9.2f %10.1f %9.2f %9.3f\n", variant, kind, where, nq, nchunks,
         bytes * 1e-9, pairs * 1e-6, bpc, ppc);
  if (b->out != NULL)
    fprintf(b->out, "%s,%s,%s,%d,%d,%.3f,%.0f,%.3f\n", variant, kind, where, nq, nchunks,
            bytes * 1e-9, pairs, bpc);
}

static void bench_memory(bench *b) {
  const char *name = "sse2";
  read_fn *fn = read_sse2;
  if (ts_l1_impl_get(TS_SIMD_AVX512) != NULL) {
    name = "avx512";
    fn = read_avx512;
  } else if (ts_l1_impl_get(TS_SIMD_AVX2) != NULL) {
    name = "avx2";
    fn = read_avx2;
  }
  size_t n = b->quick ? STREAM_BYTES / 4 : STREAM_BYTES;
  uint8_t *buf = aligned_alloc(64, n);
  if (buf == NULL) {
    fprintf(stderr, "bench_kernels: no memory for the %zu MB stream buffer\n", n >> 20);
    return;
  }
  memset(buf, 1, n); /* fault every page in before timing */
  for (int threads = 1; threads <= 2; threads++) {
    row r;
    stream_once(fn, buf, n, threads);
    for (int i = 0; i < REPS; i++) {
      double hz = clock_now();
      row_add(&r, i, stream_once(fn, buf, n, threads), 0, hz);
    }
    emit(b, name, threads == 1 ? "memread-1t" : "memread-2t", "mem", 0, 0, &r);
  }
  free(buf);
}

/* ---- kernels ---- */

typedef struct {
  const ts_l1_set *set;
  const ts_l1_impl *impl;
  int batch; /* 0: impl->single one query per call; else impl->batch */
  uint32_t nq;
  const uint8_t *queries;
  ts_l1_best *best;
} scan_cfg;

/* Runs `calls` scans of `ngr` groups each, starting at group *g and moving
 * on by `step` groups per call (wrapping); returns seconds. */
static double run_scans(const scan_cfg *c, uint32_t ngr, uint32_t step, uint32_t calls,
                        uint32_t *g) {
  uint32_t ng = c->set->ngroups;
  ts_l1_best_reset(c->best, c->nq);
  double t0 = now();
  for (uint32_t i = 0; i < calls; i++) {
    if (*g + ngr > ng) *g = 0;
    if (c->batch)
      c->impl->batch(c->set, *g, *g + ngr, c->queries, NULL, NULL, c->nq, c->best);
    else
      c->impl->single(c->set, *g, *g + ngr, c->queries, NULL, NULL, 1, c->best);
    *g = (uint32_t)(((uint64_t)*g + step) % ng);
  }
  return now() - t0;
}

/* One table row: sizes the work per repetition to about `target` seconds
 * from a probe, then takes the median of REPS repetitions. */
static void bench_scan(bench *b, const scan_cfg *c, const char *kind, int mem) {
  const ts_l1_set *set = c->set;
  double target = b->quick ? 0.01 : 0.04;
  uint32_t g = 0, ng = set->ngroups;
  uint32_t probe_groups = ng < 256 ? ng : 256;
  double tp = run_scans(c, probe_groups, probe_groups, 1, &g);
  double per_group = tp / probe_groups;
  if (per_group <= 0) per_group = 1e-9;
  /* Groups per call: the whole set in cache; in memory, as many as fit the
   * time budget (slow kernels see a smaller, still cold, window). */
  double want = target / per_group;
  uint32_t ngr = want >= ng || !mem ? ng : (uint32_t)want + 1;
  uint32_t calls = (uint32_t)(want / ngr) + 1;
  uint32_t step = ngr;
  if (mem) {
    uint32_t stride = (uint32_t)(MEM_STRIDE / ((size_t)set->nchunks * 64));
    step = ngr > stride ? ngr : stride;
  } else {
    run_scans(c, ngr, 0, 1, &g); /* warm the cache */
  }
  uint32_t nq = c->batch ? c->nq : 1;
  uint64_t npairs = (uint64_t)ngr * TS_L1_GROUP * calls * nq;
  row r;
  for (int i = 0; i < REPS; i++) {
    double hz = clock_now();
    double pairs = (double)npairs / run_scans(c, ngr, step, calls, &g);
    row_add(&r, i, pairs * set->nchunks * TS_L1_CHUNK, pairs, hz);
  }
  emit(b, c->impl->name, kind, mem ? "mem" : "cache", (int)nq, (int)set->nchunks, &r);
}

/* A vector shape and its weighted parts (l1.h). */
typedef struct {
  uint32_t nchunks, nparts;
  uint32_t end[5];
  uint64_t weight[5];
} shape;

/* Distinct weights: the general path, every multiply. */
static const shape shapes[] = {
    {7, 2, {3, 7}, {5, 3}},
    {12, 2, {5, 12}, {5, 3}},
    {20, 5, {4, 8, 12, 16, 20}, {5, 3, 2, 4, 1}},
};
#define MAX_CHUNKS 20

static int make_set(ts_l1_set *set, size_t bytes, const shape *sh) {
  uint32_t nchunks = sh->nchunks;
  uint32_t nvec = (uint32_t)(bytes / ((size_t)nchunks * TS_L1_CHUNK));
  int rc = ts_l1_set_init(set, nvec, nchunks);
  if (rc == 0) rc = ts_l1_set_weigh(set, sh->nparts, sh->end, sh->weight, NULL);
  if (rc != 0) {
    ts_l1_set_free(set);
    return rc;
  }
  /* The kernels do the same work whatever the bytes are; fill the whole
   * data array, padding included, straight from the generator. */
  ts_rng rng;
  ts_rng_seed(&rng, 42, nchunks);
  size_t n = (size_t)set->ngroups * nchunks * 64;
  for (size_t i = 0; i < n; i += 8) {
    uint64_t x = ts_rng_next(&rng);
    memcpy(set->data + i, &x, 8);
  }
  return 0;
}

static void bench_shape(bench *b, const shape *sh, uint8_t *queries, ts_l1_best *best) {
  for (int mem = 0; mem <= 1; mem++) {
    ts_l1_set set;
    size_t bytes = mem ? (b->quick ? MEM_BYTES / 2 : MEM_BYTES) : CACHE_BYTES;
    int rc = make_set(&set, bytes, sh);
    if (rc != 0) {
      fprintf(stderr, "bench_kernels: reference set of %zu bytes: %s\n", bytes, ts_strerror(rc));
      continue;
    }
    for (int id = 0; id < TS_SIMD_COUNT; id++) {
      const ts_l1_impl *impl = ts_l1_impl_get((ts_simd)id);
      if (impl == NULL || (b->only >= 0 && b->only != id)) continue;
      scan_cfg c = {&set, impl, 0, 1, queries, best};
      bench_scan(b, &c, "single", mem);
      static const uint32_t batch_nq[] = {32, 128};
      for (int i = 0; i < 2; i++) {
        c.batch = 1;
        c.nq = batch_nq[i];
        bench_scan(b, &c, "batch", mem);
      }
    }
    ts_l1_set_free(&set);
  }
}

static int parse_args(bench *b, int argc, char **argv) {
  for (int i = 1; i < argc; i++) {
    if (strcmp(argv[i], "--quick") == 0) {
      b->quick = 1;
    } else if (strcmp(argv[i], "--csv") == 0 && i + 1 < argc) {
      b->csv = argv[++i];
    } else if (strcmp(argv[i], "--variant") == 0 && i + 1 < argc) {
      b->only = (int)ts_simd_from_name(argv[++i]);
      if (b->only == TS_SIMD_COUNT || ts_l1_impl_get((ts_simd)b->only) == NULL) {
        fprintf(stderr, "bench_kernels: unknown or unsupported variant '%s'\n", argv[i]);
        return -1;
      }
    } else {
      fprintf(stderr, "usage: %s [--quick] [--csv FILE] [--variant NAME]\n", argv[0]);
      return -1;
    }
  }
  return 0;
}

int main(int argc, char **argv) {
  bench b = {0, NULL, -1, 0, 0, NULL};
  if (parse_args(&b, argc, argv) != 0) return 2;
  if (b.csv != NULL) {
    b.out = fopen(b.csv, "w");
    if (b.out == NULL) {
      perror(b.csv);
      return 1;
    }
    fprintf(b.out, "variant,kind,where,nq,nchunks,gbps,pairs_per_s,bytes_per_cycle\n");
  }
  measure_clock(&b);
  printf("# core clock %.2f GHz (busy loop of dependent adds vs clock_gettime; re-measured\n"
         "# before every repetition for B/cycle), TSC %.2f GHz\n",
         b.core_hz * 1e-9, b.tsc_hz * 1e-9);
  printf("# GB/s and B/cycle count nchunks*8 reference bytes per vector per query; "
         "median of %d runs\n",
         REPS);
  printf("%-7s %-11s %-6s %4s %8s %9s %10s %9s %9s\n", "variant", "kind", "where", "nq",
         "nchunks", "GB/s", "Mpairs/s", "B/cycle", "pairs/cyc");
  bench_memory(&b);

  const uint32_t max_nq = 128;
  uint8_t *queries = malloc((size_t)max_nq * MAX_CHUNKS * TS_L1_CHUNK);
  ts_l1_best *best = malloc(max_nq * sizeof(*best));
  if (queries == NULL || best == NULL) return 1;
  ts_rng rng;
  ts_rng_seed(&rng, 7, 0);
  for (size_t i = 0; i < (size_t)max_nq * MAX_CHUNKS * TS_L1_CHUNK; i++)
    queries[i] = (uint8_t)ts_rng_next(&rng);
  for (size_t i = 0; i < sizeof(shapes) / sizeof(shapes[0]); i++)
    bench_shape(&b, &shapes[i], queries, best);
  free(queries);
  free(best);
  if (b.out != NULL) fclose(b.out);
  return 0;
}
