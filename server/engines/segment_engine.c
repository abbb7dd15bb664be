/* segment_engine.c - texture segmentation (segment.h) as an engine
 * (engine.h): its spec keys, its inputs ("input", "train0", "labels0",
 * ..., "truth"), its results (the label raster, the JSON report, and with
 * a truth the accuracy table the CLI prints). No checkpoints: a job a
 * coordinator restart interrupts runs again from its start, which gives
 * the same bytes. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "engine.h"
#include "error.h"
#include "segment.h"
#include "util.h"

_Static_assert(sizeof(ts_seg_params) <= TS_ENGINE_PARAMS_MAX, "segment parameters outgrew ts_engine_params");
_Static_assert(2 + 2 * TS_SEG_MAX_PAIRS <= TS_ENGINE_MAX_INPUTS, "segment inputs outgrew ts_engine_inputs");

enum { OUT_LABELS, OUT_REPORT, OUT_ACCURACY, OUT_PALETTE, OUT_COUNT };

static const ts_engine_output seg_outputs[OUT_COUNT] = {
    [OUT_LABELS] = {"output", "out", TS_OUTPUT_IMAGE},
    [OUT_REPORT] = {"report", "report.json", TS_OUTPUT_FLAG},
    [OUT_ACCURACY] = {"accuracy", "accuracy.txt", TS_OUTPUT_FLAG},
    [OUT_PALETTE] = {"palette", "palette", TS_OUTPUT_IMAGE, "palette",
                     "the labels as an 8-bit RGB image to look at: each class value its own colour, the same on "
                     "every run"},
};

static void seg_params_default(void *params) { ts_seg_params_default(params); }

static void seg_inputs(const void *params, ts_engine_inputs *out) {
  const ts_seg_params *p = params;
  out->n = ts_seg_ninputs(p);
  snprintf(out->name[TS_SEG_IN_INPUT], TS_ENGINE_KEY_LEN, "input");
  for (int k = 0; k < (out->n - 1 - p->truth) / 2; k++) {
    snprintf(out->name[ts_seg_in_train(k)], TS_ENGINE_KEY_LEN, "train%d", k);
    snprintf(out->name[ts_seg_in_labels(k)], TS_ENGINE_KEY_LEN, "labels%d", k);
  }
  if (p->truth) snprintf(out->name[out->n - 1], TS_ENGINE_KEY_LEN, "truth");
}

/* ---- spec keys ----------------------------------------------------------- */

static int seg_spec_set(void *params, const char *k, const char *v) {
  return ts_params_set(ts_seg_param_table, params, k, v);
}

static int seg_spec_complete(const void *params, char *err) {
  (void)params, (void)err;
  return 0;
}

static int seg_spec_format(const void *params, char *buf, size_t cap) {
  return ts_params_format(ts_seg_param_table, params, buf, cap);
}

/* The inputs named by their options (the CLI names its files itself). */
static int seg_check(const void *params, const ts_image *const *in, char *msg, size_t len) {
  const ts_seg_params *p = params;
  char names[2 * TS_SEG_MAX_PAIRS + 2][TS_SEG_NAME_LEN];
  const char *np[2 * TS_SEG_MAX_PAIRS + 2];
  ts_seg_role_names(p, names);
  for (int k = 0; k < ts_seg_ninputs(p); k++) np[k] = names[k];
  return ts_seg_check(p, in, np, msg, len);
}

static void seg_set_max_pixels(void *params, uint64_t max_pixels) {
  ((ts_seg_params *)params)->max_pixels = max_pixels;
}

/* The labels (2 bytes a pixel at most), the report and the table. */
static uint64_t seg_result_bytes(const void *params, const ts_engine_wants *w, const ts_image_info *in) {
  (void)params;
  uint64_t per_px = 2 + (w->want[OUT_PALETTE][0] ? 3 : 0);
  return (uint64_t)in[TS_SEG_IN_INPUT].width * (uint64_t)in[TS_SEG_IN_INPUT].height * per_px + 65536;
}

static int seg_levels(const void *params) { return ((const ts_seg_params *)params)->levels; }

/* ---- running ------------------------------------------------------------- */

struct ts_engine_run {
  const ts_seg_params *p;
  const ts_search *search;
  const ts_meta *meta; /* the input's, passed to the labels (georeferencing) */
  ts_seg_result res;
};

