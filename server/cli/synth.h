/* synth.h - `texsyn synth` (alias `run`): MRF block synthesis of a texture
 * from a reference, or (ts_fill_wanted) hole filling. */
#ifndef TS_CLI_SYNTH_H
#define TS_CLI_SYNTH_H

#include "jobcmd.h"

/* Option codes of texsyn synth; the side outputs' codes are shared with
 * `texsyn fetch` and the quality commands take some of the others. */
enum {
  OPT_REF = TS_OPT_OWN, OPT_SIZE, OPT_LEVELS, OPT_WN, OPT_WB, OPT_PARITY, OPT_USAGE, OPT_COARSE,
  OPT_SEED, OPT_RGB, OPT_COPY, OPT_COPY_RAW, OPT_USAGE_MAP, OPT_STOP, OPT_REFINE, OPT_IMAGE, OPT_SAMPLES,
  OPT_BLOCK, OPT_NNF, OPT_BEST_OF, OPT_BEST_OF_LEVELS, OPT_REF_FINE, OPT_MIX_LEVEL, OPT_ACCEL, OPT_ACCEL_KERNEL,
  OPT_ACCEL_MIN, OPT_LBG, OPT_LBG_LEVELS, OPT_LBG_PROBE, OPT_LBG_EXACT
};

/* Records a side output option's path (--copy-map and the like); 0 if c
 * is no such option. */
int ts_synth_output_option(ts_output_paths *t, int c, const char *path);
/* The command: the process exit status. */
int ts_cmd_synth(int argc, char **argv);

#endif
