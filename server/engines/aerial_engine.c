/* aerial_engine.c - synthetic aerial images from a land-use class map
 * (Stahlhut 2004, seed 002 §5.1) as an engine (engine.h): `texsyn aerial`.
 *
 * Inputs: the class map (a raster whose pixel values are class ids), one
 * reference texture per class, and optionally a line raster. As the seed
 * does (§5.1.3), lines - roads, paths, rivers: the line raster's pixels
 * whose value has a colour - are drawn first, in that colour; then the
 * classes are filled by constrained synthesis (fill.h), stochastic classes
 * first, structured ones after, each from its own reference with its own
 * usage penalty, against the three-state mask (its own area to fill, lines
 * and the classes before it known, the later classes unknown). Colour is
 * gathered from the references through the copy map (§3.8); the output is
 * 8-bit RGB, written with the class map's metadata (a GeoTIFF's
 * georeferencing stays). No checkpoints: a job a restart interrupts runs
 * again, with the same bytes. */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "engine.h"
#include "error.h"
#include "fill.h"
#include "util.h"

#define AERIAL_NAME_LEN 64
#define AERIAL_MAX_COLOURS 256
#define AERIAL_MAX_ID 65535

enum { KIND_STOCHASTIC = 0, KIND_STRUCTURED = 1 };

typedef struct {
  int id, kind;
  double usage_weight;
  char name[AERIAL_NAME_LEN];
} aerial_class;

typedef struct {
  int value;
  uint8_t rgb[3];
} aerial_colour;

typedef struct {
  ts_fill_params fill;
  int nclass; /* in the catalogue's order */
  aerial_class cls[TS_FILL_MAX_CLASSES];
  int lines;  /* a line raster is an input */
  int ncolours;
  aerial_colour colour[AERIAL_MAX_COLOURS];
  uint64_t max_pixels;
} aerial_job;

_Static_assert(sizeof(aerial_job) <= TS_ENGINE_PARAMS_MAX, "aerial parameters outgrew ts_engine_params");
/* The class map, a reference per class and the lines are the inputs. */
#define AERIAL_MAX_CLASSES (TS_ENGINE_MAX_INPUTS - 2)
_Static_assert(AERIAL_MAX_CLASSES <= TS_FILL_MAX_CLASSES, "aerial classes outgrew the fill's");

enum { OUT_IMAGE, OUT_REPORT, OUT_COUNT };

static const ts_engine_output aerial_outputs[OUT_COUNT] = {
    [OUT_IMAGE] = {"output", "out", TS_OUTPUT_IMAGE},
    [OUT_REPORT] = {"report", "report.json", TS_OUTPUT_FLAG},
};

#define F(field) offsetof(aerial_job, field)

/* In the spec's order; the classes' and colours' lines (classK, colourK)
 * come from the catalogue, after them. */
static const ts_param aerial_param_table[] = {
    TS_FILL_PARAMS(F(fill), "3", "7"),
    {"max_pixels", NULL, NULL, TS_PARAM_U64, F(max_pixels), 0, 0, "268435456", "image size limit",
     .flags = TS_PARAM_UNBOUNDED},
    {"classes", NULL, NULL, TS_PARAM_INT, F(nclass), 1, AERIAL_MAX_CLASSES, NULL, "classes of the catalogue"},
    {"lines", NULL, NULL, TS_PARAM_FLAG, F(lines), 0, 1, "0", "a line raster is an input"},
    {"colours", NULL, NULL, TS_PARAM_INT, F(ncolours), 0, AERIAL_MAX_COLOURS, "0", "colours of the line raster"},
    {NULL}};

static void aerial_params_default(void *params) {
  memset(params, 0, sizeof(aerial_job));
  ts_params_default(aerial_param_table, params);
}

/* ---- spec keys ------------------------------------------------------------
 *
 * classes=N, then classK=ID KIND USAGE_WEIGHT NAME for K = 1..N (the
 * catalogue's order; the name is the rest of the line), lines=0|1,
 * colours=M and colourK=VALUE R G B, and the fill's keys. */

static int class_set(aerial_job *p, int k, const char *v) {
  if (k < 1 || k > AERIAL_MAX_CLASSES) return TS_EINVAL;
  aerial_class *c = &p->cls[k - 1];
  char kind[16];
  int used = 0;
  if (sscanf(v, "%d %15s %lf %n", &c->id, kind, &c->usage_weight, &used) != 3 || used == 0) return TS_EINVAL;
  if (strcmp(kind, "stochastic") == 0) c->kind = KIND_STOCHASTIC;
  else if (strcmp(kind, "structured") == 0) c->kind = KIND_STRUCTURED;
  else return TS_EINVAL;
  if (c->id < 0 || c->id > AERIAL_MAX_ID || strlen(v + used) == 0 || strlen(v + used) >= AERIAL_NAME_LEN)
    return TS_EINVAL;
  snprintf(c->name, sizeof(c->name), "%s", v + used);
  return 0;
}

