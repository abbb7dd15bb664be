/* search_replica.c - see search_replica.h. */
#include "search_replica.h"

#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "replica.h"
#include "usage.h"

int cl_image_ack(const ts_frame *f, const cl_request *rq, char *err) {
  uint32_t image;
  if (ts_msg_image_ack_read(f, &image, err) != 0) return TS_EPROTO;
  if (image != rq->tag)
    return ts_error(err, TS_EPROTO, "protocol: 'R' frame id %u acknowledges query image %u; it was sent image %u",
                    f->id, image, rq->tag);
  return 0;
}

int cl_image_open(ts_search *s, const ts_replica_desc *d, int *id, char *err) {
  cluster_search *cs = (cluster_search *)s;
  int slot = 0;
  while (slot < CL_MAX_IMAGES && cs->images[slot].used) slot++;
  if (slot == CL_MAX_IMAGES) return ts_error(err, TS_ENOMEM, "too many query images open at once");
  cl_image *im = &cs->images[slot];
  memset(im, 0, sizeof(*im));
  im->synced = calloc((size_t)cs->c->o.max_workers, sizeof(cl_synced));
  if (im->synced == NULL) return ts_error(err, TS_ENOMEM, "out of memory for a query image");
  int rc = ts_replica_init(&im->rep, d, err);
  if (rc != 0) {
    free(im->synced);
    return rc;
  }
  pthread_mutex_lock(&cs->c->lock);
  im->gid = ++cs->c->next_set;
  pthread_mutex_unlock(&cs->c->lock);
  im->used = 1;
  *id = slot;
  return 0;
}