static int seg_run(const void *params, const ts_image *const *in, ts_search *search, const ts_engine_hooks *h,
                   ts_engine_run **out, char *err) {
  ts_engine_run *r = calloc(1, sizeof(*r));
  *out = r;
  if (r == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  r->p = params;
  r->search = search;
  r->meta = in[TS_SEG_IN_INPUT]->meta;
  ts_seg_hooks sh = {h->progress, h->progress_ctx};
  return ts_seg_run(r->p, in, search, &sh, &r->res, err);
}

/* ---- the report ---------------------------------------------------------- */

static double share(uint64_t part, uint64_t whole) { return whole > 0 ? (double)part / (double)whole : 0.0; }

/* A level's rates or weights (one per class) as a JSON array; a rate of a
 * class absent at that level is null. */
static void put_row(FILE *f, const double *row, int n) {
  fputc('[', f);
  for (int k = 0; k < n; k++)
    if (row[k] < 0) fprintf(f, "%snull", k ? ", " : "");
    else fprintf(f, "%s%.6f", k ? ", " : "", row[k]);
  fputc(']', f);
}

static void report_levels(FILE *f, const ts_seg_result *res) {
  size_t n = (size_t)res->classes.n;
  uint64_t pixels = (uint64_t)res->level[0].w * (uint64_t)res->level[0].h;
  fprintf(f, "  \"levels\": [\n");
  for (int l = res->levels - 1; l >= 0; l--) {
    const ts_seg_level_stats *s = &res->level[l];
    fprintf(f, "    {\"level\": %d, \"size\": [%d, %d], \"queries\": %llu, \"self_queries\": %llu, "
               "\"comparisons\": %llu, \"seconds\": %.4f, \"self_seconds\": %.4f",
            l, s->w, s->h, (unsigned long long)s->queries, (unsigned long long)s->self_queries,
            (unsigned long long)s->pairs, s->seconds, s->self_seconds);
    if (res->levels > 1) {
      fprintf(f, ", \"self_rate\": ");
      put_row(f, res->rate + (size_t)l * n, (int)n);
      fprintf(f, ", \"weight\": ");
      put_row(f, res->weight + (size_t)l * n, (int)n);
    }
    if (res->has_truth) fprintf(f, ", \"accuracy\": %.6f", share(s->correct, pixels));
    fprintf(f, "}%s\n", l > 0 ? "," : "");
  }
  fprintf(f, "  ],\n");
}

static void report_accuracy(FILE *f, const ts_seg_result *res) {
  uint64_t all = 0, before = 0, after = 0;
  fprintf(f, ",\n  \"accuracy\": {\"classes\": [\n");
  for (int k = 0; k < res->classes.n; k++) {
    uint64_t n = res->truth_pixels[k];
    all += n;
    before += res->correct_before[k];
    after += res->correct_after[k];
    fprintf(f, "    {\"label\": %u, \"pixels\": %llu", res->classes.value[k], (unsigned long long)n);
    if (n > 0) fprintf(f, ", \"before\": %.6f, \"after\": %.6f", share(res->correct_before[k], n),
                       share(res->correct_after[k], n));
    fprintf(f, "}%s\n", k + 1 < res->classes.n ? "," : "");
  }
  fprintf(f, "  ], \"overall\": {\"pixels\": %llu, \"before\": %.6f, \"after\": %.6f}}", (unsigned long long)all,
          share(before, all), share(after, all));
}

/* Parameters, the search (exact, no lossy shortcut), the classes, per
 * level sizes, queries, comparisons, seconds, self-segmentation rates and
 * weights, the noise reduction, and with a truth the accuracy. */
static int write_report(const ts_engine_run *r, const char *path, int threads, char *err) {
  const ts_seg_params *p = r->p;
  const ts_seg_result *res = &r->res;
  char tmp[TS_FILE_TMP_LEN];
  FILE *f = ts_file_create(path, tmp, err);
  if (f == NULL) return TS_EIO;
  fprintf(f, "{\n  \"engine\": \"segment\",\n  \"search\": {\"mode\": \"exact\", \"lossy\": [], \"backend\": \"%s\", "
             "\"simd\": \"%s\", \"threads\": %d},\n",
          r->search->ops->name, r->search->simd->name, threads);
  fprintf(f, "  \"params\": {\"pairs\": %d, \"levels\": %d, \"window\": %d, \"denoise\": %d, \"rgb_search\": %s},\n",
          p->pairs, p->levels, p->window, p->denoise, p->rgb ? "true" : "false");
  fprintf(f, "  \"classes\": [");
  for (int k = 0; k < res->classes.n; k++) fprintf(f, "%s%u", k ? ", " : "", res->classes.value[k]);
  fprintf(f, "],\n  \"seconds\": %.4f,\n  \"fuse_seconds\": %.4f,\n", res->seconds, res->fuse_seconds);
  report_levels(f, res);
  fprintf(f, "  \"denoise\": {\"min_area\": %d, \"regions_merged\": %u, \"passes\": %u, \"seconds\": %.4f}", p->denoise,
          res->denoise.merged, res->denoise.passes, res->denoise_seconds);
  if (res->has_truth) report_accuracy(f, res);
  fprintf(f, "\n}\n");
  return ts_file_commit(f, tmp, path, 1, err);
}

static int write_accuracy(const ts_engine_run *r, const char *path, char *err) {
  char text[16384];
  if (!r->res.has_truth) return ts_error(err, TS_EINVAL, "no accuracy: the job had no truth raster");
  int n = ts_seg_accuracy_text(&r->res, r->p->denoise, text, sizeof(text));
  if (n < 0) return ts_error(err, n, "the accuracy table outgrew %zu bytes", sizeof(text));
  return ts_file_write(path, text, (size_t)n, err);
}

/* Class value v's colour: hues a golden angle apart (neighbouring values
 * far apart on the wheel), two brightnesses alternating; integers only,
 * so the bytes are the same on every machine. */
static void palette_colour(unsigned v, uint8_t rgb[3]) {
  unsigned hue = (v * 40503u) & 0xffffu; /* 65536 / golden ratio */
  unsigned top = v & 1 ? 190 : 245, low = top * 35 / 100;
  unsigned sector = hue * 6 >> 16, f = (hue * 6 & 0xffffu) * (top - low) >> 16;
  unsigned up = low + f, down = top - f;
  const unsigned c[6][3] = {{top, up, low}, {down, top, low}, {low, top, up},
                            {low, down, top}, {up, low, top}, {top, low, down}};
  for (int i = 0; i < 3; i++) rgb[i] = (uint8_t)c[sector][i];
}

static int write_palette(const ts_engine_run *r, const char *path, char *err) {
  const ts_image *labels = &r->res.labels;
  ts_image out = {0};
  int rc = ts_image_alloc(&out, labels->width, labels->height, 3, TS_PIX_U8, err);
  for (size_t i = 0; rc == 0 && i < (size_t)labels->width * (size_t)labels->height; i++) {
    unsigned v = labels->type == TS_PIX_U16 ? ((const uint16_t *)labels->pixels)[i] : ((const uint8_t *)labels->pixels)[i];
    palette_colour(v, (uint8_t *)out.pixels + 3 * i);
  }
  if (rc == 0) rc = ts_image_write(path, &out, r->meta, err);
  ts_image_free(&out);
  return rc;
}

static int seg_write_output(const ts_engine_run *r, int k, const char *path, int threads, char *err) {
  switch (k) {
  case OUT_LABELS: return ts_image_write(path, &r->res.labels, r->meta, err);
  case OUT_REPORT: return write_report(r, path, threads, err);
  case OUT_ACCURACY: return write_accuracy(r, path, err);
  case OUT_PALETTE: return write_palette(r, path, err);
  default: return ts_error(err, TS_EINVAL, "the segment engine has no output %d", k);
  }
}

static void seg_run_free(ts_engine_run *r) {
  if (r == NULL) return;
  ts_seg_result_free(&r->res);
  free(r);
}

const ts_engine ts_engine_segment = {
    .name = "segment",
    .outputs = seg_outputs,
    .noutputs = OUT_COUNT,
    .params = ts_seg_param_table,
    .params_default = seg_params_default,
    .spec_set = seg_spec_set,
    .spec_complete = seg_spec_complete,
    .spec_format = seg_spec_format,
    .inputs = seg_inputs,
    .check = seg_check,
    .set_max_pixels = seg_set_max_pixels,
    .result_bytes = seg_result_bytes,
    .levels = seg_levels,
    .run = seg_run,
    .write_output = seg_write_output,
    .run_free = seg_run_free,
};
