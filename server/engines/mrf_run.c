/* mrf_run.c - ts_mrf_synthesize (mrf.h): the reference's pyramids, then
 * a resume or the best-of candidates, then the levels, then the output. */
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "mrf_bestof.h"
#include "mrf_levels.h"
#include "mrf_plan.h"
#include "mrf_resume.h"
#include "util.h"

/* The inputs' checks, every problem listed. */
static int check_inputs(const ts_mrf_params *p, const ts_image *ref, const ts_image *fine, char *err) {
  char msg[2048];
  if (p->mix_level > 0 && fine == NULL) return ts_error(err, TS_EINVAL, "--mix-level needs a --ref-fine image");
  if (p->mix_level == 0 && fine != NULL) return ts_error(err, TS_EINVAL, "--ref-fine needs --mix-level");
  int rc = ts_mrf_check(p, ref->width, ref->height, ref->channels, msg, sizeof(msg));
  if (fine != NULL && ts_mrf_check_fine(p, fine->width, fine->height, fine->channels, ref->channels, msg,
                                        sizeof(msg)) != 0)
    rc = TS_EINVAL;
  return rc != 0 ? ts_error(err, TS_EINVAL, "%s", msg) : 0;
}

int ts_mrf_synthesize(const ts_mrf_params *p, const ts_image *ref, ts_search *search,
                      const ts_mrf_hooks *hooks, ts_mrf_result *res, char *err) {
  return ts_mrf_synthesize_mixed(p, ref, NULL, search, hooks, res, err);
}

int ts_mrf_synthesize_mixed(const ts_mrf_params *p, const ts_image *ref, const ts_image *ref_fine,
                            ts_search *search, const ts_mrf_hooks *hooks, ts_mrf_result *res, char *err) {
  memset(res, 0, sizeof(*res));
  if (check_inputs(p, ref, ref_fine, err) != 0) return TS_EINVAL;
  static const ts_mrf_hooks none = {0};
  double t_start = ts_now();
  engine e;
  memset(&e, 0, sizeof(e));
  e.p = p;
  e.search = search;
  e.hooks = hooks ? hooks : &none;
  e.res = res;
  e.last_checkpoint = t_start;
  e.image = -1;
  e.levels = p->levels;
  e.mix = p->mix_level;
  e.seed = p->seed;
  e.nplanes = mrf_nplanes_for(p, ref->channels);
  e.prog.levels = p->levels;
  mrf_level_sizes(p->width, p->height, p->levels, e.cw, e.ch, 1);
  for (int l = 0; l < p->levels; l++)
    e.prog.work_total += (double)mrf_level_blocks(p, l, e.cw[l], e.ch[l]) * mrf_level_cost(l);
  if (p->best_of > 1) e.prog.work_total += (p->best_of - 1) * mrf_candidate_work(&e, mrf_candidate_last_level(p));
  int rc = mrf_build_reference(&e, ref, p->levels, e.ref);
  if (rc == 0 && e.mix > 0) rc = mrf_build_reference(&e, ref_fine, e.mix + 1, e.fine_ref);
  if (rc != 0) rc = ts_error(err, rc, "cannot build the reference pyramids: %s", ts_strerror(rc));
  if (rc == 0 && (rc = mrf_lbg_decide(&e)) != 0) ts_error(err, rc, "out of memory");
  int first = p->levels - 1;
  const ts_mrf_checkpoint *inside = NULL;
  if (rc == 0 && e.hooks->resume) rc = mrf_take_resume(&e, &first, &inside, err);
  if (rc == 0 && p->best_of > 1 && !res->resumed) rc = mrf_choose_candidate(&e, &first, err);
  if (rc == 0) rc = mrf_run_levels(&e, first, p->stop_level, inside, err);
  if (rc == 0) {
    ts_usage_stats(&e.usage, &res->usage_mean, &res->usage_variance);
    /* Colour from the reference the finest level was made from. */
    rc = mrf_gather_output(&e, e.mix > p->stop_level ? ref_fine : ref, res, err);
  }
  mrf_engine_free(&e);
  res->seconds = ts_now() - t_start;
  if (rc != 0) ts_mrf_result_free(res);
  return rc;
}

void ts_mrf_result_free(ts_mrf_result *res) {
  ts_image_free(&res->image);
  free(res->copy_map);
  free(res->usage);
  res->copy_map = NULL;
  res->usage = NULL;
}
