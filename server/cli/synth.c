/* synth.c - `texsyn synth`: its options and --help, checked, then run as
 * an mrf job (jobcmd.h) in-process or on a coordinator. */
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "fillcmd.h"
#include "lbg.h"
#include "mrf.h"
#include "synth.h"
#include "util.h"

static void usage_synth(FILE *f) {
  fprintf(f,
          "usage: texsyn synth --ref IMG -o OUT --size WxH [options]\n"
          "       texsyn synth --input IMG --mask MASK -o OUT [options]   (fill a hole:\n"
          "                    texsyn synth --input IMG --help for its options)\n"
          "\n"
          "Synthesises a WxH texture that looks like IMG (multi-resolution MRF block\n"
          "synthesis after Stahlhut 2004). The output tiles seamlessly and has the\n"
          "reference's pixel type and channels; colour is gathered through the copy map.\n"
          "Exact: every block takes the globally best reference block (ties to the\n"
          "lowest index), so a job and seed give the same bytes on any machine.\n"
          "\n"
          "  --ref IMG            reference texture (PNG, JPEG, TIFF, OpenEXR, ...)\n"
          "  --size WxH           output size in pixels (any size, >= 1)\n"
          "  --levels L           pyramid levels, 1..%d (default 5)\n"
          "  --wn N               neighbourhood width, odd, > --wb, <= 41 (default 7)\n"
          "  --wb B               block width, odd, 1..15 (default 3)\n"
          "  --parity             parity control: compare only reference blocks of the\n"
          "                       same coordinate parity (4x fewer comparisons; removes\n"
          "                       oscillation, coarser transitions) (default off)\n"
          "  --usage-weight A     active usage-variance penalty, 0..100 (default 0 = off);\n"
          "                       A = 1 charges a block used at the average rate one grey\n"
          "                       level per neighbourhood pixel\n"
          "  --coarse-weight W    weight of the coarse-level part relative to equal\n"
          "                       weighting by area, (0, 100] (default 1)\n"
          "  --refine N           refinement sweeps, 0..20 (default 2): each block searched\n"
          "                       again with its full window - all blocks of the coarser\n"
          "                       levels, the band along the torus seam on the finest;\n"
          "                       better joins and seam, ~1/10 of level 0's time per sweep\n"
          "  --seed S             noise initialisation seed, 0..2^64-1 (default 1)\n"
          "  --rgb-search         search on the colour channels instead of luminance\n"
          "  --copy-map F         copy map as an image (red = source x, green = source y)\n"
          "  --copy-map-raw F     copy map as raw little-endian uint32 (x, y) per pixel\n"
          "  --usage-map F        usage map: counts per reference pixel (.tif/.exr as\n"
          "                       float counts; other formats normalised to the maximum)\n"
          "  --stop-level N       stop after pyramid level N and write its luminance at\n"
          "                       that level's size: a quick preview (default 0 = full)\n"
          "  --best-of K          passive usage-variance optimisation: K seeds (the first\n"
          "                       --seed) through the coarse levels, the one whose usage\n"
          "                       map has the least variance goes on, 1..%d (default 1 = off)\n"
          "  --best-of-levels N   how many of the coarsest levels the candidates run\n"
          "                       (default all but the finest two)\n"
          "  --ref-fine IMG       texture mixing: levels below --mix-level from IMG (a small\n"
          "                       crop for local structure), the coarser ones from --ref\n"
          "  --mix-level M        the first level made from --ref, 1..L-1 (with --ref-fine)\n"
          "  --copy-accel         copy-map shortcut (lossy, off): at levels 1 and 0, blocks\n"
          "                       inside coherent regions of the level above's copy map are\n"
          "                       copied without a search, once the levels above kept their\n"
          "                       regions (the report and the image's metadata say so; the\n"
          "                       job takes no checkpoints)\n"
          "  --copy-accel-kernel N  coherence kernel width, odd 1..15 (default the coarse\n"
          "                       window width W_C): the buffer kept to transitions\n"
          "  --copy-accel-min R   constancy the levels above must show, 0..1 (default 0.95)\n"
          "  --lbg P              LOSSY: search in P LBG partitions per class (seed 002\n"
          "                       §3.6.5): each block only in its nearest partition(s);\n"
          "                       0..%d, default 0 = off (exact search); a set queried\n"
          "                       too seldom for its codebook to pay stays exact\n"
          "  --lbg-levels SPEC    levels searched so: \"all\" or a list like 0,1 (default 0)\n"
          "  --lbg-probe N        partitions scanned per block, 1..P (default 1)\n"
          "  --lbg-exact          exact pruning instead: skip only partitions that cannot\n"
          "                       hold a better block (the exact search's bytes)\n"
          "%s"
          "\n"
          "TEXSYN_SIMD=scalar|mmx|sse2|avx2|avx512 forces a kernel variant.\n",
          TS_MRF_MAX_LEVELS, TS_MRF_MAX_BEST_OF, TS_LBG_MAX_PARTITIONS, ts_job_options_help);
}

