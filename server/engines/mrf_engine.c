/* mrf_engine.c - MRF block synthesis (mrf.h) as an engine (engine.h): its
 * spec keys, its checkpoints as bytes (checkpoint.h) and its result files
 * (outputs.h). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "checkpoint.h"
#include "engine.h"
#include "error.h"
#include "image_meta.h"
#include "mrf.h"
#include "mrf_report.h"
#include "outputs.h"
#include "util.h"

_Static_assert(sizeof(ts_mrf_params) <= TS_ENGINE_PARAMS_MAX, "MRF parameters outgrew ts_engine_params");

enum { OUT_IMAGE, OUT_COPY_MAP, OUT_COPY_MAP_RAW, OUT_USAGE_MAP, OUT_REPORT, OUT_COUNT };

static const ts_engine_output mrf_outputs[OUT_COUNT] = {
    [OUT_IMAGE] = {"output", "out", TS_OUTPUT_IMAGE},
    [OUT_COPY_MAP] = {"copy_map", "copymap", TS_OUTPUT_IMAGE,
                      "copy-map", "copy map as an image (red = source x, green = source y)"},
    [OUT_COPY_MAP_RAW] = {"copy_map_raw", "copymap.raw", TS_OUTPUT_FLAG,
                      "copy-map-raw", "copy map as raw little-endian uint32 (x, y) per pixel"},
    [OUT_USAGE_MAP] = {"usage_map", "usage", TS_OUTPUT_IMAGE,
                      "usage-map", "usage map: counts per reference pixel (.tif/.exr as float counts; other formats normalised to the maximum)"},
    [OUT_REPORT] = {"report", "report.json", TS_OUTPUT_FLAG},
};

/* ---- spec keys (mrf_params.c declares them) ------------------------------ */

static int mrf_spec_set(void *params, const char *k, const char *v) {
  return ts_params_set(ts_mrf_param_table, params, k, v);
}

/* Without it the spec would format as size=0x0, which no parse takes
 * back: a spooled job would be lost on a restart. */
static int mrf_spec_complete(const void *params, char *err) {
  const ts_mrf_params *p = params;
  return p->width == 0 ? ts_error(err, TS_EINVAL, "job spec: size=WxH is required") : 0;
}

static int mrf_spec_format(const void *params, char *buf, size_t cap) {
  return ts_params_format(ts_mrf_param_table, params, buf, cap);
}

static void mrf_params_default(void *params) { ts_mrf_params_default(params); }

/* The reference texture, and with mixing the fine reference. */
static void mrf_inputs(const void *params, ts_engine_inputs *out) {
  const ts_mrf_params *p = params;
  out->n = p->mix_level > 0 ? 2 : 1;
  snprintf(out->name[0], sizeof(out->name[0]), "ref");
  snprintf(out->name[1], sizeof(out->name[1]), "ref_fine");
}

static int mrf_check(const void *params, const ts_image *const *in, char *msg, size_t len) {
  const ts_mrf_params *p = params;
  int rc = ts_mrf_check(p, in[0]->width, in[0]->height, in[0]->channels, msg, len);
  if (p->mix_level > 0 &&
      ts_mrf_check_fine(p, in[1]->width, in[1]->height, in[1]->channels, in[0]->channels, msg, len) != 0)
    rc = TS_EINVAL;
  return rc;
}

static void mrf_set_max_pixels(void *params, uint64_t max_pixels) {
  ((ts_mrf_params *)params)->max_pixels = max_pixels;
}

/* Per pixel: the image (up to 8 bytes), the usage map's share, the copy
 * maps (8 bytes each), and a checkpoint inside the finest level (its copy
 * map, placed blocks, canvas planes and a quarter of them for the level
 * above: 10.25 or 12.75 bytes) twice, while the next one replaces it. */
static uint64_t mrf_result_bytes(const void *params, const ts_engine_wants *w, const ts_image_info *in) {
  const ts_mrf_params *p = params;
  (void)in; /* the output's size is a parameter */
  uint64_t checkpoint = p->rgb_search ? 13 : 11;
  uint64_t per_px = 8 + 3 + (w->want[OUT_COPY_MAP][0] ? 8 : 0) + (w->want[OUT_COPY_MAP_RAW][0] ? 8 : 0) +
                    2 * checkpoint;
  return (uint64_t)p->width * (uint64_t)p->height * per_px;
}

