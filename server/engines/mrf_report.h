/* mrf_report.h - the MRF job's JSON report: its parameters, timings, the
 * search mode (exact, or which lossy shortcut was used) and, for a run
 * resumed from a checkpoint, where it resumed; and the note a lossy search
 * leaves in the output's metadata. */
#ifndef TS_MRF_REPORT_H
#define TS_MRF_REPORT_H

#include <stddef.h>

#include "mrf.h"
#include "search.h"

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
