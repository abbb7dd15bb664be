/* fill_engine.c - constrained synthesis (fill.h) of one image as an
 * engine (engine.h): `texsyn synth --input IMG --mask MASK`. The mask's
 * bright pixels (luminance >= 128) are filled; the reference is the rest of
 * the image (unless self=0) and any further images (ref0, ref1, ...).
 * Colour is gathered through the copy map (§3.8), so the output has the
 * input's pixel type and channels, and the given pixels keep their bytes.
 * A colour image is searched on its three colour channels by default, not
 * on its luminance as the seed does: in a hole of aero1.jpg the luminance
 * search put blue and orange blotches where roofs and trees of one grey
 * met (the seed's Fig. 3.35 problem), the colour search did not.
 * No checkpoints: a job a restart interrupts is filled again, with the same
 * bytes. */
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "engine.h"
#include "error.h"
#include "fill.h"
#include "outputs.h"
#include "repetition.h"
#include "util.h"

#define FILL_MAX_REFS (TS_FILL_MAX_SOURCES - 1)

typedef struct {
  ts_fill_params fill;
  int refs;            /* further reference images */
  int self;            /* the input's given part is a reference */
  double usage_weight; /* the active usage penalty */
  int rgb_search;
  uint64_t max_pixels;
} fill_job;

_Static_assert(sizeof(fill_job) <= TS_ENGINE_PARAMS_MAX, "fill parameters outgrew ts_engine_params");
_Static_assert(2 + FILL_MAX_REFS <= TS_ENGINE_MAX_INPUTS, "fill inputs outgrew ts_engine_inputs");

enum { OUT_IMAGE, OUT_COPY_MAP, OUT_COPY_MAP_RAW, OUT_REPORT, OUT_COUNT };

static const ts_engine_output fill_outputs[OUT_COUNT] = {
    [OUT_IMAGE] = {"output", "out", TS_OUTPUT_IMAGE},
    [OUT_COPY_MAP] = {"copy_map", "copymap", TS_OUTPUT_IMAGE,
                      "copy-map", "where every pixel comes from, as an image (red = x, green = y; given pixels point at themselves)"},
    [OUT_COPY_MAP_RAW] = {"copy_map_raw", "copymap.raw", TS_OUTPUT_FLAG,
                      "copy-map-raw", "the same as little-endian uint32 (x, y) per pixel"},
    [OUT_REPORT] = {"report", "report.json", TS_OUTPUT_FLAG},
};

#define F(field) offsetof(fill_job, field)

/* In the spec's order: the fill's, then the job's. */
static const ts_param fill_param_table[] = {
    TS_FILL_PARAMS(F(fill), "4", "9", "0"),
    {"refs", NULL, NULL, TS_PARAM_INT, F(refs), 0, FILL_MAX_REFS, "0", "further reference images"},
    {"self", "no-self", NULL, TS_PARAM_FLAG, F(self), 0, 1, "1", "do not copy from IMG itself (needs --ref)",
     .flags = TS_PARAM_NEGATE},
    {"usage_weight", "usage-weight", "A", TS_PARAM_DOUBLE, F(usage_weight), 0, 100, "0",
     "active usage-variance penalty, 0 = off"},
    /* Colour images are searched on their colour: see this file's head. */
    {"rgb_search", "luma-search", NULL, TS_PARAM_FLAG, F(rgb_search), 0, 1, "1",
     "search a colour image on its luminance, as the seed does; without it on its colour channels, which keeps "
     "colours from mixing where different colours have one grey", .flags = TS_PARAM_NEGATE},
    {"max_pixels", NULL, NULL, TS_PARAM_U64, F(max_pixels), 0, 0, "268435456", "image size limit",
     .flags = TS_PARAM_UNBOUNDED},
    {NULL}};

static void fill_params_default(void *params) {
  memset(params, 0, sizeof(fill_job));
  ts_params_default(fill_param_table, params);
}

/* ---- spec keys ---------------------------------------------------------- */

static int fill_spec_set(void *params, const char *k, const char *v) {
  return ts_params_set(fill_param_table, params, k, v);
}

static int fill_spec_complete(const void *params, char *err) {
  const fill_job *p = params;
  if (!p->self && p->refs == 0)
    return ts_error(err, TS_EINVAL, "job spec: self=0 needs at least one reference (refs=N)");
  return 0;
}

static int fill_spec_format(const void *params, char *buf, size_t cap) {
  return ts_params_format(fill_param_table, params, buf, cap);
}

