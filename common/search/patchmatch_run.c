/* patchmatch_run.c - a PatchMatch pass over many tiles on a thread pool,
 * and the state a holder of the source keeps between passes
 * (patchmatch.h). The local backend and the workers both run passes
 * through here. */
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "patchmatch.h"
#include "pool.h"

int ts_pm_field_init(ts_pm_field *f, const ts_window *win, const ts_plane *const *src, int nthreads, char *err) {
  memset(f, 0, sizeof(*f));
  int rc = ts_pm_window_check(win, &f->patch, err);
  if (rc != 0) return rc;
  f->win = win;
  if (src[0]->w < f->patch || src[0]->h < f->patch)
    return ts_error(err, TS_EINVAL, "a %dx%d source holds no %dx%d patch", src[0]->w, src[0]->h, f->patch, f->patch);
  size_t n = (size_t)src[0]->w * (size_t)src[0]->h;
  f->nscr = nthreads;
  f->scr = calloc((size_t)nthreads, sizeof(*f->scr));
  f->counts = malloc(n * sizeof(*f->counts));
  f->ublock = malloc(n * sizeof(*f->ublock));
  f->col = malloc((size_t)src[0]->w * sizeof(*f->col));
  if (f->scr == NULL || f->counts == NULL || f->ublock == NULL || f->col == NULL || ts_pm_image_pack(&f->src, win, src) != 0) {
    ts_pm_field_free(f);
    return ts_error(err, TS_ENOMEM, "out of memory for a %dx%d patchmatch source", src[0]->w, src[0]->h);
  }
  return 0;
}

void ts_pm_field_free(ts_pm_field *f) {
  ts_pm_image_free(&f->src);
  ts_pm_image_free(&f->tgt);
  for (int i = 0; i < f->nscr && f->scr != NULL; i++) ts_pm_scratch_free(&f->scr[i]);
  free(f->scr);
  free(f->counts);
  free(f->ublock);
  free(f->col);
  memset(f, 0, sizeof(*f));
}

int ts_pm_field_target(ts_pm_field *f, const ts_plane *const *tgt, char *err) {
  ts_pm_image_free(&f->tgt);
  if (ts_pm_image_pack(&f->tgt, f->win, tgt) != 0)
    return ts_error(err, TS_ENOMEM, "out of memory for a %dx%d patchmatch target", tgt[0]->w, tgt[0]->h);
  return 0;
}

typedef struct {
  ts_pm_field *f;
  const ts_pm_pass *ps;
  const uint32_t *tiles;
  int n;
  uint32_t *out;
  atomic_int next;
  atomic_int rc;
} pass_run;

/* Each pool thread takes the next tile until none is left: which thread
 * sweeps a tile changes nothing in its result. */
static void sweep_tiles(void *arg, int worker, int nworkers) {
  (void)nworkers;
  pass_run *pr = arg;
  ts_pm_scratch *scr = &pr->f->scr[worker];
  for (int begun = 0;; begun = 1) {
    int i = atomic_fetch_add(&pr->next, 1);
    if (i >= pr->n || atomic_load(&pr->rc) != 0) return;
    int rc = begun ? 0 : ts_pm_scratch_begin(scr, pr->ps);
    if (rc == 0) ts_pm_sweep_tile(pr->ps, pr->tiles != NULL ? (int)pr->tiles[i] : i, scr, pr->out, &rc);
    if (rc != 0) atomic_store(&pr->rc, rc);
  }
}

static int check_job(const ts_pm_field *f, const ts_pm_job *j, char *err) {
  int p = f->patch;
  if (f->tgt.w != j->tw + p - 1 || f->tgt.h != j->th + p - 1)
    return ts_error(err, TS_EINVAL, "patchmatch target %dx%d does not fit a %dx%d field with %dx%d patches", f->tgt.w,
                    f->tgt.h, j->tw, j->th, p, p);
  int r = p / 2;
  for (size_t i = 0; i < (size_t)j->tw * (size_t)j->th; i++)
    if (j->in[2 * i] < (uint32_t)r || j->in[2 * i] >= (uint32_t)(f->src.w - r) || j->in[2 * i + 1] < (uint32_t)r ||
        j->in[2 * i + 1] >= (uint32_t)(f->src.h - r))
      return ts_error(err, TS_EINVAL, "patchmatch field entry %zu (%u, %u) is no patch centre of the %dx%d source", i,
                      j->in[2 * i], j->in[2 * i + 1], f->src.w, f->src.h);
  return 0;
}

int ts_pm_field_pass(ts_pm_field *f, const ts_pm_job *j, const uint32_t *tiles, int n, ts_pool *pool, uint32_t *out,
                     char *err) {
  int rc = check_job(f, j, err);
  if (rc != 0) return rc;
  int total = ts_pm_tiles(j->tw, j->th);
  for (int i = 0; tiles != NULL && i < n; i++)
    if (tiles[i] >= (uint32_t)total) return ts_error(err, TS_EINVAL, "patchmatch tile %u of %d", tiles[i], total);
  if (j->k != 0) {
    ts_pm_occurrences(j->in, (size_t)j->tw * (size_t)j->th, f->patch, f->src.w, f->src.h, f->counts);
    ts_pm_block_sums(f->counts, f->patch, f->src.w, f->src.h, f->col, f->ublock);
  }
  ts_pm_pass ps = {f->win, f->patch, &f->src, &f->tgt, j->tw, j->th, j->in, j->k ? f->ublock : NULL, j->k,
                   j->seed, j->pass, j->scalar};
  pass_run pr = {f, &ps, tiles, tiles != NULL ? n : total, out, 0, 0};
  if (ts_pool_size(pool) > f->nscr) return ts_error(err, TS_EINVAL, "patchmatch: a pool larger than its scratch");
  ts_pool_run(pool, sweep_tiles, &pr);
  rc = atomic_load(&pr.rc);
  return rc != 0 ? ts_error(err, rc, "out of memory in a patchmatch pass") : 0;
}
