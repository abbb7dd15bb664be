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
#include "outputs.h"
#include "util.h"

_Static_assert(sizeof(ts_mrf_params) <= TS_ENGINE_PARAMS_MAX, "MRF parameters outgrew ts_engine_params");

enum { OUT_IMAGE, OUT_COPY_MAP, OUT_COPY_MAP_RAW, OUT_USAGE_MAP, OUT_REPORT, OUT_COUNT };

static const ts_engine_output mrf_outputs[OUT_COUNT] = {
    [OUT_IMAGE] = {"output", "out", TS_OUTPUT_IMAGE},
    [OUT_COPY_MAP] = {"copy_map", "copymap", TS_OUTPUT_IMAGE},
    [OUT_COPY_MAP_RAW] = {"copy_map_raw", "copymap.raw", TS_OUTPUT_FLAG},
    [OUT_USAGE_MAP] = {"usage_map", "usage", TS_OUTPUT_IMAGE},
    [OUT_REPORT] = {"report", "report.json", TS_OUTPUT_FLAG},
};

/* ---- spec keys ---------------------------------------------------------- */

/* Ranges here only keep values in their types; ts_mrf_check judges them. */
static int mrf_spec_set(void *params, const char *k, const char *v) {
  ts_mrf_params *p = params;
  if (strcmp(k, "size") == 0) return ts_parse_size(v, TS_OUTPUT_SIDE_MAX, &p->width, &p->height) != 0 ? TS_EINVAL : 0;
  if (strcmp(k, "levels") == 0) return ts_parse_int(v, -1000, 1000, &p->levels);
  if (strcmp(k, "wn") == 0) return ts_parse_int(v, -1000, 1000, &p->wn);
  if (strcmp(k, "wb") == 0) return ts_parse_int(v, -1000, 1000, &p->wb);
  if (strcmp(k, "parity") == 0) return ts_parse_int(v, 0, 1, &p->parity);
  if (strcmp(k, "usage_weight") == 0) return ts_parse_double(v, &p->usage_weight);
  if (strcmp(k, "coarse_weight") == 0) return ts_parse_double(v, &p->coarse_weight);
  if (strcmp(k, "refine") == 0) return ts_parse_int(v, -1000, 1000, &p->refine);
  if (strcmp(k, "seed") == 0) return ts_parse_u64(v, &p->seed);
  if (strcmp(k, "rgb_search") == 0) return ts_parse_int(v, 0, 1, &p->rgb_search);
  if (strcmp(k, "max_pixels") == 0) return ts_parse_u64(v, &p->max_pixels);
  if (strcmp(k, "best_of") == 0) return ts_parse_int(v, -1000, 1000, &p->best_of);
  if (strcmp(k, "best_of_levels") == 0) return ts_parse_int(v, -1000, 1000, &p->best_of_levels);
  if (strcmp(k, "mix_level") == 0) return ts_parse_int(v, -1000, 1000, &p->mix_level);
  if (strcmp(k, "copy_accel") == 0) return ts_parse_int(v, 0, 1, &p->copy_accel);
  if (strcmp(k, "copy_accel_kernel") == 0) return ts_parse_int(v, -1000, 1000, &p->accel_kernel);
  if (strcmp(k, "copy_accel_min") == 0) return ts_parse_double(v, &p->accel_min);
  if (strcmp(k, "lbg") == 0) return ts_parse_int(v, -1, TS_LBG_MAX_PARTITIONS + 1, &p->lbg);
  if (strcmp(k, "lbg_levels") == 0) return ts_mrf_lbg_levels_parse(v, &p->lbg_levels);
  if (strcmp(k, "lbg_probe") == 0) return ts_parse_int(v, -1, TS_LBG_MAX_PARTITIONS + 1, &p->lbg_probe);
  if (strcmp(k, "lbg_exact") == 0) return ts_parse_int(v, 0, 1, &p->lbg_exact);
  return TS_ENOENT;
}

int ts_mrf_lbg_levels_parse(const char *spec, uint32_t *mask) {
  if (strcmp(spec, "all") == 0) {
    *mask = TS_MRF_LBG_ALL;
    return 0;
  }
  uint32_t m = 0;
  for (const char *s = spec;; s++) {
    int level = 0, digits = 0;
    for (; *s >= '0' && *s <= '9' && digits < 3; s++, digits++) level = 10 * level + (*s - '0');
    if (digits == 0 || level >= TS_MRF_MAX_LEVELS) return TS_EINVAL;
    m |= 1u << level;
    if (*s == '\0') break;
    if (*s != ',') return TS_EINVAL;
  }
  *mask = m;
  return 0;
}

