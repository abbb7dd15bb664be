/* calib.c - see calib.h. */
#include "calib.h"

#include <stdlib.h>
#include <time.h>

#include "error.h"
#include "rng.h"

typedef struct {
  const ts_l1_set *set;
  const ts_l1_impl *simd;
  const uint8_t *queries;
  ts_l1_best *best; /* per thread TS_CALIB_QUERIES entries */
} calib_job;

static void calib_scan(void *arg, int w, int nw) {
  calib_job *j = arg;
  uint32_t g0 = (uint32_t)((uint64_t)j->set->ngroups * w / nw);
  uint32_t g1 = (uint32_t)((uint64_t)j->set->ngroups * (w + 1) / nw);
  ts_l1_best *best = j->best + (size_t)w * TS_CALIB_QUERIES;
  ts_l1_best_reset(best, TS_CALIB_QUERIES);
  j->simd->batch(j->set, g0, g1, j->queries, NULL, NULL, TS_CALIB_QUERIES, best);
}

static uint64_t nanos_now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

int ts_calib_run(ts_pool *pool, const ts_l1_impl *simd, uint32_t millis, uint64_t *pairs,
                 uint64_t *nanos) {
  ts_l1_set set;
  int rc = ts_l1_set_init(&set, TS_CALIB_VECTORS, TS_CALIB_CHUNKS);
  if (rc != 0) return rc;
  size_t vbytes = TS_CALIB_CHUNKS * TS_L1_CHUNK;
  uint8_t *vec = malloc(vbytes * TS_CALIB_QUERIES);
  ts_l1_best *best = malloc(sizeof(ts_l1_best) * TS_CALIB_QUERIES * (size_t)ts_pool_size(pool));
  if (vec == NULL || best == NULL) {
    rc = TS_ENOMEM;
    goto out;
  }
  ts_rng rng;
  ts_rng_seed(&rng, 2004, 0);
  for (uint32_t v = 0; v < TS_CALIB_VECTORS; v++) {
    for (size_t b = 0; b < vbytes; b++) vec[b] = (uint8_t)ts_rng_next(&rng);
    ts_l1_set_put(&set, v, vec);
  }
  for (size_t b = 0; b < vbytes * TS_CALIB_QUERIES; b++) vec[b] = (uint8_t)ts_rng_next(&rng);
  calib_job job = {&set, simd, vec, best};
  uint64_t t0 = nanos_now(), t = t0, n = 0;
  /* One untimed pass warms caches and wakes the threads. */
  ts_pool_run(pool, calib_scan, &job);
  t0 = nanos_now();
  do {
    ts_pool_run(pool, calib_scan, &job);
    n++;
    t = nanos_now();
  } while (t - t0 < (uint64_t)millis * 1000000u);
  *pairs = n * TS_CALIB_VECTORS * TS_CALIB_QUERIES;
  *nanos = t - t0 ? t - t0 : 1;
out:
  free(vec);
  free(best);
  ts_l1_set_free(&set);
  return rc;
}

double ts_calib_bytes_per_second(uint64_t pairs, uint64_t nanos) {
  return nanos > 0 ? (double)pairs * TS_CALIB_CHUNKS * TS_L1_CHUNK / ((double)nanos * 1e-9) : 0.0;
}
