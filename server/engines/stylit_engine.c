/* stylit_engine.c - guided stylization (stylit.h) as an engine (engine.h):
 * the scene's inputs and spec keys (stylit_engine.h, shared with the
 * energy engine), its own keys, result files (the image, the NNF, the
 * error map) and report. No checkpoints
 * yet: a job a coordinator restart interrupts runs again from its start,
 * which gives the same bytes. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "engine.h"
#include "error.h"
#include "outputs.h"
#include "resample.h"
#include "stylit.h"
#include "stylit_engine.h"
#include "util.h"

_Static_assert(sizeof(ts_stylit_params) <= TS_ENGINE_PARAMS_MAX, "stylize parameters outgrew ts_engine_params");
_Static_assert(1 + 2 * TS_STYLIT_MAX_GUIDES <= TS_ENGINE_MAX_INPUTS, "stylize inputs outgrew ts_engine_inputs");

enum { OUT_IMAGE, OUT_NNF, OUT_REPORT, OUT_ERROR, OUT_COUNT };

static const ts_engine_output stylit_outputs[OUT_COUNT] = {
    [OUT_IMAGE] = {"output", "out", TS_OUTPUT_IMAGE},
    [OUT_NNF] = {"nnf", "nnf", TS_OUTPUT_IMAGE,
                      "nnf", "the nearest-neighbour field: for each output pixel the exemplar pixel it comes from (.raw: little-endian uint32 x, y pairs; else a 16-bit image, red = x, green = y)", "raw"},
    [OUT_REPORT] = {"report", "report.json", TS_OUTPUT_FLAG},
    [OUT_ERROR] = {"error_map", "errormap", TS_OUTPUT_IMAGE, "error-map",
                   "per output pixel, the guided distance of its patch to the exemplar patch it took, in grey levels (.tif/.tiff/.exr: those floats; else scaled by the largest)"},
};

void ts_stylit_scene_inputs(const ts_stylit_params *p, ts_engine_inputs *out) {
  int g = p->guides < TS_STYLIT_MAX_GUIDES ? p->guides : TS_STYLIT_MAX_GUIDES;
  out->n = 1 + 2 * g;
  snprintf(out->name[TS_STYLIT_IN_STYLE], TS_ENGINE_KEY_LEN, "style");
  for (int k = 0; k < g; k++) {
    snprintf(out->name[ts_stylit_in_src(k)], TS_ENGINE_KEY_LEN, "guide_src_%d", k);
    snprintf(out->name[ts_stylit_in_tgt(k)], TS_ENGINE_KEY_LEN, "guide_tgt_%d", k);
  }
}

static void stylit_inputs(const void *params, ts_engine_inputs *out) { ts_stylit_scene_inputs(params, out); }

/* ---- spec keys ---------------------------------------------------------- */

/* weight_K: K's weight; ranges are the check's business. */
int ts_stylit_weight_set(ts_stylit_params *p, const char *k, const char *v) {
  int g;
  if (strncmp(k, "weight_", 7) != 0 || ts_parse_int(k + 7, 0, TS_STYLIT_MAX_GUIDES - 1, &g) != 0) return TS_ENOENT;
  return ts_parse_double(v, &p->weight[g]) != 0 || p->weight[g] < 0 ? TS_EINVAL : 0;
}

static int stylit_spec_set(void *params, const char *k, const char *v) {
  int rc = ts_params_set(ts_stylit_param_table, params, k, v);
  return rc != TS_ENOENT ? rc : ts_stylit_weight_set(params, k, v);
}

/* A weight for a guide the job does not have would not survive format
 * and parse. */
int ts_stylit_scene_complete(const ts_stylit_params *p, char *err) {
  for (int k = p->guides; k < TS_STYLIT_MAX_GUIDES; k++)
    if (p->weight[k] >= 0)
      return ts_error(err, TS_EINVAL, "job spec: weight_%d given for a job of %d guide%s", k, p->guides,
                      p->guides == 1 ? "" : "s");
  return 0;
}

static int stylit_spec_complete(const void *params, char *err) { return ts_stylit_scene_complete(params, err); }

/* Doubles with 17 significant digits, so they round-trip; guide weights
 * resolved (a default weight is written as the value it stands for). */
int ts_stylit_weights_format(const ts_stylit_params *p, char *buf, size_t cap) {
  int n = 0;
  for (int k = 0; n >= 0 && (size_t)n < cap && k < p->guides; k++)
    n += snprintf(buf + n, cap - (size_t)n, "weight_%d=%.17g\n", k, ts_stylit_weight(p, k));
  return n < 0 || (size_t)n >= cap ? TS_ETOOBIG : n;
}

