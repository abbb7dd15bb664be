/* stylize.c - `texsyn stylize`'s options, named after Ebsynth's so its
 * users find their way (-style, -guide SRC TGT, -weight after what it
 * weighs, -patchsize, -pyramidlevels, -searchvoteiters, -uniformity); the
 * job itself runs through jobcmd.h like every job. */
#include "stylize.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "jobcmd.h"
#include "stylit.h"

static void usage(FILE *f) {
  fprintf(f,
          "usage: texsyn stylize --style EXEMPLAR --guide SRC TGT [--weight W] [--guide SRC TGT ...]\n"
          "                      -o OUT [options]\n"
          "\n"
          "Paints the target in the style of EXEMPLAR (StyLit-style guided synthesis, with\n"
          "an occurrence-map uniformity term): each guide pair tells which exemplar region\n"
          "goes where - SRC lies on the exemplar, TGT on the output (render passes,\n"
          "segmentations). Exact: every target patch takes the best source patch (ties to\n"
          "the lowest index), so a job and seed give the same bytes on any machine.\n"
          "\n"
          "  --style IMG          the painted exemplar; the output has its channels, 8-bit,\n"
          "                       at the target guides' size\n"
          "  --guide SRC TGT      a guide pair: SRC the exemplar's size, TGT the output's;\n"
          "                       1..%d pairs; 8/16-bit as is, float (EXR) passes stretched\n"
          "                       per channel over the pair's range\n"
          "  --weight W           the weight of the --style or --guide just before it:\n"
          "                       0 or 0.01..100; the style 1, each of N guides 1/N by\n"
          "                       default (weights count whole images, whatever their channels)\n"
          "  --patch-size P       patch width, odd, 3..%d (default 5)\n"
          "  --levels L           pyramid levels, 1..%d (default: as many as leave 4 patches\n"
          "                       on each side of the coarsest level, at most 6)\n"
          "  --iters K            search-and-vote iterations per level, 1..100 (default 6)\n"
          "  --uniformity U       how much a source patch used more than its share costs,\n"
          "                       0..1000 (default 1; 0 = off): U = 1 charges a patch used\n"
          "                       at the average rate one grey level per compared value\n"
          "  --seed S             seed of the coarsest level's random start (default 1)\n"
          "  --nnf F              the nearest-neighbour field: for each output pixel the\n"
          "                       exemplar pixel it comes from (.raw: little-endian uint32\n"
          "                       x, y pairs; else a 16-bit image, red = x, green = y)\n"
          "%s",
          TS_STYLIT_MAX_GUIDES, TS_STYLIT_MAX_PATCH, TS_STYLIT_MAX_LEVELS, ts_job_options_help);
}

enum { OPT_STYLE = TS_OPT_OWN, OPT_GUIDE, OPT_WEIGHT, OPT_PATCH, OPT_LEVELS, OPT_ITERS, OPT_UNIFORMITY, OPT_SEED, OPT_NNF };

static const struct option longopts[] = {
    {"style", required_argument, 0, OPT_STYLE},       {"guide", required_argument, 0, OPT_GUIDE},
    {"weight", required_argument, 0, OPT_WEIGHT},     {"patch-size", required_argument, 0, OPT_PATCH},
    {"levels", required_argument, 0, OPT_LEVELS},     {"iters", required_argument, 0, OPT_ITERS},
    {"uniformity", required_argument, 0, OPT_UNIFORMITY}, {"seed", required_argument, 0, OPT_SEED},
    {"nnf", required_argument, 0, OPT_NNF},           TS_JOB_LONGOPTS,
    {0, 0, 0, 0}};

typedef struct {
  ts_job_cmd job;
  int guides;
  int weighs; /* what --weight sets: -1 nothing yet, 0 the style, k + 1 guide k */
} stylize_opts;

static ts_stylit_params *params(stylize_opts *o) { return (ts_stylit_params *)o->job.spec.params.bytes; }

