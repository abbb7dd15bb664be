/* wfield.c - see wfield.h. */
#include "wfield.h"

#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "util.h"
#include "wmon.h"

struct ts_wfield {
  uint32_t set;
  ts_window win; /* the field's window points here: a ts_wfield never moves */
  ts_pm_field f;
  /* The image whose target f holds packed. */
  uint32_t image;
  uint64_t seq;
  int packed;
};

static ts_wfield **slot_of(ts_wfields *fs, uint32_t set) {
  for (int i = 0; i < TS_WFIELD_MAX; i++)
    if (fs->slot[i] != NULL && fs->slot[i]->set == set) return &fs->slot[i];
  return NULL;
}

static void field_free(ts_wfield **slot) {
  if (*slot == NULL) return;
  ts_wmon_source(-1);
  ts_pm_field_free(&(*slot)->f);
  ts_window_free(&(*slot)->win);
  free(*slot);
  *slot = NULL;
}

void ts_wfield_drop(ts_wfields *fs, uint32_t set) {
  for (int i = 0; i < TS_WFIELD_MAX; i++)
    if (fs->slot[i] != NULL && (set == TS_UNLOAD_ALL || fs->slot[i]->set == set)) field_free(&fs->slot[i]);
  if (set != TS_UNLOAD_ALL) return;
  free(fs->in);
  free(fs->out);
  fs->in = fs->out = NULL;
  fs->cap = 0;
}

int ts_wfield_load(ts_wfields *fs, const ts_msg_field *m, int threads, char *err) {
  ts_wfield **slot = slot_of(fs, m->set);
  for (int i = 0; slot == NULL && i < TS_WFIELD_MAX; i++)
    if (fs->slot[i] == NULL) slot = &fs->slot[i];
  if (slot == NULL) return ts_error(err, TS_ETOOBIG, "too many patchmatch sources on one connection");
  field_free(slot);
  ts_wfield *wf = calloc(1, sizeof(*wf));
  if (wf == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  int rc = ts_window_init(&wf->win, &m->win, err);
  if (rc != 0) {
    free(wf);
    return rc;
  }
  ts_plane planes[TS_WIN_MAX_PLANES];
  const ts_plane *pp[TS_WIN_MAX_PLANES];
  for (int k = 0; k < m->nplanes; k++) {
    planes[k] = (ts_plane){m->w, m->h, (uint8_t *)m->plane[k]}; /* read only: packing copies */
    pp[k] = &planes[k];
  }
  rc = ts_pm_field_init(&wf->f, &wf->win, pp, threads, err);
  if (rc != 0) {
    ts_window_free(&wf->win);
    free(wf);
    return rc;
  }
  wf->set = m->set;
  *slot = wf;
  ts_wmon_source(1);
  return 0;
}

static int ensure_buffers(ts_wfields *fs, size_t entries) {
  if (entries <= fs->cap) return 0;
  uint32_t *in = realloc(fs->in, 2 * entries * sizeof(uint32_t));
  if (in != NULL) fs->in = in;
  uint32_t *out = realloc(fs->out, 2 * entries * sizeof(uint32_t));
  if (out != NULL) fs->out = out;
  if (in == NULL || out == NULL) return TS_ENOMEM;
  fs->cap = entries;
  return 0;
}

/* The target of image r, packed unless it already is. */
static int ensure_target(ts_wfield *wf, const ts_msg_pass *m, const ts_replica *r, char *err) {
  if (wf->packed && wf->image == m->image && wf->seq == m->seq) return 0;
  const ts_plane *t[TS_WIN_MAX_PLANES];
  for (int k = 0; k < r->nplanes; k++) t[k] = &r->fine[k];
  wf->packed = 0;
  int rc = ts_pm_field_target(&wf->f, t, err);
  if (rc != 0) return rc;
  wf->packed = 1;
  wf->image = m->image;
  wf->seq = m->seq;
  return 0;
}

int ts_wfield_pass(ts_wfields *fs, const ts_msg_pass *m, const ts_replica *r, ts_pool *pool, int scalar,
                   ts_wr *reply, char *err) {
  ts_wfield **slot = slot_of(fs, m->set);
  if (slot == NULL) return ts_error(err, TS_EINVAL, "patchmatch source %u is not loaded", m->set);
  if (r == NULL || r->seq != m->seq)
    return ts_error(err, TS_EINVAL, "query image %u is not at state %llu", m->image, (unsigned long long)m->seq);
  if (r->nplanes != (*slot)->win.spec.nplanes[TS_SRC_FINE])
    return ts_error(err, TS_EINVAL, "query image %u has %d planes, patchmatch source %u %d", m->image, r->nplanes,
                    m->set, (*slot)->win.spec.nplanes[TS_SRC_FINE]);
  size_t n = (size_t)m->tw * m->th;
  uint32_t *tiles = malloc(sizeof(uint32_t) * (m->ntiles ? m->ntiles : 1));
  int rc = tiles != NULL && ensure_buffers(fs, n) == 0 ? 0 : ts_error(err, TS_ENOMEM, "out of memory for a pass");
  if (rc == 0) rc = ensure_target(*slot, m, r, err);
  if (rc == 0) {
    for (uint32_t i = 0; i < m->ntiles; i++) tiles[i] = ts_msg_pass_tile(m, i);
    /* In increasing order, so no tile is swept twice at once. */
    for (uint32_t i = 1; rc == 0 && i < m->ntiles; i++)
      if (tiles[i] <= tiles[i - 1]) rc = ts_error(err, TS_EINVAL, "patchmatch tiles not in increasing order");
  }
  if (rc == 0) {
    ts_msg_pass_field(m, fs->in);
    ts_pm_job j = {(int)m->tw, (int)m->th, fs->in, m->usage_k, m->seed, m->pass, scalar};
    double t0 = ts_now();
    rc = ts_pm_field_pass(&(*slot)->f, &j, tiles, (int)m->ntiles, pool, fs->out, err);
    uint64_t nanos = (uint64_t)((ts_now() - t0) * 1e9);
    if (rc == 0) ts_msg_pass_answer_write(reply, m->set, m->pass, nanos, tiles, m->ntiles, m->tw, m->th, fs->out);
  }
  free(tiles);
  return rc;
}