int cl_image_place(ts_search *s, int id, const ts_place *p, uint32_t n, char *err) {
  cl_image *im = cl_image_get((cluster_search *)s, id);
  if (im == NULL) return ts_error(err, TS_EINVAL, "unknown query image %d", id);
  if (im->npending + n > im->cap_pending) {
    uint32_t cap = im->cap_pending ? im->cap_pending : 1024;
    while (cap < im->npending + n) cap *= 2;
    ts_place *q = realloc(im->pending, sizeof(ts_place) * cap);
    ts_commit *k = realloc(im->commits, sizeof(ts_commit) * 2 * cap);
    if (q != NULL) im->pending = q;
    if (k != NULL) im->commits = k;
    if (q == NULL || k == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
    im->cap_pending = cap;
  }
  memcpy(im->pending + im->npending, p, sizeof(ts_place) * n);
  im->npending += n;
  return 0;
}

/* The pending placements reach the coordinator's replica, and their
 * commits the usage replicas of the image's sets, once they are on their
 * way to the workers: what is loaded later starts from them. */
int cl_flush_image(cluster_search *cs, int id, char *err) {
  cl_image *im = &cs->images[id];
  if (im->npending == 0) return 0;
  uint32_t nc;
  int rc = ts_replica_place(&im->rep, im->pending, im->npending, im->commits, &nc, err);
  im->npending = 0;
  im->rep.seq++;
  for (int k = 0; rc == 0 && k < CL_MAX_SETS; k++) {
    cl_set *st = &cs->sets[k];
    if (!st->used || st->rs.image != id || !st->with_usage) continue;
    for (uint32_t i = 0; i < nc; i++)
      ts_usage_commit(&st->usage, im->commits[i].x, im->commits[i].y, im->commits[i].w, im->commits[i].h,
                      im->commits[i].delta);
    if (st->local != NULL) rc = ts_slice_commit(st->local, im->commits, nc, err);
  }
  return rc;
}

/* What worker w holds of the image: its record, or NULL (lock held). */
cl_synced *cl_synced_of(cl_image *im, const cl_worker *w) {
  for (int i = 0; i < im->nsynced; i++)
    if (im->synced[i].worker == w->id) return &im->synced[i];
  return NULL;
}

void cl_mark_synced(ts_cluster *c, cl_image *im, const cl_worker *w, uint64_t seq) {
  cl_synced *y = cl_synced_of(im, w);
  if (y == NULL && im->nsynced < (int)c->o.max_workers) y = &im->synced[im->nsynced++];
  if (y != NULL) *y = (cl_synced){w->id, seq};
}

/* The replica as a LOAD message (its pointers stay valid until the
 * replica changes, after the exchange). */
void cl_load_message(const cl_image *im, ts_msg_image *m) {
  const ts_replica *r = &im->rep;
  memset(m, 0, sizeof(*m));
  m->image = im->gid;
  m->op = TS_IMAGE_LOAD;
  m->seq = r->seq;
  ts_replica_desc *d = &m->d;
  d->w = r->w;
  d->h = r->h;
  d->nplanes = r->nplanes;
  d->bounded = r->bounded;
  d->done = r->done;
  d->block = r->block;
  d->copy = r->copy;
  for (int k = 0; k < r->nplanes; k++) {
    d->fine[k] = r->fine[k].px;
    d->coarse[k] = r->coarse[k].px;
    d->ref[k] = r->ref[k].px;
  }
  if (r->coarse[0].px != NULL) {
    d->cw = r->coarse[0].w;
    d->ch = r->coarse[0].h;
  }
  if (r->block != 0) {
    d->rw = r->ref[0].w;
    d->rh = r->ref[0].h;
  }
}

int cl_queue_image_load(cl_worker *w, const cl_image *im, char *err) {
  ts_msg_image m;
  cl_load_message(im, &m);
  return cl_queue_image(w, im->gid, &m, err);
}

typedef struct {
  cl_image *im;
  int *acked; /* ids of the workers that answered */
  int nacked;
} image_ctx;

static int image_reply(void *ctx, cl_worker *w, const ts_frame *f, const cl_request *rq, char *err) {
  image_ctx *x = ctx;
  if (f->type == TS_MSG_ERROR) return cl_reply_error(f, err);
  int rc = cl_image_ack(f, rq, err);
  if (rc == 0 && x->acked != NULL) x->acked[x->nacked++] = w->id;
  return rc;
}

/* The next level: the workers holding the replica get the last step's
 * placements and the new reference level, and predict the level
 * themselves; the others are loaded when they are next asked. */
int cl_image_next(ts_search *s, int id, int w, int h, int rw, int rh, const uint8_t *const *ref,
                              char *err) {
  cluster_search *cs = (cluster_search *)s;
  ts_cluster *c = cs->c;
  cl_image *im = cl_image_get(cs, id);
  if (im == NULL) return ts_error(err, TS_EINVAL, "unknown query image %d", id);
  ts_msg_image m = {.image = im->gid, .op = TS_IMAGE_NEXT, .seq = im->rep.seq, .place = im->pending,
                    .nplace = im->npending, .w = w, .h = h, .rw = rw, .rh = rh, .nplanes = im->rep.nplanes};
  memcpy(m.d.ref, ref, sizeof(const uint8_t *) * (size_t)im->rep.nplanes);
  int *acked = calloc((size_t)c->o.max_workers, sizeof(int));
  if (acked == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  image_ctx x = {im, acked, 0};
  pthread_mutex_lock(&c->lock);
  cl_worker **ws = cs->ws;
  int n = 0, all = cl_ready_workers(c, ws);
  for (int i = 0; i < all; i++) {
    cl_synced *y = cl_synced_of(im, ws[i]);
    if (y != NULL && y->seq == im->rep.seq) ws[n++] = ws[i];
  }
  cl_lease(c, ws, n);
  for (int i = 0; i < n; i++) {
    char why[TS_ERR_LEN];
    if (cl_queue_image(ws[i], im->gid, &m, why) != 0) cl_worker_fail(c, ws[i], why);
  }
  cl_traffic tr = {0, 0};
  if (n > 0) cl_exchange(c, ws, n, c->o.batch_timeout + 30.0, cs->cancel, 0, image_reply, &x, &tr);
  cl_release(c, ws, n);
  cs->base.stats.bytes_out += tr.bytes_out;
  cs->base.stats.bytes_in += tr.bytes_in;
  int rc = cl_flush_image(cs, id, err);
  if (rc == 0) rc = ts_replica_next_level(&im->rep, w, h, rw, rh, ref, err);
  im->level++;
  im->nsynced = 0; /* the others hold the level above, or nothing */
  for (int i = 0; rc == 0 && i < x.nacked; i++) im->synced[im->nsynced++] = (cl_synced){x.acked[i], 0};
  pthread_mutex_unlock(&c->lock);
  free(acked);
  return rc;
}

/* Tells every ready worker to free the image (lock taken). */
void cl_image_close(ts_search *s, int id) {
  cluster_search *cs = (cluster_search *)s;
  ts_cluster *c = cs->c;
  cl_image *im = cl_image_get(cs, id);
  if (im == NULL) return;
  ts_msg_image m = {.image = im->gid, .op = TS_IMAGE_CLOSE};
  image_ctx x = {im, NULL, 0};
  pthread_mutex_lock(&c->lock);
  cl_worker **ws = cs->ws;
  int n = cl_ready_workers(c, ws);
  cl_lease(c, ws, n);
  for (int i = 0; i < n; i++) {
    char why[TS_ERR_LEN];
    if (cl_queue_image(ws[i], im->gid, &m, why) != 0) cl_worker_fail(c, ws[i], why);
  }
  cl_traffic tr = {0, 0};
  if (n > 0) cl_exchange(c, ws, n, c->o.batch_timeout, cs->cancel, CL_X_SEND_ALL, image_reply, &x, &tr);
  cl_release(c, ws, n);
  pthread_mutex_unlock(&c->lock);
  ts_replica_free(&im->rep);
  free(im->pending);
  free(im->commits);
  free(im->synced);
  memset(im, 0, sizeof(*im));
}
