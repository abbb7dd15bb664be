/* outputs.c - see outputs.h. */
#include "outputs.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "error.h"
#include "image.h"
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

int ts_write_report(const char *path, const ts_mrf_params *p, int threads, const ts_search *search,
                    const ts_mrf_result *res, char *err) {
  char tmp[TS_FILE_TMP_LEN];
  FILE *f = ts_file_create(path, tmp, err);
  if (f == NULL) return TS_EIO;
  fprintf(f, "{\n  \"engine\": \"mrf\",\n  \"search\": {\"mode\": \"exact\", \"lossy\": [], "
             "\"backend\": \"%s\", \"simd\": \"%s\", \"threads\": %d},\n",
          search->ops->name, search->simd->name, threads);
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
               "\"round_trips\": %llu, \"seconds\": %.4f}%s\n",
            l, s->ref_w, s->ref_h, s->out_w, s->out_h, s->vectors, (unsigned long long)s->blocks,
            (unsigned long long)s->steps, (unsigned long long)s->pairs, (unsigned long long)s->wire_bytes,
            (unsigned long long)s->round_trips, s->seconds,
            l > p->stop_level ? "," : "");
  }
  fprintf(f, "  ]\n}\n");
  return ts_file_commit(f, tmp, path, 1, err);
}