static int colour_set(aerial_job *p, int k, const char *v) {
  if (k < 1 || k > AERIAL_MAX_COLOURS) return TS_EINVAL;
  aerial_colour *c = &p->colour[k - 1];
  int rgb[3], used = 0;
  if (sscanf(v, "%d %d %d %d%n", &c->value, &rgb[0], &rgb[1], &rgb[2], &used) != 4 || v[used] != '\0') return TS_EINVAL;
  if (c->value < 0 || c->value > AERIAL_MAX_ID) return TS_EINVAL;
  for (int i = 0; i < 3; i++) {
    if (rgb[i] < 0 || rgb[i] > 255) return TS_EINVAL;
    c->rgb[i] = (uint8_t)rgb[i];
  }
  return 0;
}

/* The number after a key's stem ("class12" -> 12), or -1. */
static int numbered(const char *k, const char *stem) {
  size_t n = strlen(stem);
  int v;
  if (strncmp(k, stem, n) != 0 || k[n] < '1' || k[n] > '9' || ts_parse_int(k + n, 1, 100000, &v) != 0) return -1;
  return v;
}

static int aerial_spec_set(void *params, const char *k, const char *v) {
  aerial_job *p = params;
  int n, rc = ts_params_set(aerial_param_table, params, k, v);
  if (rc != TS_ENOENT) return rc;
  if ((n = numbered(k, "class")) > 0) return class_set(p, n, v);
  if ((n = numbered(k, "colour")) > 0) return colour_set(p, n, v);
  return TS_ENOENT;
}

static int aerial_spec_complete(const void *params, char *err) {
  const aerial_job *p = params;
  if (p->nclass < 1) return ts_error(err, TS_EINVAL, "job spec: classes=N (1..%d) is required", AERIAL_MAX_CLASSES);
  for (int k = 0; k < p->nclass; k++)
    if (p->cls[k].name[0] == '\0') return ts_error(err, TS_EINVAL, "job spec: class%d is missing", k + 1);
  if (p->lines && p->ncolours < 1) return ts_error(err, TS_EINVAL, "job spec: lines=1 needs colours=M and colour1..M");
  return 0;
}

static int aerial_spec_format(const void *params, char *buf, size_t cap) {
  const aerial_job *p = params;
  int n = ts_params_format(aerial_param_table, params, buf, cap);
  for (int k = 0; n >= 0 && (size_t)n < cap && k < p->nclass; k++) {
    const aerial_class *c = &p->cls[k];
    n += snprintf(buf + n, cap - (size_t)n, "class%d=%d %s %.17g %s\n", k + 1, c->id,
                  c->kind == KIND_STRUCTURED ? "structured" : "stochastic", c->usage_weight, c->name);
  }
  for (int k = 0; n >= 0 && (size_t)n < cap && k < p->ncolours; k++) {
    const aerial_colour *c = &p->colour[k];
    n += snprintf(buf + n, cap - (size_t)n, "colour%d=%d %d %d %d\n", k + 1, c->value, c->rgb[0], c->rgb[1], c->rgb[2]);
  }
  return n < 0 || (size_t)n >= cap ? TS_ETOOBIG : n;
}

/* The class map, the references in the catalogue's order, the lines. */
static void aerial_inputs(const void *params, ts_engine_inputs *out) {
  const aerial_job *p = params;
  out->n = 0;
  snprintf(out->name[out->n++], TS_ENGINE_KEY_LEN, "classes");
  for (int k = 0; k < p->nclass && k < AERIAL_MAX_CLASSES; k++)
    snprintf(out->name[out->n++], TS_ENGINE_KEY_LEN, "ref%d", k + 1);
  if (p->lines) snprintf(out->name[out->n++], TS_ENGINE_KEY_LEN, "lines");
}

/* ---- from the images ------------------------------------------------------ */

/* The integer value of an image's first channel at pixel i (a class id or
 * a line value). */
