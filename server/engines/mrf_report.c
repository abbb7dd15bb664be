/* mrf_report.c - see mrf_report.h. */
#include "mrf_report.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "repetition.h"
#include "util.h"

/* The copy-map shortcut (§3.6.6), per level from the coarsest: what it
 * did, and the constancy that decided the levels below. */
static void report_copy_map(FILE *f, const ts_mrf_params *p, const ts_mrf_result *res) {
  static const char *const role[] = {"none", "measure", "copy"};
  fprintf(f, "  \"shortcuts\": {\"copy_map\": {\"used\": %s, \"lossy\": true, \"note\": \"model-specific "
             "(seed 002 section 3.6.6): blocks inside coherent regions of the level above's copy map are copied "
             "from their predicted source without a search, which can change the result\", \"kernel\": %d, "
             "\"min_constancy\": %g, \"levels\": [\n",
          res->lossy ? "true" : "false", p->accel_kernel ? p->accel_kernel : ts_coarse_width(p->wn), p->accel_min);
  for (int l = p->levels - 1; l >= p->stop_level; l--) {
    const ts_mrf_accel_stats *a = &res->accel[l];
    fprintf(f, "    {\"level\": %d, \"role\": \"%s\", \"blocks\": %llu, \"candidates\": %llu, "
               "\"measured\": %llu, \"kept\": %llu, ",
            l, role[a->role], (unsigned long long)a->blocks, (unsigned long long)a->candidates,
            (unsigned long long)a->measured, (unsigned long long)a->kept);
    if (a->measured > 0) fprintf(f, "\"constancy\": %.4f, ", (double)a->kept / (double)a->measured);
    else fprintf(f, "\"constancy\": null, ");
    if (a->pool_measured > 0)
      fprintf(f, "\"constancy_above\": %.4f, ", (double)a->pool_kept / (double)a->pool_measured);
    else fprintf(f, "\"constancy_above\": null, ");
    fprintf(f, "\"measured_above\": %llu, ", (unsigned long long)a->pool_measured);
    fprintf(f, "\"copied\": %llu, \"skipped_share\": %.4f, \"searches_saved\": %llu}%s\n",
            (unsigned long long)a->copied, a->blocks ? (double)a->copied / (double)a->blocks : 0.0,
            (unsigned long long)a->searches_saved, l > p->stop_level ? "," : "");
  }
  fprintf(f, "  ]}},\n");
}

/* Passive variance optimisation (§3.7.1): every candidate and the choice. */
static void report_best_of(FILE *f, const ts_mrf_params *p, const ts_mrf_result *res) {
  fprintf(f, "  \"best_of\": {\"candidates\": %d, \"measured_at_level\": %d, \"runs\": [", p->best_of,
          res->best_of_level);
  for (int k = 0; k < res->ncandidates; k++)
    fprintf(f, "%s\n    {\"candidate\": %d, \"seed\": %llu, \"usage_variance\": %.6f, \"seconds\": %.4f}",
            k ? "," : "", k, (unsigned long long)res->candidate[k].seed, res->candidate[k].variance,
            res->candidate[k].seconds);
  if (res->ncandidates == 0)
    fprintf(f, "], \"chosen\": null, \"note\": \"chosen before a coordinator restart; the resumed run went on "
               "from a checkpoint after the choice\"},\n");
  else
    fprintf(f, "\n  ], \"chosen\": %d, \"chosen_seed\": %llu},\n", res->chosen,
            (unsigned long long)res->candidate[res->chosen].seed);
}

/* The levels some of whose queries were searched in partitions (bit l). */
static uint32_t lbg_levels_ran(const ts_mrf_params *p, const ts_mrf_result *res) {
  uint32_t ran = 0;
  for (int l = 0; l < p->levels; l++) ran |= (uint32_t)(res->lbg[l].on != 0) << l;
  return ran;
}

const char *ts_mrf_search_mode(const ts_mrf_params *p, const ts_mrf_result *res) {
  if (lbg_levels_ran(p, res) != 0) return p->lbg_exact ? "lbg-exact" : "lbg";
  return res->lossy ? "copy-map" : "exact";
}

/* The search: its mode, "lbg" among the lossy shortcuts when some of it
 * was partitioned and not exact, and the partitioning's parameters. */