/* The image, the mask, then the further references. */
static void fill_inputs(const void *params, ts_engine_inputs *out) {
  const fill_job *p = params;
  out->n = 0;
  snprintf(out->name[out->n++], TS_ENGINE_KEY_LEN, "input");
  snprintf(out->name[out->n++], TS_ENGINE_KEY_LEN, "mask");
  for (int i = 0; i < p->refs && i < FILL_MAX_REFS; i++) snprintf(out->name[out->n++], TS_ENGINE_KEY_LEN, "ref%d", i);
}

/* ---- the fill's inputs from the images ------------------------------------ */

/* What ts_fill_synthesize reads, built from the images. */
typedef struct {
  ts_fill_input in;
  ts_fill_class cls;
  uint8_t *state, *usable;
  uint8_t *planes[TS_FILL_MAX_SOURCES][TS_MAX_PLANES];
} fill_inputs_buf;

static void inputs_free(fill_inputs_buf *b) {
  free(b->state);
  free(b->usable);
  for (int s = 0; s < TS_FILL_MAX_SOURCES; s++)
    for (int k = 0; k < TS_MAX_PLANES; k++) free(b->planes[s][k]);
  memset(b, 0, sizeof(*b));
}

static int nplanes_of(const fill_job *p, const ts_image *img) { return p->rgb_search && img->channels >= 3 ? 3 : 1; }

/* The feature planes of an image: luminance, or its first three channels. */
static int feature_planes(const ts_image *img, int n, uint8_t **out) {
  size_t npx = (size_t)img->width * (size_t)img->height;
  for (int k = 0; k < n; k++) {
    if ((out[k] = malloc(npx)) == NULL) return TS_ENOMEM;
    if (n == 1) ts_image_luma8(img, out[k]);
    else ts_image_channel8(img, k, out[k]);
  }
  return 0;
}

static int build_inputs(const fill_job *p, const ts_image *const *in, fill_inputs_buf *b) {
  memset(b, 0, sizeof(*b));
  const ts_image *img = in[0], *mask = in[1];
  size_t npx = (size_t)img->width * (size_t)img->height;
  int n = nplanes_of(p, img);
  b->state = malloc(npx);
  b->usable = malloc(npx);
  uint8_t *luma = malloc(npx);
  int rc = b->state && b->usable && luma ? 0 : TS_ENOMEM;
  if (rc == 0) {
    ts_image_luma8(mask, luma);
    for (size_t i = 0; i < npx; i++) {
      b->state[i] = luma[i] >= 128;
      b->usable[i] = !b->state[i];
    }
  }
  free(luma);
  if (rc == 0) rc = feature_planes(img, n, b->planes[0]);
  b->in = (ts_fill_input){.w = img->width, .h = img->height, .nplanes = n, .state = b->state, .nclass = 1, .cls = &b->cls};
  for (int k = 0; k < n; k++) b->in.planes[k] = b->planes[0][k];
  b->cls.usage_weight = p->usage_weight;
  if (p->self) {
    ts_fill_source *s = &b->cls.src[b->cls.nsources++];
    *s = (ts_fill_source){.w = img->width, .h = img->height, .usable = b->usable};
    for (int k = 0; k < n; k++) s->planes[k] = b->planes[0][k];
  }
  for (int i = 0; rc == 0 && i < p->refs; i++) {
    const ts_image *r = in[2 + i];
    ts_fill_source *s = &b->cls.src[b->cls.nsources];
    rc = feature_planes(r, n, b->planes[1 + i]);
    *s = (ts_fill_source){.w = r->width, .h = r->height};
    for (int k = 0; k < n; k++) s->planes[k] = b->planes[1 + i][k];
    b->cls.nsources++;
  }
  if (rc != 0) inputs_free(b);
  return rc;
}

/* ---- checks --------------------------------------------------------------- */