static int stylit_spec_format(const void *params, char *buf, size_t cap) {
  int n = ts_params_format(ts_stylit_param_table, params, buf, cap);
  if (n < 0) return n;
  int k = ts_stylit_weights_format(params, buf + n, cap - (size_t)n);
  return k < 0 ? k : n + k;
}

static void stylit_params_default(void *params) { ts_stylit_params_default(params); }

/* ---- --scale: the inputs resampled first -------------------------------- */

static int scaled_side(int n, double scale) {
  int s = (int)lround(n * scale);
  return s < 1 ? 1 : s;
}

typedef struct {
  int n;
  ts_image img[TS_ENGINE_MAX_INPUTS];
  const ts_image *ptr[TS_ENGINE_MAX_INPUTS];
} scaled_inputs;

static void scaled_free(scaled_inputs *s) {
  for (int k = 0; k < s->n; k++) ts_image_free(&s->img[k]);
  s->n = 0;
}

/* The inputs the synthesis sees: in itself, or at p->scale. */
static int scaled_make(const ts_stylit_params *p, const ts_image *const *in, scaled_inputs *s, char *err) {
  int n = 1 + 2 * (p->guides < TS_STYLIT_MAX_GUIDES ? p->guides : TS_STYLIT_MAX_GUIDES);
  s->n = 0;
  for (int k = 0; k < n; k++) {
    s->ptr[k] = in[k];
    if (p->scale == 1.0) continue;
    int rc = ts_image_resample(in[k], scaled_side(in[k]->width, p->scale), scaled_side(in[k]->height, p->scale),
                               &s->img[k], err);
    s->n = k + (rc == 0);
    if (rc != 0) return rc;
    s->ptr[k] = &s->img[k];
  }
  return 0;
}

static int stylit_check(const void *params, const ts_image *const *in, char *msg, size_t len) {
  scaled_inputs s;
  char err[TS_ERR_LEN];
  int rc = scaled_make(params, in, &s, err);
  if (rc != 0) snprintf(msg, len, "%s", err);
  else rc = ts_stylit_check(params, s.ptr, msg, len);
  scaled_free(&s);
  return rc;
}

static void stylit_set_max_pixels(void *params, uint64_t max_pixels) {
  ((ts_stylit_params *)params)->max_pixels = max_pixels;
}

/* Per target pixel: the image (4 bytes at most) and the NNF (8). */
static uint64_t stylit_result_bytes(const void *params, const ts_engine_wants *w, const ts_image_info *in) {
  const ts_stylit_params *p = params;
  const ts_image_info *t = &in[ts_stylit_in_tgt(0)];
  return (uint64_t)scaled_side(t->width, p->scale) * (uint64_t)scaled_side(t->height, p->scale) *
         (4 + (w->want[OUT_NNF][0] ? 8 : 0) + (w->want[OUT_ERROR][0] ? 4 : 0));
}

static int stylit_levels(const void *params) { return ((const ts_stylit_params *)params)->levels; }

/* ---- running ------------------------------------------------------------ */

struct ts_engine_run {
  const ts_stylit_params *p;
  const ts_search *search;
  scaled_inputs in; /* what ran, kept for the error map */
  ts_stylit_result res;
};

