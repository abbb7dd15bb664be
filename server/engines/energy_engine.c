/* energy_engine.c - the energy of a stylized image (stylit.h's quality
 * tools) as an engine (engine.h), so that `texsyn energy` runs on a
 * cluster as every job does, through the coordinator's search. Its inputs
 * are the stylize scene's (stylit_engine.h: the same names, the same spec
 * keys) and then the image to score; its result is no image but one JSON
 * line, energy.json, which the CLI prints from whichever process measured.
 * The measure is one exact search step: no checkpoints, a job a restart
 * interrupts measures again, with the same numbers. */
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "engine.h"
#include "error.h"
#include "stylit.h"
#include "stylit_engine.h"
#include "util.h"

_Static_assert(sizeof(ts_stylit_energy_params) <= TS_ENGINE_PARAMS_MAX, "energy parameters outgrew ts_engine_params");
_Static_assert(2 + 2 * TS_STYLIT_MAX_GUIDES <= TS_ENGINE_MAX_INPUTS, "energy inputs outgrew ts_engine_inputs");

enum { OUT_RESULT, OUT_COUNT };

/* The key of output 0 is every engine's "output": `texsyn fetch ID -o F`
 * writes an energy job's JSON to F as it writes another job's image. */
static const ts_engine_output energy_outputs[OUT_COUNT] = {
    [OUT_RESULT] = {"output", "energy.json", TS_OUTPUT_FLAG},
};

#define F(field) offsetof(ts_stylit_energy_params, field)

/* The scene's parameters, then the step; the weights follow in the spec. */
static const ts_param energy_param_table[] = {
    TS_STYLIT_SCENE_PARAMS(F(scene)),
    {"sample", "sample", "STEP", TS_PARAM_INT, F(step), 1, TS_STYLIT_MAX_STEP, "1",
     "score the patches at every STEP-th pixel"},
    {NULL}};

/* The scene's stylize parameters keep their defaults (unused). */
static void energy_params_default(void *params) {
  ts_stylit_energy_params *p = params;
  ts_stylit_params_default(&p->scene);
  ts_params_default(energy_param_table, params);
}

/* The scene's inputs, then the image. */
static void energy_inputs(const void *params, ts_engine_inputs *out) {
  ts_stylit_scene_inputs(&((const ts_stylit_energy_params *)params)->scene, out);
  snprintf(out->name[out->n++], TS_ENGINE_KEY_LEN, "image");
}

/* The image is the last input (the guides bounded as the inputs are). */
static const ts_image *image_of(const ts_stylit_energy_params *p, const ts_image *const *in) {
  return in[1 + 2 * (p->scene.guides < TS_STYLIT_MAX_GUIDES ? p->scene.guides : TS_STYLIT_MAX_GUIDES)];
}

/* ---- spec keys ---------------------------------------------------------- */

static int energy_spec_set(void *params, const char *k, const char *v) {
  ts_stylit_energy_params *p = params;
  int rc = ts_params_set(energy_param_table, params, k, v);
  return rc != TS_ENOENT ? rc : ts_stylit_weight_set(&p->scene, k, v);
}

static int energy_spec_complete(const void *params, char *err) {
  return ts_stylit_scene_complete(&((const ts_stylit_energy_params *)params)->scene, err);
}

static int energy_spec_format(const void *params, char *buf, size_t cap) {
  const ts_stylit_energy_params *p = params;
  int n = ts_params_format(energy_param_table, params, buf, cap);
  if (n < 0) return n;
  int k = ts_stylit_weights_format(&p->scene, buf + n, cap - (size_t)n);
  return k < 0 ? k : n + k;
}

static int energy_check(const void *params, const ts_image *const *in, char *msg, size_t len) {
  const ts_stylit_energy_params *p = params;
  return ts_stylit_energy_check(&p->scene, in, image_of(p, in), p->step, msg, len);
}

static void energy_set_max_pixels(void *params, uint64_t max_pixels) {
  ((ts_stylit_energy_params *)params)->scene.max_pixels = max_pixels;
}

/* One line of JSON. */
static uint64_t energy_result_bytes(const void *params, const ts_engine_wants *w, const ts_image_info *in) {
  (void)params, (void)w, (void)in;
  return 256;
}

static int energy_levels(const void *params) {
  (void)params;
  return 1;
}

/* ---- running ------------------------------------------------------------ */

struct ts_engine_run {
  ts_stylit_energy en;
};

static int energy_run(const void *params, const ts_image *const *in, ts_search *search, const ts_engine_hooks *h,
                      ts_engine_run **out, char *err) {
  const ts_stylit_energy_params *p = params;
  (void)h;
  ts_engine_run *r = calloc(1, sizeof(*r));
  *out = r;
  if (r == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  return ts_stylit_energy_measure(&p->scene, in, image_of(p, in), p->step, search, &r->en, err);
}

static int write_json(const ts_stylit_energy *en, const char *path, char *err) {
  char line[256];
  int n = ts_stylit_energy_json(en, line, sizeof(line));
  if (n < 0) return ts_error(err, n, "the energy's JSON line outgrew %zu bytes", sizeof(line));
  return ts_file_write(path, line, (size_t)n, err);
}

static int energy_write_output(const ts_engine_run *r, int k, const char *path, int threads, char *err) {
  (void)threads;
  if (k != OUT_RESULT) return ts_error(err, TS_EINVAL, "the energy engine has no output %d", k);
  return write_json(&r->en, path, err);
}

static void energy_run_free(ts_engine_run *r) { free(r); }

const ts_engine ts_engine_energy = {
    .name = "energy",
    .outputs = energy_outputs,
    .noutputs = OUT_COUNT,
    .params = energy_param_table,
    .params_default = energy_params_default,
    .spec_set = energy_spec_set,
    .spec_complete = energy_spec_complete,
    .spec_format = energy_spec_format,
    .inputs = energy_inputs,
    .check = energy_check,
    .set_max_pixels = energy_set_max_pixels,
    .result_bytes = energy_result_bytes,
    .levels = energy_levels,
    .run = energy_run,
    .write_output = energy_write_output,
    .run_free = energy_run_free,
};
