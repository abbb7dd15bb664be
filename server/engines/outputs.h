/* outputs.h - the side outputs of a synthesis: copy map (as an image and
 * raw), usage map and the JSON report with the job's parameters, timings,
 * the search mode (exact, or which lossy shortcut was used) and, for a run
 * resumed from a checkpoint, where it resumed. */
#ifndef TS_OUTPUTS_H
#define TS_OUTPUTS_H

#include <stdint.h>

#include "mrf.h"
#include "search.h"

/* 16-bit RGB: red = x / (ref_w - 1), green = y / (ref_h - 1) (seed §3.1). */
int ts_write_copy_map_image(const char *path, const uint32_t *map, int w, int h, int ref_w,
                            int ref_h, char *err);
/* Raw: w*h pairs (x, y) of little-endian uint32, row-major, no header. */
int ts_write_copy_map_raw(const char *path, const uint32_t *map, int w, int h, char *err);
/* .tif/.tiff/.exr: float counts; other formats: counts / max. */
int ts_write_usage_map(const char *path, const uint32_t *usage, int w, int h, char *err);
int ts_write_report(const char *path, const ts_mrf_params *p, int threads, const ts_search *search,
                    const ts_mrf_result *res, char *err);
/* The search mode the report names: "lbg" or "lbg-exact" when some of a
 * level's queries were searched in partitions, else "copy-map" when the
 * copy-map shortcut copied blocks, else "exact". */
const char *ts_mrf_search_mode(const ts_mrf_params *p, const ts_mrf_result *res);
/* The note a lossy LBG search leaves in the output's metadata ("" when
 * none ran lossy): partitions, probe and levels. */
void ts_mrf_lbg_note(const ts_mrf_params *p, const ts_mrf_result *res, char *buf, size_t cap);

#endif
