/* rng.h - deterministic pseudo-random numbers (xoshiro256**, seeded through
 * splitmix64). Everything random in texsyn draws from here with an explicit
 * seed, so the same job and seed give the same bytes on every machine. */
#ifndef TS_RNG_H
#define TS_RNG_H

#include <stdint.h>

typedef struct {
  uint64_t s[4];
} ts_rng;

/* Seeds from (seed, stream): different streams of one seed are independent,
 * e.g. one stream per pyramid level. */
void ts_rng_seed(ts_rng *rng, uint64_t seed, uint64_t stream);
uint64_t ts_rng_next(ts_rng *rng);
/* Uniform integer in [0, n), n > 0, without modulo bias. */
uint32_t ts_rng_below(ts_rng *rng, uint32_t n);

#endif
