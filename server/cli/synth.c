/* synth.c - `texsyn synth`: its options and --help, checked, then run as
 * an mrf job (jobcmd.h) in-process or on a coordinator. Its parameters
 * are the engine's (mrf_params.c): only the inputs are its own. */
#include "synth.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "fillcmd.h"
#include "mrf.h"
#include "paramopt.h"
#include "util.h"

static void usage_synth(FILE *f, const ts_engine *e) {
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
          "  --ref-fine IMG       texture mixing: levels below --mix-level from IMG (a small\n"
          "                       crop for local structure), the coarser ones from --ref\n");
  ts_paramopt_help(f, e);
  fprintf(f,
          "%s"
          "\n"
          "TEXSYN_SIMD=scalar|mmx|sse2|avx2|avx512 forces a kernel variant.\n",
          ts_job_options_help);
}

/* The side outputs' options, by the output's spec key, for `texsyn fetch`
 * (-o and --report are every job's). */
static const struct {
  int opt;
  const char *key;
} output_opts[] = {{OPT_COPY, "copy_map"}, {OPT_COPY_RAW, "copy_map_raw"}, {OPT_USAGE_MAP, "usage_map"},
                   {OPT_NNF, "nnf"}};

int ts_synth_output_option(ts_output_paths *t, int c, const char *path) {
  for (size_t i = 0; i < sizeof(output_opts) / sizeof(output_opts[0]); i++) {
    if (output_opts[i].opt != c) continue;
    ts_output_set(t, output_opts[i].key, path);
    return 1;
  }
  return 0;
}

static const struct option synth_own[] = {
    {"ref", required_argument, 0, OPT_REF}, {"ref-fine", required_argument, 0, OPT_REF_FINE}, TS_JOB_LONGOPTS,
    {0, 0, 0, 0}};

typedef struct {
  ts_job_cmd *job;
  int levels_given; /* without --levels, an output too small for the default takes as many as it holds */
} synth_ctx;

/* Its own options: the inputs; it notes --levels (taken as the others). */
static int synth_option(void *ctx, int c, const char *arg, int argc, char **argv, char *err) {
  (void)argc, (void)argv, (void)err;
  synth_ctx *s = ctx;
  const ts_param *t = s->job->spec.engine->params;
  if (c == TS_OPT_PARAM + (int)(ts_param_find(t, "levels") - t)) s->levels_given = 1;
  if (c == OPT_REF) s->job->in[0] = arg;
  else if (c == OPT_REF_FINE) s->job->in[1] = arg;
  else return TS_ENOENT;
  return 0;
}

/* The default levels, or as many as the --size holds. */
static int fit_levels(ts_job_cmd *o, char *err) {
  char size[64], levels[16];
  int w, h;
  ts_param_format(ts_param_find(o->spec.engine->params, "size"), &o->spec.params, size, sizeof(size));
  if (ts_parse_size(size, TS_OUTPUT_SIDE_MAX, &w, &h) != 0) return 0; /* the check names it */
  snprintf(levels, sizeof(levels), "%d",
           ts_mrf_levels_that_fit(w, h, (int)ts_paramopt_number(o, "wn"), (int)ts_paramopt_number(o, "levels")));
  return ts_job_set_key(o, "levels", levels, "--levels", err);
}

static int synth_parse(int argc, char **argv, ts_job_cmd *o, char *err) {
  ts_job_cmd_init(o, "synth", ts_engine_find("mrf"));
  static const ts_cmd_options cmd = {"o:h", synth_own, synth_option, usage_synth};
  synth_ctx ctx = {o, 0};
  int rc = ts_paramopt_parse(o, &cmd, &ctx, argc, argv, err);
  if (rc != 0) return rc;
  if (o->in[0] == NULL) return ts_error(err, TS_EINVAL, "--ref IMG is required (see texsyn synth --help)");
  rc = ts_job_parse_end(o, err);
  if (rc != 0) return rc;
  if (o->spec.engine->spec_complete(&o->spec.params, err) != 0)
    return ts_error(err, TS_EINVAL, "--size WxH is required (see texsyn synth --help)");
  if (!ctx.levels_given && fit_levels(o, err) != 0) return TS_EINVAL;
  if ((o->in[1] != NULL) != (ts_paramopt_number(o, "mix_level") != 0))
    return ts_error(err, TS_EINVAL, "--ref-fine IMG and --mix-level M go together (texture mixing)");
  return ts_paramopt_check(o, err);
}

int ts_cmd_synth(int argc, char **argv) {
  if (ts_fill_wanted(argc, argv)) return ts_cmd_fill(argc, argv);
  char err[TS_ERR_LEN] = "";
  ts_job_cmd o;
  if (synth_parse(argc, argv, &o, err) != 0) {
    fprintf(stderr, "texsyn synth: %s\n", err);
    return 2;
  }
  return ts_job_run(&o);
}
