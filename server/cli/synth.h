/* synth.h - `texsyn synth` (alias `run`): MRF block synthesis of a texture
 * from a reference, or (ts_fill_wanted) hole filling. */
#ifndef TS_CLI_SYNTH_H
#define TS_CLI_SYNTH_H

#include "jobcmd.h"

/* Option codes of texsyn synth's inputs (its parameters' come from the
 * engine: paramopt.h); the side outputs' and the others are those of
 * `texsyn fetch`, `quality` and `shuffle` (main.c). */
enum {
  OPT_REF = TS_OPT_OWN, OPT_REF_FINE, OPT_SIZE, OPT_WN, OPT_SEED, OPT_IMAGE, OPT_SAMPLES, OPT_BLOCK,
  OPT_COPY, OPT_COPY_RAW, OPT_USAGE_MAP, OPT_NNF
};

/* Records a side output option's path (--copy-map and the like); 0 if c
 * is no such option. */
int ts_synth_output_option(ts_output_paths *t, int c, const char *path);
/* The command: the process exit status. */
int ts_cmd_synth(int argc, char **argv);

#endif
