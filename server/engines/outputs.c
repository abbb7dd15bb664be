/* outputs.c - see outputs.h. */
#include "outputs.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "error.h"
#include "image.h"
#include "image_meta.h"
#include "util.h"

int ts_write_copy_map_image(const char *path, const uint32_t *map, int w, int h, int ref_w,
                            int ref_h, char *err) {
  ts_image img;
  int rc = ts_image_alloc(&img, w, h, 3, TS_PIX_U16, err);
  if (rc != 0) return rc;
  uint16_t *px = img.pixels;
  double sx = ref_w > 1 ? 65535.0 / (ref_w - 1) : 0, sy = ref_h > 1 ? 65535.0 / (ref_h - 1) : 0;
  for (long i = 0; i < (long)w * h; i++) {
    px[3 * i] = (uint16_t)(map[2 * i] * sx + 0.5);
    px[3 * i + 1] = (uint16_t)(map[2 * i + 1] * sy + 0.5);
    px[3 * i + 2] = 0;
  }
  rc = ts_image_write(path, &img, NULL, err);
  ts_image_free(&img);
  return rc;
}

/* Writes to a temporary file and renames, like ts_image_write. */
int ts_write_copy_map_raw(const char *path, const uint32_t *map, int w, int h, char *err) {
  char tmp[TS_FILE_TMP_LEN];
  FILE *f = ts_file_create(path, tmp, err);
  if (f == NULL) return TS_EIO;
  uint8_t buf[8];
  int ok = 1;
  for (long i = 0; ok && i < 2L * w * h; i++) {
    for (int b = 0; b < 4; b++) buf[b] = (uint8_t)(map[i] >> (8 * b));
    ok = fwrite(buf, 4, 1, f) == 1;
  }
  return ts_file_commit(f, tmp, path, ok, err);
}

static int has_ext(const char *path, const char *ext) {
  size_t n = strlen(path), e = strlen(ext);
  return n >= e && strcasecmp(path + n - e, ext) == 0;
}

int ts_write_usage_map(const char *path, const uint32_t *usage, int w, int h, char *err) {
  ts_image img;
  int rc = ts_image_alloc(&img, w, h, 1, TS_PIX_F32, err);
  if (rc != 0) return rc;
  int raw = has_ext(path, ".tif") || has_ext(path, ".tiff") || has_ext(path, ".exr");
  uint32_t max = 1;
  for (long i = 0; i < (long)w * h; i++)
    if (usage[i] > max) max = usage[i];
  float *px = img.pixels;
  for (long i = 0; i < (long)w * h; i++) px[i] = raw ? (float)usage[i] : (float)usage[i] / (float)max;
  rc = ts_image_write(path, &img, NULL, err);
  ts_image_free(&img);
  return rc;
}

/* The levels some of whose queries were searched in partitions (bit l). */
static uint32_t lbg_levels_ran(const ts_mrf_params *p, const ts_mrf_result *res) {
  uint32_t ran = 0;
  for (int l = 0; l < p->levels; l++) ran |= (uint32_t)(res->lbg[l].on != 0) << l;
  return ran;
}

const char *ts_mrf_search_mode(const ts_mrf_params *p, const ts_mrf_result *res) {
  return lbg_levels_ran(p, res) == 0 ? "exact" : p->lbg_exact ? "lbg-exact" : "lbg";
}

/* The search: its mode, "lbg" among the lossy shortcuts when some of it
 * was partitioned and not exact, and the partitioning's parameters. */
static void report_search(FILE *f, const ts_mrf_params *p, const ts_mrf_result *res, int threads,
                          const ts_search *search) {
  uint32_t ran = lbg_levels_ran(p, res);
  int lossy = ran != 0 && !p->lbg_exact;
  fprintf(f, "  \"search\": {\"mode\": \"%s\", \"lossy\": [%s], ", ts_mrf_search_mode(p, res),
          lossy ? "\"lbg\"" : "");
  if (ran != 0) {
    fprintf(f, "\"lbg\": {\"partitions\": %d, \"probe\": %d, \"exact\": %s, \"levels\": [", p->lbg, p->lbg_probe,
            p->lbg_exact ? "true" : "false");
    for (int l = 0, n = 0; l < p->levels; l++)
      if (ran >> l & 1) fprintf(f, "%s%d", n++ ? ", " : "", l);
    fprintf(f, "]}, ");
  }
  fprintf(f, "\"backend\": \"%s\", \"simd\": \"%s\", \"threads\": %d},\n", search->ops->name, search->simd->name,
          threads);
}

/* A partitioned level: per set (the causal L's, the full window's) the
 * queries the level makes of it and whether it was partitioned - with,
 * when this run built it, its codebook - and, when this run synthesised
 * the level, the share of the reference vectors its queries compared. */