static void report_search(FILE *f, const ts_mrf_params *p, const ts_mrf_result *res, int threads,
                          const ts_search *search) {
  uint32_t ran = lbg_levels_ran(p, res);
  int lossy = ran != 0 && !p->lbg_exact;
  fprintf(f, "  \"search\": {\"mode\": \"%s\", \"lossy\": [%s%s%s], ", ts_mrf_search_mode(p, res),
          res->lossy ? "\"copy-map\"" : "", res->lossy && lossy ? ", " : "", lossy ? "\"lbg\"" : "");
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

/* The repetition score of the result's copy map (repetition.h), when the
 * run reached the finest level (the copy map is the output's then). */
static void report_repetition(FILE *f, const ts_mrf_params *p, const ts_mrf_result *res) {
  ts_repetition r;
  char err[TS_ERR_LEN];
  if (p->stop_level != 0 || res->copy_map == NULL ||
      ts_repetition_score(res->copy_map, NULL, 1, res->image.width, res->image.height, res->ref_w, res->ref_h,
                          TS_REPETITION_SIDE, &r, err) != 0)
    return;
  fprintf(f,
          "  \"repetition\": {\"side\": %d, \"share\": %.6f, \"repeated\": %llu, \"in_large\": %llu, "
          "\"patches\": %llu, \"large_patches\": %llu},\n",
          r.side, r.share, (unsigned long long)r.repeated, (unsigned long long)r.large, (unsigned long long)r.patches,
          (unsigned long long)r.large_patches);
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
             "\"rgb_search\": %s, \"stop_level\": %d, \"refine\": %d, \"best_of\": %d, "
             "\"best_of_levels\": %d, \"mix_level\": %d, \"copy_accel\": %s},\n",
          p->width, p->height, p->levels, p->wn, p->wb, p->parity ? "true" : "false", p->usage_weight,
          p->coarse_weight, (unsigned long long)p->seed, p->rgb_search ? "true" : "false",
          p->stop_level, p->refine, p->best_of, p->best_of_levels, p->mix_level, p->copy_accel ? "true" : "false");
  if (p->best_of > 1) report_best_of(f, p, res);
  if (p->copy_accel) report_copy_map(f, p, res);
  fprintf(f, "  \"seconds\": %.4f,\n  \"usage\": {\"mean\": %.6f, \"variance\": %.6f},\n",
          res->seconds, res->usage_mean, res->usage_variance);
  report_repetition(f, p, res);
  const ts_mrf_resume *rs = &res->resume;
  if (res->resumed)
    fprintf(f, "  \"resumed\": {\"level\": %d, \"step\": %llu, \"steps\": %llu, \"level_done\": %.4f, "
               "\"checkpoint_time\": %.3f, \"checkpoint_age\": %.3f, \"redone_at_most\": %.3f},\n",
            rs->level, (unsigned long long)rs->step, (unsigned long long)rs->steps, rs->level_done, rs->saved_at,
            rs->age, rs->redone);
  fprintf(f, "  \"levels\": [\n");
  for (int l = p->levels - 1; l >= p->stop_level; l--) {
    const ts_mrf_level_stats *s = &res->level[l];
    fprintf(f, "    {\"level\": %d, \"from\": \"%s\", \"ref\": [%d, %d], \"out\": [%d, %d], \"vectors\": %u, "
               "\"blocks\": %llu, \"steps\": %llu, \"comparisons\": %llu, \"wire_bytes\": %llu, "
               "\"round_trips\": %llu, \"seconds\": %.4f",
            l, l < p->mix_level ? "ref_fine" : "ref", s->ref_w, s->ref_h, s->out_w, s->out_h, s->vectors,
            (unsigned long long)s->blocks,
            (unsigned long long)s->steps, (unsigned long long)s->pairs, (unsigned long long)s->wire_bytes,
            (unsigned long long)s->round_trips, s->seconds);
    if (res->lbg[l].on) report_lbg_level(f, &res->lbg[l]);
    fprintf(f, "}%s\n", l > p->stop_level ? "," : "");
  }
  fprintf(f, "  ]\n}\n");
  return ts_file_commit(f, tmp, path, 1, err);
}

/* The lossy search in words, or "" for an exact one. */
void ts_mrf_lbg_note(const ts_mrf_params *p, const ts_mrf_result *res, char *buf, size_t cap) {
  buf[0] = '\0';
  uint32_t ran = lbg_levels_ran(p, res);
  if (ran == 0 || p->lbg_exact) return;
  char levels[64];
  ts_mrf_lbg_levels_format(ran, levels, sizeof(levels));
  snprintf(buf, cap, "lossy LBG search (seed 002 3.6.5): partitions=%d probe=%d levels=%s", p->lbg, p->lbg_probe,
           levels);
}