/* ---- synth ------------------------------------------------------------- */


/* The options that name a side output's path, by the output's spec key
 * (-o and --report are every job's). */
static const struct {
  int opt;
  const char *key;
} output_opts[] = {{OPT_COPY, "copy_map"}, {OPT_COPY_RAW, "copy_map_raw"}, {OPT_USAGE_MAP, "usage_map"},
                   {OPT_NNF, "nnf"}};

/* Records a side output option's path; 0 if c is no such option. */
int ts_synth_output_option(ts_output_paths *t, int c, const char *path) {
  for (size_t i = 0; i < sizeof(output_opts) / sizeof(output_opts[0]); i++) {
    if (output_opts[i].opt != c) continue;
    ts_output_set(t, output_opts[i].key, path);
    return 1;
  }
  return 0;
}

static const struct option synth_longopts[] = {
    {"ref", required_argument, 0, OPT_REF},
    {"size", required_argument, 0, OPT_SIZE},
    {"levels", required_argument, 0, OPT_LEVELS},
    {"wn", required_argument, 0, OPT_WN},
    {"wb", required_argument, 0, OPT_WB},
    {"parity", no_argument, 0, OPT_PARITY},
    {"usage-weight", required_argument, 0, OPT_USAGE},
    {"coarse-weight", required_argument, 0, OPT_COARSE},
    {"seed", required_argument, 0, OPT_SEED},
    {"rgb-search", no_argument, 0, OPT_RGB},
    {"copy-map", required_argument, 0, OPT_COPY},
    {"copy-map-raw", required_argument, 0, OPT_COPY_RAW},
    {"usage-map", required_argument, 0, OPT_USAGE_MAP},
    {"stop-level", required_argument, 0, OPT_STOP},
    {"refine", required_argument, 0, OPT_REFINE},
    {"best-of", required_argument, 0, OPT_BEST_OF},
    {"best-of-levels", required_argument, 0, OPT_BEST_OF_LEVELS},
    {"ref-fine", required_argument, 0, OPT_REF_FINE},
    {"mix-level", required_argument, 0, OPT_MIX_LEVEL},
    {"copy-accel", no_argument, 0, OPT_ACCEL},
    {"copy-accel-kernel", required_argument, 0, OPT_ACCEL_KERNEL},
    {"copy-accel-min", required_argument, 0, OPT_ACCEL_MIN},
    {"lbg", required_argument, 0, OPT_LBG},
    {"lbg-levels", required_argument, 0, OPT_LBG_LEVELS},
    {"lbg-probe", required_argument, 0, OPT_LBG_PROBE},
    {"lbg-exact", no_argument, 0, OPT_LBG_EXACT},
    TS_JOB_LONGOPTS,
    {0, 0, 0, 0}};

typedef struct {
  ts_job_cmd job;
  int have_size;
  int have_accel_tuning; /* --copy-accel-kernel or --copy-accel-min */
} synth_opts;

