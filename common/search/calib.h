/* calib.h - the standard calibration scan (seed 002 §3.6.4: the coordinator
 * sizes slices by each worker's measured speed). Every worker scans the same
 * deterministic vector set with all its threads, so rates compare across
 * machines and kernel variants. */
#ifndef TS_CALIB_H
#define TS_CALIB_H

#include <stdint.h>

#include "l1.h"
#include "pool.h"

/* Vectors of the standard set and queries per batch: a level-0-like job
 * (7x7 causal neighbourhood with coarse part = 7 chunks). */
#define TS_CALIB_VECTORS 65536u
#define TS_CALIB_CHUNKS 7u
#define TS_CALIB_QUERIES 32u

/* Scans batches of the standard set on every pool thread for about
 * `millis`; *pairs = comparisons done, *nanos = time taken. */
int ts_calib_run(ts_pool *pool, const ts_l1_impl *simd, uint32_t millis,
                 uint64_t *pairs, uint64_t *nanos);
/* A run's rate: bytes of vectors compared a second. */
double ts_calib_bytes_per_second(uint64_t pairs, uint64_t nanos);

#endif
