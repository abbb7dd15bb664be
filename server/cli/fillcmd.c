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
#include "util.h"

static void usage(FILE *f) {
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
          "                       up to %d; the whole of it may be copied\n"
          "  --no-self            do not copy from IMG itself (needs --ref)\n"
          "  --levels L           pyramid levels, 1..%d (default 4)\n"
          "  --wn N               neighbourhood width, odd, > --wb, <= 41 (default 9)\n"
          "  --wb B               block width, odd, 1..15 (default 3)\n"
          "  --order O            puzzle (default): the best known blocks first, re-sorted\n"
          "                       after every step; threshold: in rounds, every block with\n"
          "                       at least --threshold of its window known (seed §3.2.5)\n"
          "  --threshold F        threshold order: the share of the window, (0, 1] (0.25)\n"
          "  --parity             parity control (4x fewer comparisons, coarser joins)\n"
          "  --usage-weight A     active usage-variance penalty, 0..100 (default 0 = off)\n"
          "  --coarse-weight W    weight of the coarse-level part, (0, 100] (default 1)\n"
          "  --seed S             seed of the blocks that start areas with nothing known\n"
          "                       around them (default 1)\n"
          "  --luma-search        search a colour image on its luminance, as the seed does\n"
          "                       (default: on its colour channels, which keeps colours\n"
          "                       from mixing where different colours have one grey)\n"
          "  --copy-map F         where every pixel comes from, as an image (red = x,\n"
          "                       green = y; given pixels point at themselves)\n"
          "  --copy-map-raw F     the same as little-endian uint32 (x, y) per pixel\n"
          "%s",
          TS_FILL_MAX_SOURCES - 1, TS_FILL_MAX_LEVELS, ts_job_options_help);
}

enum {
  OPT_INPUT = TS_OPT_OWN, OPT_MASK, OPT_REF, OPT_NO_SELF, OPT_LEVELS, OPT_WN, OPT_WB, OPT_ORDER, OPT_THRESHOLD,
  OPT_PARITY, OPT_USAGE, OPT_COARSE, OPT_SEED, OPT_LUMA, OPT_COPY, OPT_COPY_RAW
};

static const struct option longopts[] = {
    {"input", required_argument, 0, OPT_INPUT},       {"mask", required_argument, 0, OPT_MASK},
    {"ref", required_argument, 0, OPT_REF},           {"no-self", no_argument, 0, OPT_NO_SELF},
    {"levels", required_argument, 0, OPT_LEVELS},     {"wn", required_argument, 0, OPT_WN},
    {"wb", required_argument, 0, OPT_WB},             {"order", required_argument, 0, OPT_ORDER},
    {"threshold", required_argument, 0, OPT_THRESHOLD}, {"parity", no_argument, 0, OPT_PARITY},
    {"usage-weight", required_argument, 0, OPT_USAGE}, {"coarse-weight", required_argument, 0, OPT_COARSE},
    {"seed", required_argument, 0, OPT_SEED},         {"luma-search", no_argument, 0, OPT_LUMA},
    {"copy-map", required_argument, 0, OPT_COPY},     {"copy-map-raw", required_argument, 0, OPT_COPY_RAW},
    TS_JOB_LONGOPTS,
    {0, 0, 0, 0}};

/* Keys of the options that set one spec key from their value as is. */
static const ts_key_option value_keys[] = {{OPT_LEVELS, "levels", "--levels"},          {OPT_WN, "wn", "--wn"},
                  {OPT_WB, "wb", "--wb"},                      {OPT_ORDER, "order", "--order"},
                  {OPT_THRESHOLD, "threshold", "--threshold"}, {OPT_USAGE, "usage_weight", "--usage-weight"},
                  {OPT_COARSE, "coarse_weight", "--coarse-weight"}, {OPT_SEED, "seed", "--seed"}};

typedef struct {
  ts_job_cmd job;
  int refs;
  const char *ref[TS_FILL_MAX_SOURCES - 1];
} fill_opts;

static int fill_option(fill_opts *o, int c, const char *arg, char *err) {
  int rc = ts_job_key_option(&o->job, value_keys, sizeof(value_keys) / sizeof(value_keys[0]), c, arg, err);
  if (rc != TS_ENOENT) return rc;
  switch (c) {
  case OPT_INPUT: o->job.in[0] = arg; return 0;
  case OPT_MASK: o->job.in[1] = arg; return 0;
  case OPT_REF:
    if (o->refs == TS_FILL_MAX_SOURCES - 1)
      return ts_error(err, TS_EINVAL, "--ref: at most %d further references", TS_FILL_MAX_SOURCES - 1);
    o->ref[o->refs++] = arg;
    return 0;
  case OPT_NO_SELF: return ts_job_set_key(&o->job, "self", "0", "--no-self", err);
  case OPT_PARITY: return ts_job_set_key(&o->job, "parity", "1", "--parity", err);
  case OPT_LUMA: return ts_job_set_key(&o->job, "rgb_search", "0", "--luma-search", err);
  case OPT_COPY: ts_output_set(&o->job.out, "copy_map", arg); return 0;
  case OPT_COPY_RAW: ts_output_set(&o->job.out, "copy_map_raw", arg); return 0;
  default:
    rc = ts_job_option(&o->job, c, arg, err);
    return rc == TS_ENOENT ? ts_error(err, TS_EINVAL, "unknown option (see texsyn synth --help)") : rc;
  }
}

static int parse(int argc, char **argv, fill_opts *o, char *err) {
  memset(o, 0, sizeof(*o));
  ts_job_cmd_init(&o->job, "synth", ts_engine_find("fill"));
  optind = 1;
  opterr = 0;
  int c;
  while ((c = getopt_long(argc, argv, "o:h", longopts, NULL)) != -1) {
    if (c == TS_OPT_HELP || c == 'h') {
      usage(stdout);
      exit(0);
    }
    if (c == '?' || c == ':') return ts_arg_unknown("synth", argv[optind - 1], longopts, err);
    int rc = fill_option(o, c, optarg, err);
    if (rc != 0) return rc;
  }
  if (optind < argc) return ts_error(err, TS_EINVAL, "unexpected argument '%s'", argv[optind]);
  if (o->job.in[0] == NULL || o->job.in[1] == NULL)
    return ts_error(err, TS_EINVAL, "--input IMG and --mask MASK are both required (see texsyn synth --help)");
  char n[16];
  snprintf(n, sizeof(n), "%d", o->refs);
  int rc = ts_job_set_key(&o->job, "refs", n, "--ref", err);
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