void ts_mrf_lbg_levels_format(uint32_t mask, char *buf, size_t cap) {
  size_t at = 0;
  buf[0] = '\0';
  if (mask == TS_MRF_LBG_ALL) {
    snprintf(buf, cap, "all");
    return;
  }
  for (int l = 0; l < 32 && at < cap; l++)
    if (mask >> l & 1) {
      int n = snprintf(buf + at, cap - at, "%s%d", at ? "," : "", l);
      if (n < 0) break;
      at += (size_t)n;
    }
}

/* Without it the spec would format as size=0x0, which no parse takes
 * back: a spooled job would be lost on a restart. */
static int mrf_spec_complete(const void *params, char *err) {
  const ts_mrf_params *p = params;
  return p->width == 0 ? ts_error(err, TS_EINVAL, "job spec: size=WxH is required") : 0;
}

/* The keys of best-of, mixing and the copy-map shortcut, when set: a job
 * without them keeps the spec text (and so the checkpoint tag) it had
 * before they existed. */
static int format_extras(const ts_mrf_params *p, char *buf, size_t cap) {
  int n = 0;
  if (p->best_of != 1 || p->best_of_levels != 0)
    n += snprintf(buf, cap, "best_of=%d\nbest_of_levels=%d\n", p->best_of, p->best_of_levels);
  if (n >= 0 && (size_t)n < cap && p->mix_level != 0) n += snprintf(buf + n, cap - (size_t)n, "mix_level=%d\n", p->mix_level);
  if (n >= 0 && (size_t)n < cap && p->copy_accel)
    n += snprintf(buf + n, cap - (size_t)n, "copy_accel=1\ncopy_accel_kernel=%d\ncopy_accel_min=%.17g\n",
                  p->accel_kernel, p->accel_min);
  return n;
}

/* Doubles with 17 significant digits, so they round-trip. */
static int mrf_spec_format(const void *params, char *buf, size_t cap) {
  const ts_mrf_params *p = params;
  int n = snprintf(buf, cap,
                   "size=%dx%d\nlevels=%d\nwn=%d\nwb=%d\nparity=%d\nusage_weight=%.17g\n"
                   "coarse_weight=%.17g\nrefine=%d\nseed=%llu\nrgb_search=%d\nmax_pixels=%llu\n",
                   p->width, p->height, p->levels, p->wn, p->wb, p->parity, p->usage_weight, p->coarse_weight,
                   p->refine, (unsigned long long)p->seed, p->rgb_search, (unsigned long long)p->max_pixels);
  if (n >= 0 && (size_t)n < cap) n += format_extras(p, buf + n, cap - (size_t)n);
  if (n < 0 || (size_t)n >= cap) return TS_ETOOBIG;
  /* The partitioning keys only when set: a spec without them reads and
   * writes as before (its checkpoints' tag unchanged). */
  if (p->lbg == 0 && p->lbg_probe == 1 && !p->lbg_exact && p->lbg_levels == 1) return n;
  char levels[64];
  ts_mrf_lbg_levels_format(p->lbg_levels, levels, sizeof(levels));
  int more = snprintf(buf + n, cap - (size_t)n, "lbg=%d\nlbg_levels=%s\nlbg_probe=%d\nlbg_exact=%d\n", p->lbg, levels,
                      p->lbg_probe, p->lbg_exact);
  return more < 0 || (size_t)more >= cap - (size_t)n ? TS_ETOOBIG : n + more;
}

void ts_mrf_params_default(ts_mrf_params *p) {
  memset(p, 0, sizeof(*p));
  p->levels = 5;
  p->wn = 7;
  p->wb = 3;
  p->coarse_weight = 1.0;
  p->refine = 2;
  p->seed = 1;
  p->max_pixels = TS_IMAGE_DEFAULT_MAX_PIXELS;
  p->best_of = 1;
  p->accel_min = 0.95;
  p->lbg_levels = 1; /* level 0, as the seed does */
  p->lbg_probe = 1;
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