static int mrf_levels(const void *params) { return ((const ts_mrf_params *)params)->levels; }

/* ---- running, with checkpoints as bytes ---------------------------------- */

struct ts_engine_run {
  const ts_mrf_params *p;
  const ts_image *ref; /* the caller's, alive until outputs are written */
  const ts_search *search;
  ts_mrf_result res;
  /* The output's metadata: that of the reference its pixels come from,
   * marked when a lossy shortcut made it (NULL: none). */
  ts_meta *meta;
};

/* The engine hooks behind the MRF hooks. */
typedef struct {
  const ts_engine_hooks *h;
  int levels;
} hook_ctx;

/* Where a checkpoint was taken, for the log: "after level 1", or "inside
 * level 0 at step 412 of 1042". Returns the length. */
static int describe_place(char *buf, size_t cap, int level, uint64_t step, uint64_t steps) {
  if (step == steps) return snprintf(buf, cap, "after level %d", level);
  return snprintf(buf, cap, "inside level %d at step %llu of %llu", level, (unsigned long long)step,
                  (unsigned long long)steps);
}

static int save_level(void *arg, const ts_mrf_checkpoint *ck, char *err) {
  const hook_ctx *hc = arg;
  uint8_t *buf;
  size_t len;
  int rc = ts_checkpoint_encode(ck, hc->levels, hc->h->tag, &buf, &len, err);
  if (rc != 0) return rc;
  char what[96];
  describe_place(what, sizeof(what), ck->level, ck->step, ck->steps);
  rc = hc->h->save(hc->h->save_ctx, buf, len, what, err);
  free(buf);
  return rc;
}

static void on_resumed(void *arg, const ts_mrf_resume *r) {
  const hook_ctx *hc = arg;
  if (hc->h->resumed == NULL) return;
  char where[128];
  int n = describe_place(where, sizeof(where), r->level, r->step, r->steps);
  if (r->step < r->steps)
    snprintf(where + n, sizeof(where) - (size_t)n, " (%.1f %% of the level done)", 100.0 * r->level_done);
  hc->h->resumed(hc->h->save_ctx, where, r->redone);
}

static void on_refused(void *arg, const char *why) {
  const hook_ctx *hc = arg;
  if (hc->h->resume_refused) hc->h->resume_refused(hc->h->save_ctx, why);
}

/* The state to resume from, if the hooks hold an intact checkpoint of
 * this job (whether it fits the job's synthesis, the engine checks). */
static int decode_resume(const ts_mrf_params *p, const ts_engine_hooks *h, ts_mrf_checkpoint *ck) {
  if (h->resume == NULL) return 0;
  char err[TS_ERR_LEN];
  if (ts_checkpoint_decode(h->resume, h->resume_len, h->tag, p->max_pixels, ck, err) != 0) {
    if (h->resume_refused) h->resume_refused(h->save_ctx, err);
    return 0;
  }
  return 1;
}

/* The note a lossy result carries in its metadata. */
static void lossy_note(const ts_mrf_result *res, char *buf, size_t cap) {
  int n = snprintf(buf, cap, "texsyn: lossy copy-map shortcut (seed 002 section 3.6.6) at level");
  for (int l = TS_MRF_MAX_LEVELS - 1; l >= 0; l--)
    if (res->accel[l].role == TS_ACCEL_ON && n > 0 && (size_t)n < cap)
      n += snprintf(buf + n, cap - (size_t)n, " %d", l);
  if (n > 0 && (size_t)n < cap)
    snprintf(buf + n, cap - (size_t)n, "; blocks were copied without a search, so the result can differ from "
             "exact synthesis");
}

/* The output image's metadata: the reference's, and on a lossy result the
 * shortcuts named in texsyn:search (PNG and OpenEXR keep it) and in the
 * ImageDescription (which TIFF keeps too), after any the reference had. */
