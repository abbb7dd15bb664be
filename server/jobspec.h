/* jobspec.h - a synthesis job as text: what a client submits, what the
 * spool keeps (job.spec) and what a restarted coordinator reads back.
 *
 * One `key=value` per line, keys in any order, unknown keys refused (a
 * newer client's option must not be silently dropped):
 *
 *   size=1024x1024  levels=5  wn=7  wb=3  parity=0  usage_weight=0
 *   coarse_weight=1  refine=2  seed=1  rgb_search=0  max_pixels=N
 *   output=png  copy_map=png  copy_map_raw=1  usage_map=tif  report=1
 *
 * `size` is required. `output`, `copy_map` and `usage_map` are file extensions (the format of
 * the file the coordinator writes); empty or absent means not wanted.
 * Doubles are written with 17 significant digits so they round-trip. */
#ifndef TS_JOBSPEC_H
#define TS_JOBSPEC_H

#include <stddef.h>

#include "mrf.h"

#define TS_EXT_LEN 16
/* Largest output width or height a spec (and the command line) takes. */
#define TS_OUTPUT_SIDE_MAX 1000000

typedef struct {
  ts_mrf_params p;
  char output[TS_EXT_LEN];   /* required */
  char copy_map[TS_EXT_LEN]; /* "" = none */
  char usage_map[TS_EXT_LEN];
  int copy_map_raw, report;
} ts_jobspec;

void ts_jobspec_default(ts_jobspec *s);
/* Writes the spec; returns its length, or TS_ETOOBIG if cap is too small. */
int ts_jobspec_format(const ts_jobspec *s, char *buf, size_t cap);
/* Parses len bytes (need not be NUL-terminated). Every line is checked;
 * the first problem is reported with its line number. Parameter ranges
 * are the engine's business (ts_mrf_check). */
int ts_jobspec_parse(const char *text, size_t len, ts_jobspec *s, char *err);
/* 1 if ext is a non-empty extension a spec accepts (letters and digits,
 * shorter than TS_EXT_LEN), else 0. */
int ts_ext_valid(const char *ext);
/* The extension of a path ("png" for "a/b.png"), or "" without one. */
const char *ts_path_ext(const char *path);

#endif
