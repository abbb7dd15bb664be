/* aerial.h - `texsyn aerial`: a synthetic aerial image from a land-use
 * class map and a reference catalogue (aerial_engine.c, catalogue.h). */
#ifndef TS_AERIAL_H
#define TS_AERIAL_H

/* Runs it: the process exit status (as ts_job_run; 2 for bad options or
 * a bad catalogue). */
int ts_cmd_aerial(int argc, char **argv);

#endif
