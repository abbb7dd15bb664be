/* fillcmd.h - `texsyn synth --input IMG --mask MASK`: the constrained form
 * of texsyn synth (fill.h), with options of its own. */
#ifndef TS_FILLCMD_H
#define TS_FILLCMD_H

/* Whether a synth command line asks for the constrained form (--input). */
int ts_fill_wanted(int argc, char **argv);
/* Runs it: the process exit status (as ts_job_run). */
int ts_cmd_fill(int argc, char **argv);

#endif
