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

/* The draws are inline: PatchMatch takes about 20 per pixel. */
static inline uint64_t ts_rng_rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

static inline uint64_t ts_rng_next(ts_rng *rng) {
  uint64_t *s = rng->s;
  uint64_t result = ts_rng_rotl(s[1] * 5, 7) * 9;
  uint64_t t = s[1] << 17;
  s[2] ^= s[0];
  s[3] ^= s[1];
  s[1] ^= s[2];
  s[0] ^= s[3];
  s[2] ^= t;
  s[3] = ts_rng_rotl(s[3], 45);
  return result;
}

/* Uniform integer in [0, n), n > 0, without modulo bias: Lemire's
 * multiply-shift with rejection of the biased low range. */
static inline uint32_t ts_rng_below(ts_rng *rng, uint32_t n) {
  uint64_t m = (uint64_t)(uint32_t)(ts_rng_next(rng) >> 32) * n;
  uint32_t low = (uint32_t)m;
  if (low < n) {
    uint32_t threshold = (uint32_t)(-n) % n;
    while (low < threshold) {
      m = (uint64_t)(uint32_t)(ts_rng_next(rng) >> 32) * n;
      low = (uint32_t)m;
    }
  }
  return (uint32_t)(m >> 32);
}

#endif