static void report_lbg_level(FILE *f, const ts_mrf_lbg_stats *s) {
  static const char *const window[2] = {"causal", "full"};
  fprintf(f, ", \"lbg\": {");
  if (s->ran)
    fprintf(f, "\"scanned_fraction\": %.6f, ", s->full_pairs ? (double)s->pairs / (double)s->full_pairs : 0.0);
  fprintf(f, "\"sets\": [");
  for (int k = 0; k < 2; k++) {
    const ts_lbg_report *r = &s->set[k];
    fprintf(f, "%s{\"window\": \"%s\", \"queries\": %llu, \"partitioned\": %s", k ? ", " : "", window[k],
            (unsigned long long)s->queries[k], s->partitioned[k] ? "true" : "false");
    if (s->partitioned[k] && s->ran)
      fprintf(f, ", \"partitions\": %u, \"iterations\": %u, \"converged\": %s, \"seconds\": %.4f, "
                 "\"sizes\": {\"min\": %u, \"median\": %u, \"max\": %u}",
              r->partitions, r->iterations, r->converged ? "true" : "false", r->seconds, r->size_min,
              r->size_median, r->size_max);
    fprintf(f, "}");
  }
  fprintf(f, "]}");
}

int ts_write_report(const char *path, const ts_mrf_params *p, int threads, const ts_search *search,
                    const ts_mrf_result *res, char *err) {
  char tmp[TS_FILE_TMP_LEN];
  FILE *f = ts_file_create(path, tmp, err);
  if (f == NULL) return TS_EIO;
  fprintf(f, "{\n  \"engine\": \"mrf\",\n");
  report_search(f, p, res, threads, search);
  fprintf(f, "  \"params\": {\"width\": %d, \"height\": %d, \"levels\": %d, \"wn\": %d, \"wb\": %d, "
             "\"parity\": %s, \"usage_weight\": %g, \"coarse_weight\": %g, \"seed\": %llu, "
             "\"rgb_search\": %s, \"stop_level\": %d, \"refine\": %d},\n",
          p->width, p->height, p->levels, p->wn, p->wb, p->parity ? "true" : "false", p->usage_weight,
          p->coarse_weight, (unsigned long long)p->seed, p->rgb_search ? "true" : "false",
          p->stop_level, p->refine);
  fprintf(f, "  \"seconds\": %.4f,\n  \"usage\": {\"mean\": %.6f, \"variance\": %.6f},\n",
          res->seconds, res->usage_mean, res->usage_variance);
  const ts_mrf_resume *rs = &res->resume;
  if (res->resumed)
    fprintf(f, "  \"resumed\": {\"level\": %d, \"step\": %llu, \"steps\": %llu, \"level_done\": %.4f, "
               "\"checkpoint_time\": %.3f, \"checkpoint_age\": %.3f, \"redone_at_most\": %.3f},\n",
            rs->level, (unsigned long long)rs->step, (unsigned long long)rs->steps, rs->level_done, rs->saved_at,
            rs->age, rs->redone);
  fprintf(f, "  \"levels\": [\n");
  for (int l = p->levels - 1; l >= p->stop_level; l--) {
    const ts_mrf_level_stats *s = &res->level[l];
    fprintf(f, "    {\"level\": %d, \"ref\": [%d, %d], \"out\": [%d, %d], \"vectors\": %u, "
               "\"blocks\": %llu, \"steps\": %llu, \"comparisons\": %llu, \"wire_bytes\": %llu, "
               "\"round_trips\": %llu, \"seconds\": %.4f",
            l, s->ref_w, s->ref_h, s->out_w, s->out_h, s->vectors, (unsigned long long)s->blocks,
            (unsigned long long)s->steps, (unsigned long long)s->pairs, (unsigned long long)s->wire_bytes,
            (unsigned long long)s->round_trips, s->seconds);
    if (res->lbg[l].on) report_lbg_level(f, &res->lbg[l]);
    fprintf(f, "}%s\n", l > p->stop_level ? "," : "");
  }
  fprintf(f, "  ]\n}\n");
  return ts_file_commit(f, tmp, path, 1, err);
}

/* The lossy search in words, or "" for an exact one. */
static void search_note(const ts_mrf_params *p, const ts_mrf_result *res, char *buf, size_t cap) {
  buf[0] = '\0';
  uint32_t ran = lbg_levels_ran(p, res);
  if (ran == 0 || p->lbg_exact) return;
  char levels[64];
  ts_mrf_lbg_levels_format(ran, levels, sizeof(levels));
  snprintf(buf, cap, "lossy LBG search (seed 002 3.6.5): partitions=%d probe=%d levels=%s", p->lbg, p->lbg_probe,
           levels);
}

int ts_write_synth_image(const char *path, const ts_mrf_result *res, const ts_image *ref, const ts_mrf_params *p,
                         char *err) {
  const ts_image *img = &res->image;
  char note[160];
  search_note(p, res, note, sizeof(note));
  if (note[0] == '\0') return ts_image_write(path, img, ref->meta, err);
  ts_image with = *ref; /* its metadata object is ref's, or a new one */
  char desc[1024] = "";
  int had = ts_meta_get(with.meta, "ImageDescription", desc, sizeof(desc) - sizeof(note) - 8) == 0 && desc[0];
  if (strstr(desc, note) == NULL) /* a second write notes it once */
    snprintf(desc + strlen(desc), sizeof(desc) - strlen(desc), "%s%s", had ? "\n" : "", note);
  int rc = ts_meta_set(&with.meta, TS_META_SEARCH, note);
  if (rc == 0) rc = ts_meta_set(&with.meta, "ImageDescription", desc);
  if (rc != 0) rc = ts_error(err, rc, "%s: cannot note the lossy search in the image's metadata: %s", path,
                             ts_strerror(rc));
  if (rc == 0) rc = ts_image_write(path, img, with.meta, err);
  if (with.meta != ref->meta) ts_meta_free(with.meta);
  return rc;
}
