/* paramopt.h - a job command's options that come from its engine's
 * declarations: one option per parameter with a flag (param.h) and one
 * per side output (ts_engine_output.flag). A command adds its own (its
 * inputs) and every job's (jobcmd.h); parsing, --help and the manual
 * follow from the engine's tables, so a parameter is declared once. */
#ifndef TS_PARAMOPT_H
#define TS_PARAMOPT_H

#include <getopt.h>
#include <stdio.h>

#include "jobcmd.h"

/* getopt codes: TS_OPT_PARAM + the parameter's index, TS_OPT_SIDE + the
 * output's; a command's own codes stay below TS_OPT_PARAM. */
enum { TS_OPT_PARAM = 1000, TS_OPT_SIDE = 1900 };
#define TS_PARAMOPT_MAX 160 /* entries of a built getopt_long table */

/* The command's own options (`own`, ending with a zero entry), then the
 * engine's: a getopt_long table in out (cap entries), zero-terminated. */
int ts_paramopt_build(const ts_engine *e, const struct option *own, struct option *out, size_t cap);
/* Takes option c if it is an engine parameter or side output: 0, TS_EINVAL
 * with a message, or TS_ENOENT when c is not one. */
int ts_paramopt_take(ts_job_cmd *o, int c, const char *arg, char *err);
/* After parsing: a setting that runs in-process only refused with a
 * server. */
int ts_paramopt_check(const ts_job_cmd *o, char *err);
/* --help: the engine's parameters, then its side outputs. */
void ts_paramopt_help(FILE *f, const ts_engine *e);
/* The value of a parameter of o's engine as a number (param.h). */
double ts_paramopt_number(const ts_job_cmd *o, const char *key);

/* A job command's option loop, the same for every command: getopt_long
 * over its own options and its engine's; --help printed by `usage` (and
 * exit 0); each option handed first to `option` (TS_ENOENT when it is not
 * the command's own; argc and argv for options that take two words), then
 * taken as an engine parameter or side output, then as every job's (the
 * engine's parameters start from the command's own defaults, if any); a
 * mistyped one named with the closest option; no word left over. */
typedef struct {
  const char *shortopts;    /* "o:h", or "+o:h" to keep the words in order */
  const struct option *own; /* the command's own long options, zero-terminated */
  int (*option)(void *ctx, int c, const char *arg, int argc, char **argv, char *err);
  void (*usage)(FILE *f, const ts_engine *e);
  const ts_param_default *defaults; /* the command's own defaults (param.h), or NULL */
} ts_cmd_options;
int ts_paramopt_parse(ts_job_cmd *o, const ts_cmd_options *cmd, void *ctx, int argc, char **argv, char *err);

/* `texsyn params [ENGINE]`: the engines' parameter tables, for people
 * writing job specs and for the tests that hold --help and the manual to
 * the tables. The exit status. */
int ts_cmd_params(int argc, char **argv);

#endif