static int value_at(const ts_image *img, size_t i) {
  size_t o = i * (size_t)img->channels;
  switch (img->type) {
  case TS_PIX_U8: return ((const uint8_t *)img->pixels)[o];
  case TS_PIX_U16: return ((const uint16_t *)img->pixels)[o];
  default: {
    float v = ts_image_sample(img, (int)(i % (size_t)img->width), (int)(i / (size_t)img->width), 0);
    return v >= 0 && v <= AERIAL_MAX_ID ? (int)lrintf(v) : -1;
  }
  }
}

/* The colour index of a line value, or -1. */
static int colour_of(const aerial_job *p, int v) {
  for (int k = 0; k < p->ncolours; k++)
    if (p->colour[k].value == v) return k;
  return -1;
}

/* The catalogue index of a class id, or -1. */
static int class_of(const aerial_job *p, int id) {
  for (int k = 0; k < p->nclass; k++)
    if (p->cls[k].id == id) return k;
  return -1;
}

/* Classes in the order they are filled: stochastic first, then structured,
 * each in the catalogue's order. order[c - 1] is the catalogue index of
 * fill class c. */
static void fill_order(const aerial_job *p, int *order) {
  int n = 0;
  for (int kind = KIND_STOCHASTIC; kind <= KIND_STRUCTURED; kind++)
    for (int k = 0; k < p->nclass; k++)
      if (p->cls[k].kind == kind) order[n++] = k;
}

static const ts_image *lines_of(const aerial_job *p, const ts_image *const *in) {
  return p->lines ? in[1 + p->nclass] : NULL;
}

/* 8-bit luminance (BT.601) of an 8-bit RGB pixel. */
static uint8_t luma_of(const uint8_t *rgb) { return (uint8_t)((299 * rgb[0] + 587 * rgb[1] + 114 * rgb[2] + 500) / 1000); }

typedef struct {
  ts_fill_input in;
  ts_fill_class cls[TS_FILL_MAX_CLASSES];
  const char *names[TS_FILL_MAX_CLASSES];
  int order[TS_FILL_MAX_CLASSES];
  uint8_t *canvas, *state;
  uint8_t *ref_luma[TS_FILL_MAX_CLASSES];
} aerial_fill;

static void aerial_fill_free(aerial_fill *a) {
  free(a->canvas);
  free(a->state);
  for (int k = 0; k < TS_FILL_MAX_CLASSES; k++) free(a->ref_luma[k]);
  memset(a, 0, sizeof(*a));
}

/* The fill's input: lines given in their colours' luminance, every other
 * pixel the work area of its class (in fill order). */
static int aerial_fill_build(const aerial_job *p, const ts_image *const *in, aerial_fill *a) {
  memset(a, 0, sizeof(*a));
  const ts_image *map = in[0], *lines = lines_of(p, in);
  size_t npx = (size_t)map->width * (size_t)map->height;
  int rank[TS_FILL_MAX_CLASSES];
  fill_order(p, a->order);
  for (int c = 0; c < p->nclass; c++) rank[a->order[c]] = c;
  a->canvas = calloc(npx, 1);
  a->state = malloc(npx);
  if (a->canvas == NULL || a->state == NULL) return TS_ENOMEM;
  for (size_t i = 0; i < npx; i++) {
    int line = lines != NULL ? colour_of(p, value_at(lines, i)) : -1;
    if (line >= 0) {
      a->state[i] = 0;
      a->canvas[i] = luma_of(p->colour[line].rgb);
    } else {
      a->state[i] = (uint8_t)(rank[class_of(p, value_at(map, i))] + 1);
    }
  }
  for (int c = 0; c < p->nclass; c++) {
    int k = a->order[c];
    const ts_image *ref = in[1 + k];
    if ((a->ref_luma[c] = malloc((size_t)ref->width * (size_t)ref->height)) == NULL) return TS_ENOMEM;
    ts_image_luma8(ref, a->ref_luma[c]);
    a->cls[c].nsources = 1;
    a->cls[c].src[0] = (ts_fill_source){.w = ref->width, .h = ref->height, .planes = {a->ref_luma[c]}};
    a->cls[c].usage_weight = p->cls[k].usage_weight;
    a->names[c] = p->cls[k].name;
  }
  a->in = (ts_fill_input){.w = map->width, .h = map->height, .nplanes = 1, .planes = {a->canvas}, .state = a->state,
                          .nclass = p->nclass, .cls = a->cls, .names = a->names};
  return 0;
}

/* ---- checks ---------------------------------------------------------------- */

/* Class ids in the map without a catalogue entry, named with their pixel
 * counts (lines cover pixels of any class). */