static int output_meta(ts_engine_run *r, char *err) {
  char lbg[160], note[700] = "", search[200] = "", old[512], desc[1300];
  ts_mrf_lbg_note(r->p, &r->res, lbg, sizeof(lbg));
  if (r->res.lossy) {
    lossy_note(&r->res, note, sizeof(note));
    snprintf(search, sizeof(search), "copy-map (lossy)");
  }
  if (lbg[0] != '\0') {
    snprintf(note + strlen(note), sizeof(note) - strlen(note), "%s%s", note[0] ? "; " : "", lbg);
    snprintf(search + strlen(search), sizeof(search) - strlen(search), "%s%s", search[0] ? "; " : "", lbg);
  }
  if (note[0] == '\0') return 0;
  int has_old = ts_meta_get(r->ref->meta, "ImageDescription", old, sizeof(old)) == 0 && old[0] != '\0';
  snprintf(desc, sizeof(desc), "%s%s%s", has_old ? old : "", has_old ? "; " : "", note);
  int rc = ts_meta_copy(r->ref->meta, &r->meta);
  if (rc == 0) rc = ts_meta_set(&r->meta, "texsyn:search", search);
  if (rc == 0) rc = ts_meta_set(&r->meta, "ImageDescription", desc);
  return rc != 0 ? ts_error(err, rc, "cannot note the lossy search in the output's metadata: %s", ts_strerror(rc))
                 : 0;
}

static int mrf_run(const void *params, const ts_image *const *in, ts_search *search, const ts_engine_hooks *h,
                   ts_engine_run **out, char *err) {
  const ts_image *ref = in[0];
  ts_engine_run *r = calloc(1, sizeof(*r));
  *out = r;
  if (r == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  r->p = params;
  r->ref = ref;
  r->search = search;
  hook_ctx hc = {h, r->p->levels};
  ts_mrf_checkpoint resume;
  int resumed = decode_resume(r->p, h, &resume);
  /* The copy-map shortcut decides each level from the copy maps and the
   * constancy of the levels above, which checkpoints do not hold: such a
   * job saves none, and a restarted coordinator runs it again from its
   * start (with the same bytes). */
  int save = h->save != NULL && !r->p->copy_accel;
  /* A checkpoint that does not fit is refused, and the job starts over. */
  ts_mrf_hooks mh = {.progress = h->progress,
                     .progress_ctx = h->progress_ctx,
                     .checkpoint = save ? save_level : NULL,
                     .checkpoint_ctx = &hc,
                     .checkpoint_interval = h->checkpoint_interval,
                     .resume = resumed ? &resume : NULL,
                     .resumed = on_resumed,
                     .refused = on_refused,
                     .resume_ctx = &hc,
                     .stop = save ? h->stop : NULL};
  const ts_image *fine = r->p->mix_level > 0 ? in[1] : NULL;
  int rc = ts_mrf_synthesize_mixed(r->p, ref, fine, search, &mh, &r->res, err);
  if (resumed) ts_checkpoint_free(&resume);
  /* The output's pixels come from the fine reference below the mix level. */
  if (fine != NULL && r->p->stop_level < r->p->mix_level) r->ref = fine;
  if (rc == 0) rc = output_meta(r, err);
  return rc;
}

static int mrf_write_output(const ts_engine_run *r, int k, const char *path, int threads, char *err) {
  const ts_mrf_result *res = &r->res;
  int w = res->image.width, h = res->image.height;
  switch (k) {
  case OUT_IMAGE: return ts_image_write(path, &res->image, r->meta != NULL ? r->meta : r->ref->meta, err);
  case OUT_COPY_MAP: return ts_write_copy_map_image(path, res->copy_map, w, h, res->ref_w, res->ref_h, err);
  case OUT_COPY_MAP_RAW: return ts_write_copy_map_raw(path, res->copy_map, w, h, err);
  case OUT_USAGE_MAP: return ts_write_usage_map(path, res->usage, res->ref_w, res->ref_h, err);
  case OUT_REPORT: return ts_write_report(path, r->p, threads, r->search, res, err);
  default: return ts_error(err, TS_EINVAL, "the mrf engine has no output %d", k);
  }
}

static void mrf_run_free(ts_engine_run *r) {
  if (r == NULL) return;
  ts_mrf_result_free(&r->res);
  ts_meta_free(r->meta);
  free(r);
}

const ts_engine ts_engine_mrf = {
    .name = "mrf",
    .outputs = mrf_outputs,
    .noutputs = OUT_COUNT,
    .params = ts_mrf_param_table,
    .params_default = mrf_params_default,
    .spec_set = mrf_spec_set,
    .spec_complete = mrf_spec_complete,
    .spec_format = mrf_spec_format,
    .inputs = mrf_inputs,
    .check = mrf_check,
    .set_max_pixels = mrf_set_max_pixels,
    .result_bytes = mrf_result_bytes,
    .levels = mrf_levels,
    .run = mrf_run,
    .write_output = mrf_write_output,
    .run_free = mrf_run_free,
};