static int stylit_run(const void *params, const ts_image *const *in, ts_search *search, const ts_engine_hooks *h,
                      ts_engine_run **out, char *err) {
  ts_engine_run *r = calloc(1, sizeof(*r));
  *out = r;
  if (r == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  r->p = params;
  r->search = search;
  ts_progress_hooks sh = {h->progress, h->progress_ctx};
  int rc = scaled_make(r->p, in, &r->in, err);
  if (rc == 0) rc = ts_stylit_run(r->p, r->in.ptr, search, &sh, &r->res, err);
  return rc;
}

/* The report: parameters, the search (its mode, and "patchmatch" among
 * the lossy shortcuts when a level ran it), per level sizes, the search
 * that ran, queries, exact comparisons and seconds, the exemplar coverage. */
static int write_report(const ts_engine_run *r, const char *path, int threads, char *err) {
  const ts_stylit_params *p = r->p;
  const ts_stylit_result *res = &r->res;
  char tmp[TS_FILE_TMP_LEN];
  FILE *f = ts_file_create(path, tmp, err);
  if (f == NULL) return TS_EIO;
  int pm_levels = 0;
  ts_stylit_params ran = *p; /* what ran, as a list (coarsest first) */
  ran.search = TS_STYLIT_LIST;
  ran.nlevel_modes = res->levels;
  for (int l = 0; l < res->levels; l++) {
    pm_levels += res->level[l].mode == TS_STYLIT_PATCHMATCH;
    ran.level_mode[res->levels - 1 - l] = (uint8_t)res->level[l].mode;
  }
  char mode[TS_STYLIT_SEARCH_LEN], levels[TS_STYLIT_SEARCH_LEN];
  ts_stylit_search_format(p, mode, sizeof(mode));
  ts_stylit_search_format(&ran, levels, sizeof(levels));
  fprintf(f, "{\n  \"engine\": \"stylize\",\n  \"search\": {\"mode\": \"%s\", \"levels\": \"%s\", \"lossy\": [%s], "
             "\"pm_iters\": %d, \"budget\": %g, \"plan_rate\": %.4g, \"backend\": \"%s\", \"simd\": \"%s\", "
             "\"threads\": %d},\n",
          mode, levels, pm_levels ? "\"patchmatch\"" : "", p->pm_iters, p->budget, res->rate, r->search->ops->name,
          r->search->simd->name, threads);
  fprintf(f, "  \"params\": {\"patch_size\": %d, \"levels\": %d, \"iters\": %d, \"uniformity\": %g, "
             "\"seed\": %llu, \"style_weight\": %g, \"guide_weights\": [",
          p->patch, res->levels, p->iters, p->uniformity, (unsigned long long)p->seed, p->style_weight);
  for (int k = 0; k < p->guides; k++) fprintf(f, "%s%g", k ? ", " : "", ts_stylit_weight(p, k));
  fprintf(f, "]},\n  \"seconds\": %.4f,\n  \"coverage\": %.6f,\n  \"levels\": [\n", res->seconds, res->coverage);
  for (int l = res->levels - 1; l >= 0; l--) {
    const ts_stylit_level_stats *s = &res->level[l];
    fprintf(f, "    {\"level\": %d, \"target\": [%d, %d], \"search\": \"%s\", \"exact_estimate_s\": %.4g, "
               "\"queries\": %llu, \"comparisons\": %llu, \"seconds\": %.4f}%s\n",
            l, s->w, s->h, ts_stylit_search_name(s->mode), s->estimate, (unsigned long long)s->queries,
            (unsigned long long)s->pairs, s->seconds, l > 0 ? "," : "");
  }
  fprintf(f, "  ]\n}\n");
  return ts_file_commit(f, tmp, path, 1, err);
}

/* The NNF: raw (x, y) uint32 pairs for a .raw path, else a 16-bit image
 * (red = x, green = y, scaled to the exemplar), as the MRF's copy map. */
static int write_nnf(const ts_stylit_result *res, const char *path, char *err) {
  int w = res->image.width, h = res->image.height;
  const char *dot = strrchr(path, '.');
  if (dot != NULL && strcmp(dot, ".raw") == 0) return ts_write_copy_map_raw(path, res->nnf, w, h, err);
  return ts_write_copy_map_image(path, res->nnf, w, h, res->src_w, res->src_h, err);
}

/* The error map (stylit.h) as a float image, written as the usage map is. */
static int write_error(const ts_engine_run *r, const char *path, char *err) {
  int w = r->res.image.width, h = r->res.image.height;
  float *e = malloc(sizeof(float) * (size_t)w * (size_t)h);
  if (e == NULL) return ts_error(err, TS_ENOMEM, "out of memory for the error map");
  int rc = ts_stylit_error_map(r->p, r->in.ptr, &r->res, e, err);
  if (rc == 0) rc = ts_write_float_map(path, e, w, h, err);
  free(e);
  return rc;
}

static int stylit_write_output(const ts_engine_run *r, int k, const char *path, int threads, char *err) {
  switch (k) {
  case OUT_IMAGE: return ts_image_write(path, &r->res.image, NULL, err);
  case OUT_NNF: return write_nnf(&r->res, path, err);
  case OUT_REPORT: return write_report(r, path, threads, err);
  case OUT_ERROR: return write_error(r, path, err);
  default: return ts_error(err, TS_EINVAL, "the stylize engine has no output %d", k);
  }
}

static void stylit_run_free(ts_engine_run *r) {
  if (r == NULL) return;
  ts_stylit_result_free(&r->res);
  scaled_free(&r->in);
  free(r);
}

const ts_engine ts_engine_stylize = {
    .name = "stylize",
    .outputs = stylit_outputs,
    .noutputs = OUT_COUNT,
    .params = ts_stylit_param_table,
    .params_default = stylit_params_default,
    .spec_set = stylit_spec_set,
    .spec_complete = stylit_spec_complete,
    .spec_format = stylit_spec_format,
    .inputs = stylit_inputs,
    .check = stylit_check,
    .set_max_pixels = stylit_set_max_pixels,
    .result_bytes = stylit_result_bytes,
    .levels = stylit_levels,
    .run = stylit_run,
    .write_output = stylit_write_output,
    .run_free = stylit_run_free,
};