static int fill_check(const void *params, const ts_image *const *in, char *msg, size_t len) {
  const fill_job *p = params;
  const ts_image *img = in[0], *mask = in[1];
  int n = 0;
  msg[0] = '\0';
  ts_fill_check_params(&p->fill, msg, len, &n);
  if ((uint64_t)img->width * (uint64_t)img->height > p->max_pixels)
    ts_problem(msg, len, &n, "--input: %dx%d pixels exceed the limit of %llu (raise --max-pixels)", img->width,
               img->height, (unsigned long long)p->max_pixels);
  if (mask->width != img->width || mask->height != img->height)
    ts_problem(msg, len, &n, "--mask is %dx%d, the input %dx%d: they must be the same size", mask->width, mask->height,
               img->width, img->height);
  for (int i = 0; i < p->refs; i++) {
    const ts_image *r = in[2 + i];
    if (r->channels != img->channels || r->type != img->type)
      ts_problem(msg, len, &n, "--ref %d has %d channels of %s, the input %d of %s: convert it (e.g. oiiotool) so "
                 "they match", i + 1, r->channels, ts_pixtype_name(r->type), img->channels, ts_pixtype_name(img->type));
  }
  if (n > 0) return TS_EINVAL;
  fill_inputs_buf b;
  if (build_inputs(p, in, &b) != 0) {
    ts_problem(msg, len, &n, "out of memory");
    return TS_ENOMEM;
  }
  size_t holes = 0;
  for (size_t i = 0; i < (size_t)img->width * (size_t)img->height; i++) holes += b.state[i];
  int rc = 0;
  if (holes == 0) {
    ts_problem(msg, len, &n, "--mask marks nothing to fill (it fills where the mask is bright: luminance >= 128)");
    rc = TS_EINVAL;
  } else {
    rc = ts_fill_check(&p->fill, &b.in, NULL, msg, len);
  }
  inputs_free(&b);
  return rc;
}

static void fill_set_max_pixels(void *params, uint64_t max_pixels) { ((fill_job *)params)->max_pixels = max_pixels; }

/* The output (the input's type), the copy map image (8 bytes a pixel). */
static uint64_t fill_result_bytes(const void *params, const ts_engine_wants *w, const ts_image_info *in) {
  (void)params;
  uint64_t px = (uint64_t)in[0].width * (uint64_t)in[0].height;
  return px * ((uint64_t)in[0].channels * ts_pixtype_size(in[0].type) + (w->want[OUT_COPY_MAP][0] ? 8 : 0) +
               (w->want[OUT_COPY_MAP_RAW][0] ? 8 : 0)) + 4096;
}

static int fill_levels(const void *params) { return ((const fill_job *)params)->fill.levels; }

/* ---- running ------------------------------------------------------------- */

struct ts_engine_run {
  const fill_job *p;
  const ts_image *const *in;
  const ts_search *search;
  ts_fill_result res;
};