static void check_ids(const aerial_job *p, const ts_image *const *in, char *msg, size_t len, int *n) {
  const ts_image *map = in[0], *lines = lines_of(p, in);
  size_t npx = (size_t)map->width * (size_t)map->height;
  uint64_t *count = calloc(AERIAL_MAX_ID + 2, sizeof(uint64_t));
  if (count == NULL) {
    ts_problem(msg, len, n, "out of memory");
    return;
  }
  for (size_t i = 0; i < npx; i++) {
    if (lines != NULL && colour_of(p, value_at(lines, i)) >= 0) continue;
    int v = value_at(map, i);
    if (v < 0 || class_of(p, v) < 0) count[v < 0 ? AERIAL_MAX_ID + 1 : v]++;
  }
  char list[512] = "";
  size_t used = 0;
  int missing = 0;
  for (int v = 0; v <= AERIAL_MAX_ID + 1; v++) {
    if (count[v] == 0) continue;
    if (missing++ < 12 && used < sizeof(list))
      used += (size_t)snprintf(list + used, sizeof(list) - used, "%s%s%d (%llu pixels)", missing > 1 ? ", " : "",
                               v > AERIAL_MAX_ID ? "not a whole number " : "", v > AERIAL_MAX_ID ? -1 : v,
                               (unsigned long long)count[v]);
  }
  if (missing > 0)
    ts_problem(msg, len, n, "--classes holds class ids the catalogue has no entry for: %s%s; add them to the "
               "catalogue's \"classes\"", list, missing > 12 ? ", ..." : "");
  free(count);
}

static int aerial_check(const void *params, const ts_image *const *in, char *msg, size_t len) {
  const aerial_job *p = params;
  const ts_image *map = in[0], *lines = lines_of(p, in);
  int n = 0;
  msg[0] = '\0';
  ts_fill_check_params(&p->fill, msg, len, &n);
  if ((uint64_t)map->width * (uint64_t)map->height > p->max_pixels)
    ts_problem(msg, len, &n, "--classes: %dx%d pixels exceed the limit of %llu (raise --max-pixels)", map->width,
               map->height, (unsigned long long)p->max_pixels);
  if (lines != NULL && (lines->width != map->width || lines->height != map->height))
    ts_problem(msg, len, &n, "the line raster is %dx%d, the class map %dx%d: they must be the same size", lines->width,
               lines->height, map->width, map->height);
  for (int k = 0; k < p->nclass; k++)
    for (int j = 0; j < k; j++)
      if (p->cls[j].id == p->cls[k].id) ts_problem(msg, len, &n, "class id %d is given twice", p->cls[k].id);
  if (n == 0) check_ids(p, in, msg, len, &n);
  if (n > 0) return TS_EINVAL;
  aerial_fill a;
  int rc = aerial_fill_build(p, in, &a);
  if (rc != 0) ts_problem(msg, len, &n, "out of memory");
  else rc = ts_fill_check(&p->fill, &a.in, a.names, msg, len);
  aerial_fill_free(&a);
  return rc;
}

static void aerial_set_max_pixels(void *params, uint64_t max_pixels) { ((aerial_job *)params)->max_pixels = max_pixels; }

/* 8-bit RGB. */
static uint64_t aerial_result_bytes(const void *params, const ts_engine_wants *w, const ts_image_info *in) {
  (void)params, (void)w;
  return (uint64_t)in[0].width * (uint64_t)in[0].height * 3 + 4096;
}

static int aerial_levels(const void *params) { return ((const aerial_job *)params)->fill.levels; }

/* ---- running ----------------------------------------------------------------- */

struct ts_engine_run {
  const aerial_job *p;
  const ts_image *const *in;
  const ts_search *search;
  int order[TS_FILL_MAX_CLASSES];
  ts_fill_result res;
};

