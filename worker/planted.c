/* planted.c - see planted.h. */
#include "planted.h"

#ifdef TEXSYN_FAULT_HOOKS
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "log.h"

/* Volatile, so the compiler cannot prove the faults away. */
static volatile uint32_t sink;

static void plant(const char *fault) {
  if (strcmp(fault, "overflow") == 0) {
    /* Through memcpy of a length the compiler cannot see, which ASan
     * checks: a load it could inline meets UBSan's object-size check
     * first, and this fault is ASan's. */
    uint8_t *block = malloc(16);
    uint16_t past = 0;
    volatile size_t len = sizeof(past);
    if (block != NULL) memcpy(&past, block + 15, len);
    sink = past;
    free(block);
  } else if (strcmp(fault, "leak") == 0) {
    volatile uint8_t *block = malloc(4096);
    if (block != NULL) block[0] = 1;
    block = NULL;
  } else if (strcmp(fault, "undefined") == 0) {
    volatile int shift = 32;
    sink = 1u << shift;
  } else {
    ts_warn("TEXSYN_PLANT_FAULT=%s: no such fault (overflow, leak, undefined)", fault);
  }
}

void ts_planted_fault(void) {
  static int done;
  const char *fault = getenv("TEXSYN_PLANT_FAULT");
  if (fault == NULL || done) return;
  done = 1;
  ts_warn("planting the fault %s (TEXSYN_PLANT_FAULT)", fault);
  plant(fault);
}
#endif
