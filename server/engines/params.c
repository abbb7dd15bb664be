/* params.c - the engine's default parameters, apart from the engine so
 * that light users (the job spec parser and its fuzzer) don't link it. */
#include <string.h>

#include "image.h"
#include "mrf.h"

void ts_mrf_params_default(ts_mrf_params *p) {
  memset(p, 0, sizeof(*p));
  p->levels = 5;
  p->wn = 7;
  p->wb = 3;
  p->coarse_weight = 1.0;
  p->refine = 2;
  p->seed = 1;
  p->max_pixels = TS_IMAGE_DEFAULT_MAX_PIXELS;
}
