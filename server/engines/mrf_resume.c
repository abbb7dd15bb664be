/* mrf_resume.c - see mrf_resume.h. */
#include "mrf_resume.h"

#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "mrf_plan.h"

/* What the first steps of a plan leave: the blocks placed, and how many
 * were searched. */
typedef struct {
  int w;
  uint8_t *done;
  uint64_t blocks;
} walk_state;

static void mark_block(void *ctx, const ts_block *b) {
  walk_state *ws = ctx;
  ws->blocks++;
  for (int dy = 0; dy < b->h; dy++) memset(ws->done + (size_t)(b->y + dy) * ws->w + b->x, 1, b->w);
}

/* A checkpoint inside a level must hold what its first `step` steps of the
 * plan leave: exactly those blocks placed, as many blocks searched, and
 * usage counters that count the placed pixels' copies (every copy adds
 * its pixels, every sweep's replacement takes the old ones away). */
static int check_inside(const engine *e, const ts_mrf_checkpoint *ck, const level_plan *pl, char *err) {
  int l = ck->level, top = l + 1 == e->levels;
  int rw = mrf_level_refs(e, 0, l)[l].w, rh = mrf_level_refs(e, 0, l)[l].h;
  if (ck->coarse_width != (top ? 0 : e->cw[l + 1]) || ck->coarse_height != (top ? 0 : e->ch[l + 1]) ||
      ck->ref_width != rw || ck->ref_height != rh)
    return ts_error(err, TS_EINVAL,
                    "the checkpoint inside level %d (coarse canvas %dx%d, reference %dx%d) does not belong to "
                    "this job", l, ck->coarse_width, ck->coarse_height, ck->ref_width, ck->ref_height);
  size_t npx = (size_t)ck->width * ck->height;
  walk_state ws = {ck->width, calloc(npx, 1), 0};
  uint32_t *count = calloc((size_t)rw * rh, sizeof(uint32_t));
  int rc = ws.done && count ? 0 : ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0) mrf_plan_walk(pl, ck->step, mark_block, &ws);
  if (rc == 0 && memcmp(ws.done, ck->done, npx) != 0)
    rc = ts_error(err, TS_EINVAL, "the checkpoint's placed blocks are not those of its %llu steps",
                  (unsigned long long)ck->step);
  if (rc == 0 && ws.blocks != ck->stats[l].blocks)
    rc = ts_error(err, TS_EINVAL, "the checkpoint counts %llu blocks searched, its %llu steps search %llu",
                  (unsigned long long)ck->stats[l].blocks, (unsigned long long)ck->step,
                  (unsigned long long)ws.blocks);
  for (size_t i = 0; rc == 0 && i < npx; i++)
    if (ck->done[i]) count[(size_t)ck->copy[2 * i + 1] * rw + ck->copy[2 * i]]++;
  if (rc == 0 && memcmp(count, ck->usage, (size_t)rw * rh * sizeof(uint32_t)) != 0)
    rc = ts_error(err, TS_EINVAL, "the checkpoint's usage counters do not count its placed copies");
  free(ws.done);
  free(count);
  return rc;
}

/* Checks that a checkpoint is a state this job's synthesis passes through.
 * It came through a checksum, but from a file: one left by another build,
 * or a lie, must be refused rather than trusted. */
