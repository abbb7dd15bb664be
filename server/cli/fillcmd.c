/* fillcmd.c - `texsyn synth --input IMG --mask MASK`: constrained
 * synthesis (hole filling, extension; fill.h) of one image. */
#include "fillcmd.h"

#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "fill.h"
#include "jobcmd.h"
#include "paramopt.h"
#include "util.h"

static void usage(FILE *f, const ts_engine *e) {
  fprintf(f,
          "usage: texsyn synth --input IMG --mask MASK -o OUT [options]\n"
          "\n"
          "Fills the part of IMG that MASK marks (its bright pixels, luminance >= 128):\n"
          "holes, missing borders, an extension. Constrained MRF block synthesis after\n"
          "Stahlhut 2004: blocks whose neighbourhood is best known are filled first (the\n"
          "\"puzzle\" order), each from the reference block whose neighbourhood - the known\n"
          "part of it - matches best, over a pyramid of masked levels. The reference is\n"
          "the rest of IMG, and any --ref images. The given pixels keep their bytes; the\n"
          "output has IMG's pixel type and channels. Exact, as every synthesis: the same\n"
          "bytes in-process and on any pool of workers.\n"
          "\n"
          "  --input IMG          the image to complete\n"
          "  --mask MASK          what to fill: bright (>= 128) pixels; IMG's size\n"
          "  --ref IMG            a further reference image (IMG's channels and type),\n"
          "                       up to %d; the whole of it may be copied\n",
          TS_FILL_MAX_SOURCES - 1);
  ts_paramopt_help(f, e);
  fprintf(f, "%s", ts_job_options_help);
}

enum { OPT_INPUT = TS_OPT_OWN, OPT_MASK, OPT_REF };

/* Its own options: the inputs (the parameters are the engine's). */
static const struct option own_opts[] = {
    {"input", required_argument, 0, OPT_INPUT}, {"mask", required_argument, 0, OPT_MASK},
    {"ref", required_argument, 0, OPT_REF},     TS_JOB_LONGOPTS,
    {0, 0, 0, 0}};

typedef struct {
  ts_job_cmd job;
  int refs;
  const char *ref[TS_FILL_MAX_SOURCES - 1];
} fill_opts;

static int fill_option(void *ctx, int c, const char *arg, int argc, char **argv, char *err) {
  (void)argc, (void)argv;
  fill_opts *o = ctx;
  switch (c) {
  case OPT_INPUT: o->job.in[0] = arg; return 0;
  case OPT_MASK: o->job.in[1] = arg; return 0;
  case OPT_REF:
    if (o->refs == TS_FILL_MAX_SOURCES - 1)
      return ts_error(err, TS_EINVAL, "--ref: at most %d further references", TS_FILL_MAX_SOURCES - 1);
    o->ref[o->refs++] = arg;
    return 0;
  default: return TS_ENOENT;
  }
}

static int parse(int argc, char **argv, fill_opts *o, char *err) {
  memset(o, 0, sizeof(*o));
  ts_job_cmd_init(&o->job, "synth", ts_engine_find("fill"));
  static const ts_cmd_options cmd = {"o:h", own_opts, fill_option, usage};
  int rc = ts_paramopt_parse(&o->job, &cmd, o, argc, argv, err);
  if (rc != 0) return rc;
  if (o->job.in[0] == NULL || o->job.in[1] == NULL)
    return ts_error(err, TS_EINVAL, "--input IMG and --mask MASK are both required (see texsyn synth --help)");
  char n[16];
  snprintf(n, sizeof(n), "%d", o->refs);
  rc = ts_job_set_key(&o->job, "refs", n, "--ref", err);
  for (int i = 0; i < o->refs; i++) o->job.in[2 + i] = o->ref[i];
  if (rc == 0) rc = o->job.spec.engine->spec_complete(o->job.spec.params.bytes, err);
  if (rc != 0) return ts_error(err, TS_EINVAL, "--no-self needs at least one --ref");
  return ts_job_parse_end(&o->job, err);
}

int ts_cmd_fill(int argc, char **argv) {
  char err[TS_ERR_LEN] = "";
  fill_opts o;
  if (parse(argc, argv, &o, err) != 0) {
    fprintf(stderr, "texsyn synth: %s\n", err);
    return 2;
  }
  return ts_job_run(&o.job);
}

int ts_fill_wanted(int argc, char **argv) {
  for (int i = 1; i < argc; i++) {
    if (strcmp(argv[i], "--") == 0) return 0;
    if (strcmp(argv[i], "--input") == 0 || strncmp(argv[i], "--input=", 8) == 0) return 1;
  }
  return 0;
}