/* --guide SRC TGT: getopt hands over SRC; TGT is the next word. */
static int guide_option(stylize_opts *o, int argc, char **argv, const char *src, char *err) {
  if (optind >= argc) return ts_error(err, TS_EINVAL, "--guide %s: needs a target guide after it (--guide SRC TGT)", src);
  if (o->guides == TS_STYLIT_MAX_GUIDES)
    return ts_error(err, TS_EINVAL, "--guide: at most %d guide pairs", TS_STYLIT_MAX_GUIDES);
  o->job.in[ts_stylit_in_src(o->guides)] = src;
  o->job.in[ts_stylit_in_tgt(o->guides)] = argv[optind++];
  o->weighs = ++o->guides;
  return 0;
}

static int weight_option(stylize_opts *o, const char *arg, char *err) {
  double w;
  if (o->weighs < 0)
    return ts_error(err, TS_EINVAL, "--weight %s: put it after the --style or --guide it weighs", arg);
  int rc = ts_arg_double("--weight", arg, &w, err);
  if (rc == 0 && w < 0) rc = ts_error(err, TS_EINVAL, "--weight %s: need 0 or 0.01..100", arg);
  if (rc == 0 && o->weighs == 0) params(o)->style_weight = w;
  else if (rc == 0) params(o)->weight[o->weighs - 1] = w;
  return rc;
}

static int stylize_option(stylize_opts *o, int c, int argc, char **argv, char *err) {
  ts_stylit_params *p = params(o);
  long v;
  int rc = 0;
  switch (c) {
  case OPT_STYLE: o->job.in[TS_STYLIT_IN_STYLE] = optarg; o->weighs = 0; break;
  case OPT_GUIDE: rc = guide_option(o, argc, argv, optarg, err); break;
  case OPT_WEIGHT: rc = weight_option(o, optarg, err); break;
  case OPT_PATCH: rc = ts_arg_long("--patch-size", optarg, -1000, 1000, &v, err); p->patch = (int)v; break;
  case OPT_LEVELS: rc = ts_arg_long("--levels", optarg, -1000, 1000, &v, err); p->levels = (int)v; break;
  case OPT_ITERS: rc = ts_arg_long("--iters", optarg, -1000, 1000, &v, err); p->iters = (int)v; break;
  case OPT_UNIFORMITY: rc = ts_arg_double("--uniformity", optarg, &p->uniformity, err); break;
  case OPT_SEED: rc = ts_arg_u64("--seed", optarg, &p->seed, err); break;
  case OPT_NNF: ts_output_set(&o->job.out, "nnf", optarg); break;
  default:
    rc = ts_job_option(&o->job, c, optarg, err);
    if (rc == TS_ENOENT) rc = ts_error(err, TS_EINVAL, "unknown option (see texsyn stylize --help)");
  }
  return rc;
}

/* '+': no reordering of argv, so the word after --guide SRC is its TGT. */
static int stylize_parse(int argc, char **argv, stylize_opts *o, char *err) {
  memset(o, 0, sizeof(*o));
  ts_job_cmd_init(&o->job, "stylize", ts_engine_find("stylize"));
  o->weighs = -1;
  optind = 1;
  opterr = 0;
  int c;
  while ((c = getopt_long(argc, argv, "+o:h", longopts, NULL)) != -1) {
    if (c == TS_OPT_HELP || c == 'h') {
      usage(stdout);
      exit(0);
    }
    if (c == '?' || c == ':')
      return ts_error(err, TS_EINVAL, "%s: unknown option or missing value (see texsyn stylize --help)",
                      argv[optind - 1]);
    int rc = stylize_option(o, c, argc, argv, err);
    if (rc != 0) return rc;
  }
  if (optind < argc) return ts_error(err, TS_EINVAL, "unexpected argument '%s'", argv[optind]);
  if (o->job.in[TS_STYLIT_IN_STYLE] == NULL)
    return ts_error(err, TS_EINVAL, "--style EXEMPLAR is required (see texsyn stylize --help)");
  if (o->guides == 0) return ts_error(err, TS_EINVAL, "at least one --guide SRC TGT is required");
  params(o)->guides = o->guides;
  return ts_job_parse_end(&o->job, err);
}

int ts_cmd_stylize(int argc, char **argv) {
  char err[TS_ERR_LEN] = "";
  stylize_opts o;
  if (stylize_parse(argc, argv, &o, err) != 0) {
    fprintf(stderr, "texsyn stylize: %s\n", err);
    return 2;
  }
  return ts_job_run(&o.job);
}
