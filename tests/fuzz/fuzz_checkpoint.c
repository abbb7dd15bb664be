/* fuzz_checkpoint.c - libFuzzer target for the checkpoint decoder
 * (server/engines/checkpoint.c), which reads files a crashed coordinator left in
 * its spool: checkpoints after a level and inside one. The input is a checkpoint without its trailing checksum: the
 * target appends the right one, so the fuzzer reaches the header and
 * length checks instead of stopping at the checksum. The tag is taken from
 * the input's own tag field, so foreign-job refusals do not hide the rest.
 * A decoded checkpoint must re-encode to the same bytes. Any crash,
 * sanitizer report or mismatch is a bug. Build and run: make fuzz. */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "checkpoint.h"
#include "error.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static uint64_t fnv1a64(const uint8_t *p, size_t n) {
  uint64_t h = 0xcbf29ce484222325ull; /* the format's checksum */
  for (size_t i = 0; i < n; i++) h = (h ^ p[i]) * 0x100000001b3ull;
  return h;
}

static uint64_t le64(const uint8_t *p) {
  uint64_t v = 0;
  for (int i = 7; i >= 0; i--) v = v << 8 | p[i];
  return v;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  uint8_t *buf = malloc(size + 8);
  if (buf == NULL) return 0;
  memcpy(buf, data, size);
  uint64_t sum = fnv1a64(data, size);
  for (int i = 0; i < 8; i++) buf[size + i] = (uint8_t)(sum >> (8 * i));
  uint64_t tag = size >= 16 ? le64(data + 8) : 0;
  ts_mrf_checkpoint ck;
  char err[TS_ERR_LEN];
  if (ts_checkpoint_decode(buf, size + 8, tag, 1u << 20, &ck, err) == 0) {
    /* Decoded, so the 84-byte header is there: its stats count. */
    uint32_t nstats = (uint32_t)(data[64] | data[65] << 8 | data[66] << 16 | (uint32_t)data[67] << 24);
    uint8_t *again;
    size_t len;
    if (ts_checkpoint_encode(&ck, ck.level + (int)nstats, tag, &again, &len, err) != 0) abort();
    if (len != size + 8 || memcmp(again, buf, len) != 0) abort(); /* decode and encode disagree */
    free(again);
    ts_checkpoint_free(&ck);
  } else if (err[0] == '\0') {
    abort(); /* refused without a reason */
  }
  free(buf);
  return 0;
}
