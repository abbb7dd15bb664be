/* engine.c - the engine registry: every engine's operations table, found by
 * the name a job spec gives. */
#include "engine.h"

#include <stdio.h>
#include <string.h>

#include "error.h"
#include "region.h"

extern const ts_engine ts_engine_mrf, ts_engine_stylize, ts_engine_energy, ts_engine_fill, ts_engine_aerial,
    ts_engine_segment;

static const ts_engine *const registry[] = {&ts_engine_mrf,  &ts_engine_stylize, &ts_engine_energy,
                                             &ts_engine_fill, &ts_engine_aerial,  &ts_engine_segment};

const ts_engine *ts_engine_find(const char *name) {
  for (size_t i = 0; i < sizeof(registry) / sizeof(registry[0]); i++)
    if (strcmp(registry[i]->name, name) == 0) return registry[i];
  return NULL;
}

const ts_engine *ts_engine_at(int i) {
  return i >= 0 && (size_t)i < sizeof(registry) / sizeof(registry[0]) ? registry[i] : NULL;
}

const ts_engine *ts_engine_default(void) { return &ts_engine_mrf; }

int ts_engine_output_index(const ts_engine *e, const char *key) {
  for (int k = 0; k < e->noutputs; k++)
    if (strcmp(e->outputs[k].key, key) == 0) return k;
  return -1;
}

void ts_engine_output_file(const ts_engine *e, int k, const ts_engine_wants *w, char *out, size_t cap) {
  const ts_engine_output *o = &e->outputs[k];
  if (o->kind == TS_OUTPUT_IMAGE) snprintf(out, cap, "%s.%s", o->file, w->want[k]);
  else snprintf(out, cap, "%s", o->file);
}

/* The output of e a fetched file name belongs to, or -1. */
static int output_of_file(const ts_engine *e, const char *name) {
  /* Exact names first: "copymap.raw" is no copy map image in raw format. */
  for (int k = 0; k < e->noutputs; k++)
    if (e->outputs[k].kind == TS_OUTPUT_FLAG && strcmp(e->outputs[k].file, name) == 0) return k;
  for (int k = 0; k < e->noutputs; k++) {
    size_t n = strlen(e->outputs[k].file);
    if (e->outputs[k].kind == TS_OUTPUT_IMAGE && strncmp(e->outputs[k].file, name, n) == 0 && name[n] == '.')
      return k;
  }
  return -1;
}

const ts_engine_output *ts_engine_output_of_file(const char *name) {
  for (size_t i = 0; i < sizeof(registry) / sizeof(registry[0]); i++) {
    int k = output_of_file(registry[i], name);
    if (k >= 0) return &registry[i]->outputs[k];
  }
  return NULL;
}

int ts_engine_input_by_regions(const ts_engine *e, const void *params, int k) {
  return e->input_by_regions != NULL && e->input_by_regions(params, k);
}

int ts_engine_input_is_file(const ts_engine *e, const void *params, int k) {
  return e->input_is_file != NULL && e->input_is_file(params, k);
}

int ts_engine_input_read(const ts_engine *e, const void *params, int k, const char *path,
                         const ts_image_limits *limits, ts_engine_file *f, char *err) {
  memset(f, 0, sizeof(*f));
  if ((size_t)snprintf(f->path, sizeof(f->path), "%s", path) >= sizeof(f->path))
    return ts_error(err, TS_EINVAL, "%.64s...: the path is too long", path);
  if (ts_engine_input_is_file(e, params, k)) return 0;
  if (!ts_engine_input_by_regions(e, params, k)) return ts_image_read(path, &f->img, limits, err);
  ts_region_source *src;
  int rc = ts_region_source_open(path, NULL, &src, err);
  if (rc != 0) return rc;
  f->img.width = src->width;
  f->img.height = src->height;
  src->close(src);
  return 0;
}