static int aerial_run(const void *params, const ts_image *const *in, ts_search *search, const ts_engine_hooks *h,
                      ts_engine_run **out, char *err) {
  ts_engine_run *r = calloc(1, sizeof(*r));
  *out = r;
  if (r == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  r->p = params;
  r->in = in;
  r->search = search;
  aerial_fill a;
  if (aerial_fill_build(r->p, in, &a) != 0) {
    aerial_fill_free(&a);
    return ts_error(err, TS_ENOMEM, "out of memory");
  }
  memcpy(r->order, a.order, sizeof(r->order));
  ts_fill_hooks fh = {.progress = h->progress, .progress_ctx = h->progress_ctx};
  int rc = ts_fill_synthesize(&r->p->fill, &a.in, search, &fh, &r->res, err);
  aerial_fill_free(&a);
  return rc;
}

/* Channel c (0..2) of pixel (x, y) as 8 bits: grey images give it to all
 * three. */
static uint8_t rgb8(const ts_image *img, int x, int y, int c) {
  float v = ts_image_sample(img, x, y, img->channels >= 3 ? c : 0);
  return (uint8_t)lrintf((v < 0 ? 0 : v > 1 ? 1 : v) * 255.0f);
}

static int write_image(const ts_engine_run *r, const char *path, char *err) {
  const aerial_job *p = r->p;
  const ts_image *map = r->in[0], *lines = lines_of(p, r->in);
  ts_image img;
  int rc = ts_image_alloc(&img, map->width, map->height, 3, TS_PIX_U8, err);
  if (rc != 0) return rc;
  uint8_t *px = img.pixels;
  const ts_fill_result *res = &r->res;
  for (size_t i = 0; i < (size_t)map->width * (size_t)map->height; i++) {
    uint8_t *o = px + 3 * i;
    if (res->source[i] == TS_FILL_NO_SOURCE) {
      memcpy(o, p->colour[colour_of(p, value_at(lines, i))].rgb, 3);
      continue;
    }
    int k = class_of(p, value_at(map, i));
    const ts_image *ref = r->in[1 + k];
    for (int c = 0; c < 3; c++) o[c] = rgb8(ref, (int)res->copy[2 * i], (int)res->copy[2 * i + 1], c);
  }
  rc = ts_image_write(path, &img, map->meta, err);
  ts_image_free(&img);
  return rc;
}

static int write_report(const ts_engine_run *r, const char *path, int threads, char *err) {
  char tmp[TS_FILE_TMP_LEN];
  FILE *f = ts_file_create(path, tmp, err);
  if (f == NULL) return TS_EIO;
  const aerial_job *p = r->p;
  fprintf(f, "{\n  \"engine\": \"aerial\",\n  \"search\": {\"mode\": \"exact\", \"lossy\": [], \"backend\": \"%s\", "
             "\"simd\": \"%s\", \"threads\": %d},\n  \"params\": {",
          r->search->ops->name, r->search->simd->name, threads);
  ts_fill_report_params(f, &p->fill);
  fprintf(f, "},\n  \"seconds\": %.4f,\n  \"classes\": [\n", r->res.seconds);
  for (int c = 0; c < p->nclass; c++) {
    const aerial_class *k = &p->cls[r->order[c]];
    const ts_fill_class_stats *s = &r->res.cls[c];
    fprintf(f, "    {\"order\": %d, \"id\": %d, \"name\": \"", c + 1, k->id);
    for (const char *q = k->name; *q; q++) fprintf(f, *q == '"' || *q == '\\' ? "\\%c" : "%c", *q);
    fprintf(f, "\", \"kind\": \"%s\", \"usage_weight\": %g, \"blocks\": %llu, \"usage_mean\": %.6f, "
               "\"usage_variance\": %.6f}%s\n",
            k->kind == KIND_STRUCTURED ? "structured" : "stochastic", k->usage_weight, (unsigned long long)s->blocks,
            s->usage_mean, s->usage_variance, c + 1 < p->nclass ? "," : "");
  }
  fprintf(f, "  ],\n");
  ts_fill_report_levels(f, &p->fill, &r->res);
  fprintf(f, "}\n");
  return ts_file_commit(f, tmp, path, 1, err);
}

static int aerial_write_output(const ts_engine_run *r, int k, const char *path, int threads, char *err) {
  switch (k) {
  case OUT_IMAGE: return write_image(r, path, err);
  case OUT_REPORT: return write_report(r, path, threads, err);
  default: return ts_error(err, TS_EINVAL, "the aerial engine has no output %d", k);
  }
}

static void aerial_run_free(ts_engine_run *r) {
  if (r == NULL) return;
  ts_fill_result_free(&r->res);
  free(r);
}

const ts_engine ts_engine_aerial = {
    .name = "aerial",
    .outputs = aerial_outputs,
    .noutputs = OUT_COUNT,
    .params = aerial_param_table,
    .params_default = aerial_params_default,
    .spec_set = aerial_spec_set,
    .spec_complete = aerial_spec_complete,
    .spec_format = aerial_spec_format,
    .inputs = aerial_inputs,
    .check = aerial_check,
    .set_max_pixels = aerial_set_max_pixels,
    .result_bytes = aerial_result_bytes,
    .levels = aerial_levels,
    .run = aerial_run,
    .write_output = aerial_write_output,
    .run_free = aerial_run_free,
};