static int fill_run(const void *params, const ts_image *const *in, ts_search *search, const ts_engine_hooks *h,
                    ts_engine_run **out, char *err) {
  ts_engine_run *r = calloc(1, sizeof(*r));
  *out = r;
  if (r == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  r->p = params;
  r->in = in;
  r->search = search;
  fill_inputs_buf b;
  if (build_inputs(r->p, in, &b) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
  ts_progress_hooks fh = {.progress = h->progress, .progress_ctx = h->progress_ctx};
  int rc = ts_fill_synthesize(&r->p->fill, &b.in, search, &fh, &r->res, err);
  inputs_free(&b);
  return rc;
}

/* The image a filled pixel's source number names. */
static const ts_image *source_image(const ts_engine_run *r, int s) { return r->in[r->p->self ? (s == 0 ? 0 : 1 + s) : 2 + s]; }

static int write_image(const ts_engine_run *r, const char *path, char *err) {
  const ts_image *img = r->in[0];
  ts_image outi;
  int rc = ts_image_alloc(&outi, img->width, img->height, img->channels, img->type, err);
  if (rc != 0) return rc;
  const ts_fill_result *res = &r->res;
  for (int y = 0; y < img->height; y++)
    for (int x = 0; x < img->width; x++) {
      size_t o = (size_t)y * (size_t)img->width + (size_t)x;
      if (res->source[o] == TS_FILL_NO_SOURCE) ts_image_copy_pixel(&outi, x, y, img, x, y);
      else ts_image_copy_pixel(&outi, x, y, source_image(r, res->source[o]), (int)res->copy[2 * o], (int)res->copy[2 * o + 1]);
    }
  rc = ts_image_write(path, &outi, img->meta, err);
  ts_image_free(&outi);
  return rc;
}

/* Where every pixel comes from: given pixels point at themselves. */
static uint32_t *whole_copy_map(const ts_fill_result *res) {
  size_t npx = (size_t)res->w * (size_t)res->h;
  uint32_t *map = malloc(sizeof(uint32_t) * 2 * npx);
  for (size_t i = 0; map != NULL && i < npx; i++) {
    int given = res->source[i] == TS_FILL_NO_SOURCE;
    map[2 * i] = given ? (uint32_t)(i % (size_t)res->w) : res->copy[2 * i];
    map[2 * i + 1] = given ? (uint32_t)(i / (size_t)res->w) : res->copy[2 * i + 1];
  }
  return map;
}

static int write_copy_map(const ts_engine_run *r, int raw, const char *path, char *err) {
  const ts_fill_result *res = &r->res;
  uint32_t *map = whole_copy_map(res);
  if (map == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  int rc = raw ? ts_write_copy_map_raw(path, map, res->w, res->h, err)
               : ts_write_copy_map_image(path, map, res->w, res->h, res->w, res->h, err);
  free(map);
  return rc;
}

/* The repetition score of the filled pixels (repetition.h; given ones
 * left out), each source image a reference of its own. */
static void report_repetition(FILE *f, const ts_engine_run *r) {
  const ts_fill_result *res = &r->res;
  size_t npx = (size_t)res->w * (size_t)res->h;
  uint32_t *map = malloc(sizeof(uint32_t) * 2 * npx);
  int nsrc = 0, rw = 1, rh = 1;
  for (size_t i = 0; map != NULL && i < npx; i++) {
    int s = res->source[i];
    map[2 * i] = s == TS_FILL_NO_SOURCE ? UINT32_MAX : res->copy[2 * i];
    map[2 * i + 1] = res->copy[2 * i + 1];
    if (s != TS_FILL_NO_SOURCE && s >= nsrc) nsrc = s + 1;
  }
  for (int s = 0; s < nsrc; s++) {
    const ts_image *img = source_image(r, s);
    rw = img->width > rw ? img->width : rw;
    rh = img->height > rh ? img->height : rh;
  }
  ts_repetition rep;
  char err[TS_ERR_LEN];
  if (map != NULL && nsrc > 0 &&
      ts_repetition_score(map, res->source, nsrc, res->w, res->h, rw, rh, TS_REPETITION_SIDE, &rep, err) == 0)
    fprintf(f, "  \"repetition\": {\"side\": %d, \"share\": %.6f, \"repeated\": %llu, \"in_large\": %llu, "
               "\"filled\": %llu},\n",
            rep.side, rep.share, (unsigned long long)rep.repeated, (unsigned long long)rep.large,
            (unsigned long long)rep.pixels);
  free(map);
}

static int write_report(const ts_engine_run *r, const char *path, int threads, char *err) {
  char tmp[TS_FILE_TMP_LEN];
  FILE *f = ts_file_create(path, tmp, err);
  if (f == NULL) return TS_EIO;
  const fill_job *p = r->p;
  fprintf(f, "{\n  \"engine\": \"fill\",\n  \"search\": {\"mode\": \"exact\", \"lossy\": [], \"backend\": \"%s\", "
             "\"simd\": \"%s\", \"threads\": %d},\n",
          r->search->ops->name, r->search->simd->name, threads);
  fprintf(f, "  \"params\": {\"refs\": %d, \"self\": %s, \"usage_weight\": %g, \"rgb_search\": %s, ", p->refs,
          p->self ? "true" : "false", p->usage_weight, p->rgb_search ? "true" : "false");
  ts_fill_report_params(f, &p->fill);
  fprintf(f, "},\n  \"seconds\": %.4f,\n  \"usage\": {\"mean\": %.6f, \"variance\": %.6f},\n", r->res.seconds,
          r->res.cls[0].usage_mean, r->res.cls[0].usage_variance);
  report_repetition(f, r);
  ts_fill_report_levels(f, &p->fill, &r->res);
  fprintf(f, "}\n");
  return ts_file_commit(f, tmp, path, 1, err);
}

static int fill_write_output(const ts_engine_run *r, int k, const char *path, int threads, char *err) {
  switch (k) {
  case OUT_IMAGE: return write_image(r, path, err);
  case OUT_COPY_MAP: return write_copy_map(r, 0, path, err);
  case OUT_COPY_MAP_RAW: return write_copy_map(r, 1, path, err);
  case OUT_REPORT: return write_report(r, path, threads, err);
  default: return ts_error(err, TS_EINVAL, "the fill engine has no output %d", k);
  }
}

static void fill_run_free(ts_engine_run *r) {
  if (r == NULL) return;
  ts_fill_result_free(&r->res);
  free(r);
}

const ts_engine ts_engine_fill = {
    .name = "fill",
    .outputs = fill_outputs,
    .noutputs = OUT_COUNT,
    .params = fill_param_table,
    .params_default = fill_params_default,
    .spec_set = fill_spec_set,
    .spec_complete = fill_spec_complete,
    .spec_format = fill_spec_format,
    .inputs = fill_inputs,
    .check = fill_check,
    .set_max_pixels = fill_set_max_pixels,
    .result_bytes = fill_result_bytes,
    .levels = fill_levels,
    .run = fill_run,
    .write_output = fill_write_output,
    .run_free = fill_run_free,
};