static int check_resume(const engine *e, const ts_mrf_checkpoint *ck, char *err) {
  const ts_mrf_params *p = e->p;
  int l = ck->level, inside = ck->step < ck->steps;
  if (l < p->stop_level + !inside || l >= p->levels || ck->nplanes != e->nplanes || ck->width != e->cw[l] ||
      ck->height != e->ch[l])
    return ts_error(err, TS_EINVAL, "the checkpoint (level %d, %dx%d, %d planes) does not belong to this job", l,
                    ck->width, ck->height, ck->nplanes);
  if (p->copy_accel)
    return ts_error(err, TS_EINVAL, "a job with --copy-accel takes no checkpoints: its choices rest on the copy "
                    "maps and constancy of the levels above, which a checkpoint does not hold");
  int last = mrf_candidate_last_level(p);
  if (p->best_of > 1 && (l > last || (l == last && inside)))
    return ts_error(err, TS_EINVAL, "the checkpoint (level %d) lies among the best-of candidates' levels (%d and "
                    "up), which take none", l, last);
  size_t npx = (size_t)ck->width * ck->height;
  const ts_plane *r = &mrf_level_refs(e, 0, l)[l];
  for (size_t i = 0; i < npx; i++)
    if (ck->copy[2 * i] >= (uint32_t)r->w || ck->copy[2 * i + 1] >= (uint32_t)r->h)
      return ts_error(err, TS_EINVAL, "the checkpoint's copy map points outside the level-%d reference", l);
  level_plan pl;
  if (mrf_plan_level(&pl, p, l, ck->width, ck->height) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
  int rc = 0;
  if (ck->steps != pl.steps || ck->stats[l].steps != ck->step || ck->step > ck->steps)
    rc = ts_error(err, TS_EINVAL, "the checkpoint is at step %llu of %llu of level %d, which has %llu steps here",
                  (unsigned long long)ck->step, (unsigned long long)ck->steps, l, (unsigned long long)pl.steps);
  else if (inside)
    rc = check_inside(e, ck, &pl, err);
  mrf_plan_free(&pl);
  return rc;
}

/* Takes over a finished level's state: its canvas becomes the coarse part
 * of the next level and its copy map the prediction. */
static int restore_level_end(engine *e, const ts_mrf_checkpoint *ck, char *err) {
  int l = ck->level;
  size_t npx = (size_t)ck->width * ck->height;
  for (int k = 0; k < e->nplanes; k++) {
    if (ts_plane_alloc(&e->canvas[k][l], ck->width, ck->height) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
    memcpy(e->canvas[k][l].px, ck->planes[k], npx);
  }
  e->copy = malloc(sizeof(uint32_t) * 2 * npx);
  if (e->copy == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  memcpy(e->copy, ck->copy, sizeof(uint32_t) * 2 * npx);
  e->level = l;
  return 0;
}

static void describe_resume(const engine *e, const ts_mrf_checkpoint *ck, ts_mrf_resume *r) {
  int l = ck->level;
  r->level = l;
  r->step = ck->step;
  r->steps = ck->steps;
  r->level_done = (double)ck->stats[l].blocks / (double)mrf_level_blocks(e->p, l, e->cw[l], e->ch[l]);
  r->saved_at = ck->saved_at;
  r->age = mrf_wall_now() - ck->saved_at;
  if (!(r->age > 0)) r->age = 0; /* a clock set back */
  r->redone = ck->interval > 0 && ck->interval < r->age ? ck->interval : r->age;
}

/* Goes on from hooks->resume when it fits the job: *first is the level to
 * run first, and *inside the checkpoint to start it from when it was taken
 * inside that level. One that does not fit fails the synthesis, or, with a
 * `refused` hook, is reported and synthesis starts from noise. */
int mrf_take_resume(engine *e, int *first, const ts_mrf_checkpoint **inside, char *err) {
  const ts_mrf_hooks *h = e->hooks;
  const ts_mrf_checkpoint *ck = h->resume;
  char why[TS_ERR_LEN];
  int rc = check_resume(e, ck, why);
  if (rc == TS_EINVAL && h->refused != NULL) {
    h->refused(h->resume_ctx, why);
    return 0;
  }
  if (rc != 0) return ts_error(err, rc, "%s", why);
  int l = ck->level, finished = ck->step == ck->steps;
  if (finished) rc = restore_level_end(e, ck, err);
  *first = finished ? l - 1 : l;
  *inside = finished ? NULL : ck;
  for (int k = finished ? l : l + 1; k < e->levels; k++) { /* the levels done */
    e->res->level[k] = ck->stats[k];
    e->prog.work_done += (double)mrf_level_blocks(e->p, k, e->cw[k], e->ch[k]) * mrf_level_cost(k);
  }
  e->res->resumed = 1;
  describe_resume(e, ck, &e->res->resume);
  if (h->resumed) h->resumed(h->resume_ctx, &e->res->resume);
  return rc;
}