static int synth_option(synth_opts *o, int c, const char *arg, char *err) {
  ts_mrf_params *p = (ts_mrf_params *)o->job.spec.params.bytes;
  long v;
  int rc = 0;
  switch (c) {
  case OPT_REF: o->job.in[0] = arg; break;
  case OPT_SIZE: rc = ts_arg_size("--size", arg, &p->width, &p->height, err); o->have_size = 1; break;
  case OPT_LEVELS: rc = ts_arg_long("--levels", arg, -1000, 1000, &v, err); p->levels = (int)v; break;
  case OPT_WN: rc = ts_arg_long("--wn", arg, -1000, 1000, &v, err); p->wn = (int)v; break;
  case OPT_WB: rc = ts_arg_long("--wb", arg, -1000, 1000, &v, err); p->wb = (int)v; break;
  case OPT_PARITY: p->parity = 1; break;
  case OPT_USAGE: rc = ts_arg_double("--usage-weight", arg, &p->usage_weight, err); break;
  case OPT_COARSE: rc = ts_arg_double("--coarse-weight", arg, &p->coarse_weight, err); break;
  case OPT_SEED: rc = ts_arg_u64("--seed", arg, &p->seed, err); break;
  case OPT_RGB: p->rgb_search = 1; break;
  case OPT_STOP: rc = ts_arg_long("--stop-level", arg, -1000, 1000, &v, err); p->stop_level = (int)v; break;
  case OPT_REFINE: rc = ts_arg_long("--refine", arg, -1000, 1000, &v, err); p->refine = (int)v; break;
  case OPT_BEST_OF: rc = ts_arg_long("--best-of", arg, -1000, 1000, &v, err); p->best_of = (int)v; break;
  case OPT_BEST_OF_LEVELS:
    rc = ts_arg_long("--best-of-levels", arg, -1000, 1000, &v, err);
    p->best_of_levels = (int)v;
    break;
  case OPT_REF_FINE: o->job.in[1] = arg; break;
  case OPT_MIX_LEVEL: rc = ts_arg_long("--mix-level", arg, -1000, 1000, &v, err); p->mix_level = (int)v; break;
  case OPT_ACCEL: p->copy_accel = 1; break;
  case OPT_ACCEL_KERNEL:
    rc = ts_arg_long("--copy-accel-kernel", arg, -1000, 1000, &v, err);
    p->accel_kernel = (int)v;
    o->have_accel_tuning = 1;
    break;
  case OPT_ACCEL_MIN: rc = ts_arg_double("--copy-accel-min", arg, &p->accel_min, err); o->have_accel_tuning = 1; break;
  case OPT_LBG: rc = ts_arg_long("--lbg", arg, 0, TS_LBG_MAX_PARTITIONS, &v, err); p->lbg = (int)v; break;
  case OPT_LBG_PROBE:
    rc = ts_arg_long("--lbg-probe", arg, 1, TS_LBG_MAX_PARTITIONS, &v, err);
    p->lbg_probe = (int)v;
    break;
  case OPT_LBG_EXACT: p->lbg_exact = 1; break;
  case OPT_LBG_LEVELS:
    if (ts_mrf_lbg_levels_parse(arg, &p->lbg_levels) != 0)
      rc = ts_error(err, TS_EINVAL, "--lbg-levels %s: need \"all\" or level numbers 0..%d separated by commas, "
                    "e.g. 0,1", arg, TS_MRF_MAX_LEVELS - 1);
    break;
  default:
    rc = ts_job_option(&o->job, c, arg, err);
    if (rc == TS_ENOENT && ts_synth_output_option(&o->job.out, c, arg)) rc = 0;
    if (rc == TS_ENOENT) rc = ts_error(err, TS_EINVAL, "unknown option (see texsyn synth --help)");
  }
  return rc;
}

/* Options that mean something only together. */
static int synth_check_pairs(const synth_opts *o, const ts_mrf_params *p, char *err) {
  if ((o->job.in[1] != NULL) != (p->mix_level != 0))
    return ts_error(err, TS_EINVAL, "--ref-fine IMG and --mix-level M go together (texture mixing)");
  if (p->best_of_levels != 0 && p->best_of == 1)
    return ts_error(err, TS_EINVAL, "--best-of-levels needs --best-of K with K > 1");
  if (o->have_accel_tuning && !p->copy_accel)
    return ts_error(err, TS_EINVAL, "--copy-accel-kernel and --copy-accel-min need --copy-accel");
  return 0;
}

static int synth_parse(int argc, char **argv, synth_opts *o, char *err) {
  memset(o, 0, sizeof(*o));
  ts_job_cmd_init(&o->job, "synth", ts_engine_find("mrf"));
  optind = 1;
  opterr = 0;
  int c;
  while ((c = getopt_long(argc, argv, "o:h", synth_longopts, NULL)) != -1) {
    if (c == TS_OPT_HELP || c == 'h') {
      usage_synth(stdout);
      exit(0);
    }
    if (c == '?' || c == ':') return ts_arg_unknown("synth", argv[optind - 1], synth_longopts, err);
    int rc = synth_option(o, c, optarg, err);
    if (rc != 0) return rc;
  }
  if (optind < argc) return ts_error(err, TS_EINVAL, "unexpected argument '%s'", argv[optind]);
  if (o->job.in[0] == NULL) return ts_error(err, TS_EINVAL, "--ref IMG is required (see texsyn synth --help)");
  int rc = ts_job_parse_end(&o->job, err);
  if (rc != 0) return rc;
  if (!o->have_size) return ts_error(err, TS_EINVAL, "--size WxH is required (see texsyn synth --help)");
  const ts_mrf_params *p = (const ts_mrf_params *)o->job.spec.params.bytes;
  if (o->job.server != NULL && p->stop_level != 0)
    return ts_error(err, TS_EINVAL, "--stop-level previews run embedded only (add --embedded)");
  return synth_check_pairs(o, p, err);
}

int ts_cmd_synth(int argc, char **argv) {
  if (ts_fill_wanted(argc, argv)) return ts_cmd_fill(argc, argv);
  char err[TS_ERR_LEN] = "";
  synth_opts o;
  if (synth_parse(argc, argv, &o, err) != 0) {
    fprintf(stderr, "texsyn synth: %s\n", err);
    return 2;
  }
  return ts_job_run(&o.job);
}

