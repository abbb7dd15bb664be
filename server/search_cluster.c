/* search_cluster.c - the search backend over the coordinator's pool (see
 * cluster.h): every reference set cut into one slice per worker in
 * proportion to its rate, batches sent to every worker holding a slice,
 * answers merged into the exact global best. */
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "search_cluster_impl.h"
#include "calib.h"
#include "error.h"
#include "replica.h"
#include "slice.h"
#include "usage.h"

#if __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "usage counters are shipped as in memory: little-endian hosts only"
#endif


static cl_image *image_get(cluster_search *cs, int id) {
  if (id < 0 || id >= CL_MAX_IMAGES || !cs->images[id].used) return NULL;
  return &cs->images[id];
}

static cl_set *set_get(cluster_search *cs, int id) {
  if (id < 0 || id >= CL_MAX_SETS || !cs->sets[id].used) return NULL;
  return &cs->sets[id];
}

/* Cuts every class into contiguous ranges in proportion to the workers'
 * rates, on group (8-vector) boundaries so every slice scans whole groups. */
static void cut_ranges(const ts_anchors *g, cl_worker **ws, int n, cl_slice *out) {
  double total = 0;
  for (int i = 0; i < n; i++) total += ws[i]->slice_rate;
  for (int c = 0; c < g->nclass; c++) {
    uint64_t groups = (g->count[c] + TS_L1_GROUP - 1) / TS_L1_GROUP;
    double cum = 0;
    uint32_t start = 0;
    for (int i = 0; i < n; i++) {
      cum += ws[i]->slice_rate;
      uint64_t gend = i == n - 1 ? groups : (uint64_t)llround((double)groups * cum / total);
      uint64_t end = gend * TS_L1_GROUP;
      if (end > g->count[c]) end = g->count[c];
      if (end < start) end = start;
      out[i].w = ws[i];
      out[i].i0[c] = start;
      out[i].i1[c] = (uint32_t)end;
      start = (uint32_t)end;
    }
  }
}

int cl_image_ack(const ts_frame *f, const cl_request *rq, char *err) {
  uint32_t image;
  if (ts_msg_image_ack_read(f, &image, err) != 0) return TS_EPROTO;
  if (image != rq->tag)
    return ts_error(err, TS_EPROTO, "protocol: 'R' frame id %u acknowledges query image %u; it was sent image %u",
                    f->id, image, rq->tag);
  return 0;
}

/* Answers to a slicing (ctx: the set): the 'N' of every worker, and the
 * 'R' of those loaded with the set's image first. */
static int loaded_reply(void *ctx, cl_worker *w, const ts_frame *f, const cl_request *rq, char *err) {
  const cl_set *st = ctx;
  ts_msg_loaded m;
  (void)w;
  if (f->type == TS_MSG_ERROR) return cl_reply_error(f, err);
  if (f->type == TS_MSG_IMAGE) return cl_image_ack(f, rq, err);
  if (ts_msg_loaded_read(f, &m, err) != 0) return TS_EPROTO;
  if (m.set != st->gid || m.gen != st->gen)
    return ts_error(err, TS_EPROTO, "protocol: 'N' frame id %u loaded set %u generation %u; it was sent set %u "
                    "generation %u", f->id, m.set, m.gen, st->gid, st->gen);
  return 0;
}


/* The rows w holds of st that its next slice may keep, or NULL. Its
 * usage counters are those of the coordinator's replica only if it holds
 * the image's current state: it has counted the same placements. */
static const ts_slice_held *held_rows(cluster_search *cs, const cl_set *st, const cl_worker *w) {
  cl_image *im = &cs->images[st->rs.image];
  const cl_synced *y = cl_synced_of(im, w);
  if (y == NULL || y->seq != im->rep.seq) return NULL;
  for (int i = 0; i < st->nheld; i++)
    if (st->held[i].worker == w->id && st->held[i].unloads == w->unloads) return &st->held[i].rows;
  return NULL;
}

/* Worker i's slice of st as an 'N' message: what changed since the slice
 * it holds; `loading`: the worker is sent st's image before it. */
static void describe_slice(cluster_search *cs, cl_set *st, int i, int loading, ts_slice_desc *m) {
  cl_slice *sl = &st->slices[i];
  cl_image *im = &cs->images[st->rs.image];
  ts_slice_describe(m, &st->rs, &st->usage, st->gid, st->gen, st->image, sl->i0, sl->i1, held_rows(cs, st, sl->w));
  if (st->lbg.mode != TS_LBG_OFF) ts_slice_describe_lbg(m, &st->lbg);
  sl->rows = ts_slice_held_by(m);
  if (st->tile_w > 0) {
    m->labelled = TS_SLICE_LABELS_TILE;
    m->tile_w = st->tile_w;
    m->tile_h = st->tile_h;
    memcpy(m->tile, st->tile, sizeof(st->tile));
  }
  /* Any state of the image's current level holds its reference planes. */
  if (st->fine_in_image && st->image_level == im->level && (loading || cl_synced_of(im, sl->w) != NULL)) {
    m->fine_sum = ts_slice_fine_sum(m);
    m->fine_from_image = 1;
  }
}

/* Whether st's fine planes are its image's reference planes (the MRF's:
 * the canvas copies from the level the set is made of). */
static int fine_is_image_ref(const cl_set *st, const ts_replica *r) {
  int n = st->rs.window->spec.nplanes[TS_SRC_FINE];
  if (r->block == 0 || n > r->nplanes) return 0;
  for (int p = 0; p < n; p++) {
    const ts_plane *a = st->rs.ref->fine[p], *b = &r->ref[p];
    if (a->w != b->w || a->h != b->h || memcmp(a->px, b->px, (size_t)a->w * (size_t)a->h) != 0) return 0;
  }
  return 1;
}

/* What of st need not travel (see cl_set). */
static void find_shortcuts(cluster_search *cs, cl_set *st) {
  const cl_image *im = &cs->images[st->rs.image];
  st->fine_in_image = fine_is_image_ref(st, &im->rep);
  st->image_level = im->level;
  if (st->rs.labels == NULL || !ts_slice_label_tile(st->rs.labels, &st->tile_w, &st->tile_h, st->tile)) st->tile_w = 0;
}

/* After a slicing's exchange: the workers that loaded their slice. */
static void record_held(cl_set *st, int n) {
  st->nheld = 0;
  for (int i = 0; i < n; i++) {
    const cl_worker *w = st->slices[i].w;
    if (w->state != TS_WORKER_FAILED)
      st->held[st->nheld++] = (cl_held){w->id, w->unloads, st->slices[i].rows};
  }
}

/* Cuts st over ws[0..n) so that every worker can take its slice's 'N'
 * message; one that cannot (its --max-message, or its frame limit if it
 * takes no pieces) gets no slice of this set and the others share it, so
 * the set never goes to a worker that must refuse it (it would be dropped,
 * rejoin and be refused again). Returns how many workers hold slices. */

static int cut_fitting(cluster_search *cs, cl_set *st, cl_worker **ws, int n) {
  ts_cluster *c = cs->c;
  ts_msg_image load; /* a worker holding a slice may need the image whole */
  cl_load_message(&cs->images[st->rs.image], &load);
  uint64_t image_bytes = cl_image_bytes(&load);
  for (;;) {
    cut_ranges(st->grid, ws, n, st->slices);
    int i = 0;
    uint64_t bytes = 0;
    for (; i < n; i++) {
      ts_slice_desc m;
      describe_slice(cs, st, i, 0, &m);
      bytes = cl_slice_bytes(&m);
      if (!cl_worker_takes(ws[i], bytes)) break;
      bytes = image_bytes;
      if (!cl_worker_takes(ws[i], bytes)) break;
    }
    if (i == n) return n;
    cl_log(c, "worker %d (%s) gets no slice of set %u: it would need a message of %llu bytes, over its limit of "
           "%llu (%s)", ws[i]->id, ws[i]->conn.peer, st->gid, (unsigned long long)bytes,
           (unsigned long long)(ws[i]->pieces ? ws[i]->max_message : ws[i]->max_payload),
           ws[i]->pieces ? "texsyn-worker --max-message" : "an older worker: its frame limit, no pieces");
    ws[i]->share = 0;
    memmove(ws + i, ws + i + 1, sizeof(*ws) * (size_t)(n - i - 1));
    n--;
  }
}

/* A worker builds a slice's vectors on one thread after the rows arrive:
 * the square set of a 4096x4096 colour reference, 8.7 GB of vectors, took
 * 49 s (180 MB/s) on one worker of the loaded 2-core VM. A load's deadline
 * allows this rate, 4.5 times slower, on top of its fixed floor; a fixed
 * deadline dropped the worker of a big reference mid-build, and it would
 * rejoin and be given the same slice again. */
#define CL_BUILD_RATE 40e6

static double load_deadline(const ts_cluster *c, const cl_set *st, int n) {
  double most = 0;
  for (int i = 0; i < n; i++) {
    double bytes = 0;
    for (int k = 0; k < st->grid->nclass; k++)
      bytes += (double)(st->slices[i].i1[k] - st->slices[i].i0[k]) * ts_window_bytes(st->rs.window);
    most = fmax(most, bytes);
  }
  return c->o.batch_timeout + 30.0 + most / CL_BUILD_RATE;
}


/* Whether w is loaded with st's query image before its slice, so that the
 * slice's fine rows need not travel: they are the image's reference and
 * w holds no state of the image's current level (it would be loaded
 * before its first queries anyway). */
static int loads_image_first(cluster_search *cs, const cl_set *st, const cl_worker *w) {
  cl_image *im = &cs->images[st->rs.image];
  return st->fine_in_image && st->image_level == im->level && cl_synced_of(im, w) == NULL;
}

static int queue_image_load(ts_cluster *c, const cl_image *im, cl_worker *w, char *err) {
  ts_msg_image m;
  cl_load_message(im, &m);
  (void)c;
  return cl_queue_image(w, im->gid, &m, err);
}

static int load_local(cluster_search *cs, cl_set *st, char *err) {
  static const uint32_t i0[TS_MAX_CLASSES] = {0};
  ts_cluster *c = cs->c;
  if (cl_canceled(cs)) return ts_error(err, TS_ECANCELED, "job canceled"); /* nothing in-process for it */
  ts_slice_desc m;
  ts_slice_describe(&m, &st->rs, &st->usage, st->gid, st->gen, st->image, i0, st->grid->count, NULL);
  if (st->lbg.mode != TS_LBG_OFF) ts_slice_describe_lbg(&m, &st->lbg);
  st->nheld = 0;
  return ts_slice_load(&st->local, &m, NULL, c->local_pool, err);
}

/* Makes the set's slicing match the current pool (lock held): every ready
 * worker gets a fresh slice (new generation) with the replica's counts; with
 * none, the coordinator loads the whole set itself. The set's loads may
 * lose workers --max-redispatch times: a worker that dies loading it (out
 * of memory, say) and rejoins would otherwise be fed it again and again -
 * and a slicing without it loads fine, so the count is not reset. */
static int ensure_slices(cluster_search *cs, cl_set *st, char *err) {
  ts_cluster *c = cs->c;
  while (!st->sliced || st->epoch != c->epoch) {
    if (cl_canceled(cs)) return ts_error(err, TS_ECANCELED, "job canceled");
    cl_worker **ws = cs->ws;
    int n = cl_ready_workers(c, ws);
    st->epoch = c->epoch;
    st->gen++;
    ts_slice_free(st->local);
    st->local = NULL;
    st->nslices = 0;
    st->sliced = 1;
    if (n > 0) n = cut_fitting(cs, st, ws, n);
    if (n == 0) return load_local(cs, st, err);
    cl_lease(c, ws, n);
    cl_traffic tr = {0, 0};
    double total = 0;
    uint64_t sent = 0, kept = 0;
    for (int i = 0; i < n; i++) total += ws[i]->slice_rate;
    for (int i = 0; i < n; i++) {
      ts_slice_desc m;
      char why[TS_ERR_LEN];
      int first = loads_image_first(cs, st, ws[i]);
      ws[i]->images_sent = (uint32_t)first << st->rs.image;
      if (first && queue_image_load(c, &cs->images[st->rs.image], ws[i], why) != 0) cl_worker_fail(c, ws[i], why);
      describe_slice(cs, st, i, first, &m);
      sent += ts_slice_row_bytes(&m, 0);
      kept += ts_slice_row_bytes(&m, 1);
      /* The rows stay in the level planes: each chunk of the message is
       * copied from there as the worker's socket drains. */
      if (cl_queue_slice(ws[i], st->gid, &m, why) != 0)
        cl_worker_fail(c, ws[i], why); /* moves the epoch: sliced again without it */
      ws[i]->share = (uint32_t)llround(1000.0 * ws[i]->slice_rate / total);
    }
    st->nslices = n;
    if (kept > 0)
      cl_log(c, "set %u generation %u over %d workers: %llu bytes of rows sent, %llu kept from their slices", st->gid,
             st->gen, n, (unsigned long long)sent, (unsigned long long)kept);
    int rc = cl_exchange(c, ws, n, load_deadline(c, st, n), cs->cancel, 0, loaded_reply, st, &tr);
    for (int i = 0; rc != TS_ECANCELED && i < n; i++)
      if (ws[i]->images_sent != 0 && ws[i]->state != TS_WORKER_FAILED)
        cl_mark_synced(c, &cs->images[st->rs.image], ws[i], cs->images[st->rs.image].rep.seq);
    if (rc != TS_ECANCELED) record_held(st, n);
    cl_release(c, ws, n);
    cs->base.stats.bytes_out += tr.bytes_out;
    cs->base.stats.bytes_in += tr.bytes_in;
    if (rc == TS_ECANCELED) return ts_error(err, TS_ECANCELED, "job canceled");
    if (rc == TS_ECONN && ++st->load_losses >= (int)c->o.max_redispatch)
      return ts_error(err, TS_ECONN, "loading set %u lost workers %d times (does a worker die loading it, out of "
                      "memory?); giving up on this job to protect the pool (texsyn-server --max-redispatch)", st->gid,
                      st->load_losses);
    /* A failure bumped the epoch: loop and slice again without it. */
  }
  return 0;
}

/* Frees what a set holds on the coordinator, and clears it. */
static void set_free(cl_set *st) {
  ts_slice_free(st->local);
  ts_usage_free(&st->usage);
  ts_lbg_free(&st->lbg);
  free(st->slices);
  free(st->ranges);
  free(st->held);
  memset(st, 0, sizeof(*st));
}

/* A partitioned set's codebook, on threads of its own (as many as the
 * local pool, which other jobs may be scanning on), outside the lock:
 * the coordinator holds every level plane, so it builds the whole set's. */
static int build_codebook(ts_cluster *c, cl_set *st, char *err) {
  ts_pool *pool;
  if (ts_pool_create(&pool, ts_pool_size(c->local_pool)) != 0)
    return ts_error(err, TS_ENOMEM, "cannot start threads to build a codebook");
  int rc = ts_lbg_build(&st->lbg, st->rs.window, st->rs.anchors, st->rs.ref, st->rs.lbg, pool, c->simd,
                        st->rs.lbg_report, err);
  ts_pool_destroy(pool);
  return rc;
}

static int cluster_prepare(ts_search *s, const ts_refset *rs, int *id, char *err) {
  cluster_search *cs = (cluster_search *)s;
  int slot = 0;
  while (slot < CL_MAX_SETS && cs->sets[slot].used) slot++;
  if (slot == CL_MAX_SETS) return ts_error(err, TS_ENOMEM, "too many reference sets prepared at once");
  cl_set *st = &cs->sets[slot];
  if (rs->field) {
    memset(st, 0, sizeof(*st));
    st->rs = *rs;
    int rc = cl_field_prepare(cs, st, err);
    *id = slot;
    return rc;
  }
  if (image_get(cs, rs->image) == NULL) return ts_error(err, TS_EINVAL, "unknown query image %d", rs->image);
  memset(st, 0, sizeof(*st));
  st->rs = *rs;
  st->image = cs->images[rs->image].gid;
  st->grid = rs->anchors;
  st->with_usage = rs->usage;
  size_t slots = (size_t)cs->c->o.max_workers, nclass = (size_t)rs->anchors->nclass;
  st->slices = calloc(slots, sizeof(*st->slices));
  st->ranges = calloc(slots * 2 * nclass, sizeof(uint32_t));
  st->held = calloc(slots, sizeof(*st->held));
  if (st->slices == NULL || st->ranges == NULL || st->held == NULL ||
      (rs->usage && ts_usage_init(&st->usage, rs->anchors, rs->window->spec.block, 0) != 0)) {
    set_free(st);
    return ts_error(err, TS_ENOMEM, "out of memory for a reference set");
  }
  for (size_t i = 0; i < slots; i++) {
    st->slices[i].i0 = st->ranges + 2 * nclass * i;
    st->slices[i].i1 = st->slices[i].i0 + nclass;
  }
  if (rs->usage && rs->counts != NULL) ts_usage_load(&st->usage, rs->counts->count);
  int rc = rs->lbg != NULL ? build_codebook(cs->c, st, err) : 0;
  if (rc != 0) {
    set_free(st);
    return rc;
  }
  find_shortcuts(cs, st);
  pthread_mutex_lock(&cs->c->lock);
  st->gid = ++cs->c->next_set;
  st->used = 1;
  rc = ensure_slices(cs, st, err);
  pthread_mutex_unlock(&cs->c->lock);
  *id = slot;
  return rc;
}

static int cluster_image_open(ts_search *s, const ts_replica_desc *d, int *id, char *err) {
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

static int cluster_place(ts_search *s, int id, const ts_place *p, uint32_t n, char *err) {
  cl_image *im = image_get((cluster_search *)s, id);
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
static int cluster_image_next(ts_search *s, int id, int w, int h, int rw, int rh, const uint8_t *const *ref,
                              char *err) {
  cluster_search *cs = (cluster_search *)s;
  ts_cluster *c = cs->c;
  cl_image *im = image_get(cs, id);
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
static void cluster_image_close(ts_search *s, int id) {
  cluster_search *cs = (cluster_search *)s;
  ts_cluster *c = cs->c;
  cl_image *im = image_get(cs, id);
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

/* The queries of one exchange are counted over the concatenated queries
 * of all its requests. */
#define CL_MAX_QUERIES (1u << 24)
#define CL_MAX_REQS 64

typedef struct {
  cl_set *st[CL_MAX_REQS];
  uint32_t q0[CL_MAX_REQS + 1]; /* request r holds queries q0[r]..q0[r+1]-1 */
  uint32_t nreq;
  const ts_search_req *req;
  ts_l1_best *best;
  uint64_t lbg_pairs; /* vectors the answers of partitioned sets report compared */
} batch_ctx;

static void merge_best(ts_l1_best *into, const ts_l1_best *b) {
  if (b->dist < into->dist || (b->dist == into->dist && b->index < into->index)) *into = *b;
}

/* A worker's rate: the bytes its answers report scanned over the scan time
 * they report. Its own scan time, not the time to its last answer: a
 * worker behind a slower link scans as fast as the others and must keep
 * its share (end to end, it would lose some at every rebalance), while
 * one whose CPU is taken by other work scans slower and loses share. */
static void track_rate(cl_worker *w) {
  w->batches++;
  double dt = (double)w->answered_nanos * 1e-9;
  if (dt < CL_MIN_SAMPLE_SECONDS || w->answered_bytes == 0) return;
  /* Decayed sums of bytes and of seconds, and their ratio: an average over
   * time. An average of per-batch rates would let the short batches that
   * ran uninterrupted outweigh the long ones, and under-report a worker
   * that gets half of its CPU as getting 0.7 of it. */
  double keep = exp(-dt / CL_RATE_TAU);
  w->ewma_bytes = w->ewma_bytes * keep + (double)w->answered_bytes;
  w->ewma_secs = w->ewma_secs * keep + dt;
  w->ewma_rate = w->ewma_bytes / w->ewma_secs;
  w->ewma_weight += dt;
}

/* Whether every result of an answer lies in the answering worker's slice
 * of the queries' classes: a result from elsewhere (a forged or confused
 * answer) could beat the true best and change the output. An exhaustive
 * slice holding vectors of a class always has a best one. */
static int check_results(const batch_ctx *b, uint32_t r, const cl_frame_sent *fs, const ts_msg_answer *a,
                         char *err) {
  const cl_set *st = b->st[r];
  const cl_slice *sl = &st->slices[fs->slice];
  const ts_query_batch *qb = &b->req[r].b;
  for (uint32_t i = 0; i < a->nq; i++) {
    ts_l1_best res;
    ts_msg_result_at(a, i, &res);
    int cls = qb->klass ? qb->klass[fs->q0 - b->q0[r] + i] : 0;
    uint32_t lo = st->grid->base[cls] + sl->i0[cls], hi = st->grid->base[cls] + sl->i1[cls];
    if (res.index == UINT32_MAX ? st->lbg.mode == TS_LBG_OFF && hi > lo : res.index < lo || res.index >= hi)
      return ts_error(err, TS_EPROTO, "protocol: answer index %d to query %u (class %d) outside the worker's slice "
                      "[%u, %u) of set %u", res.index == UINT32_MAX ? -1 : (int)res.index, fs->q0 + i, cls, lo, hi,
                      st->gid);
  }
  return 0;
}

/* One answer frame (rq: the 'V' or 'R' it answers). A short, extra or
 * misaddressed answer fails the worker, so the batch is asked again:
 * merging it would leave queries with another worker's best only, a wrong
 * result. */
static int answer_reply(void *ctx, cl_worker *w, const ts_frame *f, const cl_request *rq, char *err) {
  batch_ctx *b = ctx;
  if (f->type == TS_MSG_ERROR) return cl_reply_error(f, err);
  if (f->type == TS_MSG_IMAGE) return cl_image_ack(f, rq, err); /* a query image loaded ahead of the queries */
  ts_msg_answer a;
  if (ts_msg_answer_read(f, &a, err) != 0) return TS_EPROTO;
  const cl_frame_sent *fs = &w->frames[rq->tag];
  uint32_t r = 0;
  if (a.nq != fs->nq)
    return ts_error(err, TS_EPROTO, "protocol: answer with %u results to the query frame of first query %u, which "
                    "asked %u", a.nq, fs->q0, fs->nq);
  while (r < b->nreq && fs->q0 >= b->q0[r + 1]) r++;
  const cl_set *st = b->st[r];
  if (a.set != st->gid || a.gen != st->gen)
    return ts_error(err, TS_EPROTO, "protocol: answer for set %u generation %u to a query of set %u generation %u",
                    a.set, a.gen, st->gid, st->gen);
  int rc = check_results(b, r, fs, &a, err);
  if (rc != 0) return rc;
  for (uint32_t i = 0; i < a.nq; i++) {
    ts_l1_best res;
    ts_msg_result_at(&a, i, &res);
    merge_best(&b->best[fs->q0 + i], &res);
  }
  if (st->lbg.mode != TS_LBG_OFF) b->lbg_pairs += a.pairs;
  w->answered_bytes += a.pairs * ts_window_bytes(st->rs.window);
  w->answered_nanos += a.scan_nanos;
  return 0;
}

/* After each batch: do the measured rates still match the slicing? A
 * deviation beyond the tolerance that lasts `persist` seconds re-slices
 * everything with the measured rates (lock held). */
static void check_balance(ts_cluster *c, cl_worker **ws, int n) {
  if (n < 2 || !(c->o.rebalance_from & TS_REBALANCE_BATCHES)) return;
  double mean = 0;
  for (int i = 0; i < n; i++) {
    if (ws[i]->ewma_weight < CL_RATE_TAU) return; /* too little measured yet */
    mean += ws[i]->ewma_rate / ws[i]->slice_rate;
  }
  mean /= n;
  double dev = 0;
  for (int i = 0; i < n; i++) dev = fmax(dev, fabs(ws[i]->ewma_rate / ws[i]->slice_rate / mean - 1.0));
  double now = ts_now();
  if (dev <= c->o.tolerance) {
    c->deviating_since = 0;
    return;
  }
  if (c->deviating_since == 0) {
    c->deviating_since = now;
    return;
  }
  if (now - c->deviating_since < c->o.persist) return;
  for (int i = 0; i < n; i++) {
    ws[i]->slice_rate = ws[i]->ewma_rate;
    ws[i]->share_sized = -1; /* the next Modbus read is the new baseline */
  }
  c->deviating_since = 0;
  c->rebalances++;
  c->epoch++;
  cl_log(c, "rebalance %llu: rates deviated by %.0f%% for %.1fs", (unsigned long long)c->rebalances, dev * 100,
       c->o.persist);
}

static int ensure_best(cluster_search *cs, uint32_t nq) {
  if (nq <= cs->cap_best) return 0;
  ts_l1_best *b = realloc(cs->best, sizeof(ts_l1_best) * nq);
  if (b == NULL) return TS_ENOMEM;
  cs->best = b;
  cs->cap_best = nq;
  return 0;
}

/* With no worker ready the coordinator scans its own whole-set slice,
 * with the code a worker runs. */
static int query_local(cluster_search *cs, cl_set *st, const ts_query_batch *b, ts_l1_best *out, uint64_t *pairs,
                       char *err) {
  ts_cluster *c = cs->c;
  ts_vec_batch vb;
  int rc = cl_flush_image(cs, st->rs.image, err);
  if (rc == 0) rc = ts_query_vectors(&cs->scratch, &cs->images[st->rs.image].rep, st->rs.window, b, &vb, err);
  if (rc == 0) rc = ts_slice_scan(st->local, c->local_pool, 0, c->simd, &vb, out, pairs, err);
  return rc;
}

/* Slices every request's set over the current pool; all of them must end
 * up cut for the same epoch (a failed load moves it: start again). */
static int slice_all(cluster_search *cs, batch_ctx *bc, char *err) {
  for (;;) {
    for (uint32_t r = 0; r < bc->nreq; r++) {
      int rc = ensure_slices(cs, bc->st[r], err);
      if (rc != 0) return rc;
    }
    uint32_t r = 0;
    while (r < bc->nreq && bc->st[r]->epoch == cs->c->epoch) r++;
    if (r == bc->nreq) return 0;
  }
}

/* Remembers a query frame sent to w (of its slice i of the set), to check
 * its answer. */
static int note_frame(cl_worker *w, uint32_t q0, uint32_t nq, int slice) {
  if (w->nframes == w->cap_frames) {
    uint32_t cap = w->cap_frames ? 2 * w->cap_frames : 64;
    cl_frame_sent *f = realloc(w->frames, sizeof(*f) * cap);
    if (f == NULL) return TS_ENOMEM;
    w->frames = f;
    w->cap_frames = cap;
  }
  w->frames[w->nframes++] = (cl_frame_sent){q0, nq, slice};
  return 0;
}

/* The workers holding slices of the batch's sets, each once. */
static int batch_workers(const batch_ctx *bc, cl_worker **ws) {
  int n = 0;
  for (uint32_t r = 0; r < bc->nreq; r++)
    for (int i = 0; i < bc->st[r]->nslices; i++) {
      cl_worker *w = bc->st[r]->slices[i].w;
      int k = 0;
      while (k < n && ws[k] != w) k++;
      if (k == n) ws[n++] = w;
    }
  return n;
}

/* Before w's first frame of image im in this exchange: a load of the
 * replica if w does not hold its state; that frame carries the pending
 * placements. Returns the placements the frame carries. */
static int image_frame(cluster_search *cs, const batch_ctx *bc, cl_worker *w, int id, uint32_t *nplace, char *err) {
  cl_image *im = &cs->images[id];
  *nplace = 0;
  if (w->images_sent & 1u << id) return 0;
  w->images_sent |= 1u << id;
  *nplace = im->npending;
  cl_synced *y = cl_synced_of(im, w);
  if (y != NULL && y->seq == im->rep.seq) return 0;
  ts_msg_image m;
  cl_load_message(im, &m);
  (void)bc;
  return cl_queue_image(w, im->gid, &m, err);
}

/* Queues every request's V frames to the leased workers holding its
 * slices; cl_exchange encodes them as the sockets drain. */
static int queue_frames(cluster_search *cs, const batch_ctx *bc, const ts_search_req *req, cl_worker **ws, int n,
                        char *err) {
  ts_cluster *c = cs->c;
  for (int i = 0; i < n; i++) {
    ws[i]->answered_bytes = ws[i]->expected_bytes = ws[i]->answered_nanos = 0;
    ws[i]->nframes = 0;
    ws[i]->images_sent = 0;
  }
  for (uint32_t r = 0; r < bc->nreq; r++) {
    cl_set *st = bc->st[r];
    const cl_image *im = &cs->images[st->rs.image];
    const ts_query_batch *b = &req[r].b;
    uint32_t vbytes = ts_window_bytes(st->rs.window);
    uint64_t seq = im->rep.seq + (im->npending > 0); /* the state the queries need */
    for (int i = 0; i < st->nslices; i++) {
      cl_worker *w = st->slices[i].w;
      for (uint32_t q = 0; q < b->nq; q++) {
        int cls = b->klass ? b->klass[q] : 0;
        w->expected_bytes += (uint64_t)(st->slices[i].i1[cls] - st->slices[i].i0[cls]) * vbytes;
      }
      for (uint32_t q0 = 0; q0 < b->nq; q0 += c->o.pipeline_queries) {
        uint32_t q1 = q0 + c->o.pipeline_queries < b->nq ? q0 + c->o.pipeline_queries : b->nq, np;
        int rc = image_frame(cs, bc, w, st->rs.image, &np, err);
        if (rc != 0) return rc;
        cl_query_frame qf = {st->gid, st->gen, im->gid, seq, im->pending, np, b, q0, q1};
        if (note_frame(w, bc->q0[r] + q0, q1 - q0, i) != 0) return ts_error(err, TS_ENOMEM, "out of memory for a batch");
        rc = cl_queue_query(w, w->nframes - 1, &qf, err);
        if (rc != 0) return rc;
      }
    }
  }
  return 0;
}

/* After an exchange: the placements it carried reach the coordinator's
 * replicas, and every worker that was sent an image's frames and is not
 * failed answered them all: it holds that image's state. */
static int settle_images(cluster_search *cs, const batch_ctx *bc, cl_worker **ws, int n, char *err) {
  int rc = 0;
  for (uint32_t r = 0; r < bc->nreq; r++) {
    int id = bc->st[r]->rs.image;
    int fr = cl_flush_image(cs, id, err);
    if (rc == 0) rc = fr;
    for (int i = 0; i < n; i++)
      if (ws[i]->images_sent & 1u << id && ws[i]->state != TS_WORKER_FAILED)
        cl_mark_synced(cs->c, &cs->images[id], ws[i], cs->images[id].rep.seq);
  }
  return rc;
}

/* A batch's deadline: CL_DEADLINE_SLACK times what the slowest worker
 * should need at the lower of its sized and measured rates, never below
 * the --batch-timeout floor. A worker missing it is taken for stalled. */
static double batch_deadline(const ts_cluster *c, cl_worker **ws, int n) {
  double need = 0;
  for (int i = 0; i < n; i++) {
    double rate = fmin(ws[i]->slice_rate, ws[i]->ewma_rate);
    if (rate > 0) need = fmax(need, (double)ws[i]->expected_bytes / rate);
  }
  return fmax(c->o.batch_timeout, CL_DEADLINE_SLACK * need);
}

/* Every request in one exchange with the pool (lock held). Returns 0,
 * TS_ECONN when a worker failed (re-slice and retry), TS_ESTALE when the
 * pool changed while the workers were awaited (re-slice), or an error. */
static int exchange_batch(cluster_search *cs, batch_ctx *bc, const ts_search_req *req, char *err) {
  ts_cluster *c = cs->c;
  cl_worker **ws = cs->ws;
  int n = batch_workers(bc, ws);
  uint64_t epoch = c->epoch;
  cl_lease(c, ws, n);
  if (c->epoch != epoch) { /* the slicing is stale: nothing was sent */
    cl_release(c, ws, n);
    return TS_ESTALE;
  }
  bc->lbg_pairs = 0;
  ts_l1_best_reset(bc->best, bc->q0[bc->nreq]);
  int rc = queue_frames(cs, bc, req, ws, n, err);
  if (rc != 0) {
    for (int i = 0; i < n; i++) cl_out_reset(ws[i]);
    cl_release(c, ws, n);
    return rc;
  }
  cl_traffic tr = {0, 0};
  rc = cl_exchange(c, ws, n, batch_deadline(c, ws, n), cs->cancel, 0, answer_reply, bc, &tr);
  cl_release(c, ws, n);
  cs->base.stats.bytes_out += tr.bytes_out;
  cs->base.stats.bytes_in += tr.bytes_in;
  /* Canceled: which frames went out is not known, nor which workers hold
   * the image's new state - and the job is over. */
  if (rc == TS_ECANCELED) return ts_error(err, TS_ECANCELED, "job canceled");
  char why[TS_ERR_LEN];
  if (settle_images(cs, bc, ws, n, why) != 0) return ts_error(err, TS_EINVAL, "%s", why);
  if (rc == 0) {
    for (int i = 0; i < n; i++) track_rate(ws[i]);
    check_balance(c, ws, n);
  }
  return rc;
}

/* Checks a request against its set; *st = the set. */
static int check_req(cluster_search *cs, const ts_search_req *r, cl_set **st, char *err) {
  *st = set_get(cs, r->id);
  if (*st == NULL || (*st)->field) return ts_error(err, TS_EINVAL, "unknown reference set %d", r->id);
  if (r->b.usage_k != 0 && !(*st)->with_usage)
    return ts_error(err, TS_EINVAL, "a usage penalty on a set prepared without usage");
  return 0;
}

static int cluster_query_many(ts_search *s, const ts_search_req *req, uint32_t nreq, char *err) {
  cluster_search *cs = (cluster_search *)s;
  ts_cluster *c = cs->c;
  if (nreq > CL_MAX_REQS) return ts_error(err, TS_ETOOBIG, "%u requests at once (at most %d)", nreq, CL_MAX_REQS);
  batch_ctx bc = {.nreq = nreq, .req = req};
  for (uint32_t r = 0; r < nreq; r++) {
    int rc = check_req(cs, &req[r], &bc.st[r], err);
    if (rc != 0) return rc;
    if (req[r].b.nq > CL_MAX_QUERIES - bc.q0[r]) return ts_error(err, TS_ETOOBIG, "too many queries at once");
    bc.q0[r + 1] = bc.q0[r] + req[r].b.nq;
  }
  uint32_t nq = bc.q0[nreq];
  if (nq == 0) return 0;
  if (cl_canceled(cs)) return ts_error(err, TS_ECANCELED, "job canceled");
  if (ensure_best(cs, nq) != 0) return ts_error(err, TS_ENOMEM, "out of memory for a batch of %u queries", nq);
  bc.best = cs->best;
  double t0 = ts_now();
  uint64_t local_pairs = 0;
  int local = 0, rc, lost = 0;
  pthread_mutex_lock(&c->lock);
  do {
    rc = slice_all(cs, &bc, err);
    if (rc != 0) break;
    local = bc.st[0]->local != NULL; /* no worker: every set is local */
    if (local) {
      for (uint32_t r = 0; r < nreq && rc == 0; r++) {
        uint64_t pairs = 0;
        rc = query_local(cs, bc.st[r], &req[r].b, req[r].out, &pairs, err);
        local_pairs += pairs;
      }
      break;
    }
    /* A failed worker moved the epoch: slice again and re-ask (the
     * commits are in the replica now, which the new slices carry) -
     * unless this batch keeps killing workers: then it fails the job
     * rather than the pool. */
    rc = exchange_batch(cs, &bc, req, err);
    if (rc == TS_ECONN && ++lost >= (int)c->o.max_redispatch) {
      rc = ts_error(err, TS_ECONN, "a batch lost workers %d times in a row; giving up on this job to protect the pool",
                    lost);
      break;
    }
  } while (rc == TS_ECONN || rc == TS_ESTALE);
  pthread_mutex_unlock(&c->lock);
  if (rc != 0) return rc;
  /* Pairs: what the scans compared (an exhaustive set's every vector of
   * the class, a partitioned one's as its workers report); full pairs:
   * what exhaustive search compares. */
  for (uint32_t r = 0; r < nreq; r++) {
    const ts_query_batch *b = &req[r].b;
    uint64_t full = 0;
    for (uint32_t i = 0; i < b->nq; i++) full += bc.st[r]->grid->count[b->klass ? b->klass[i] : 0];
    if (!local) memcpy(req[r].out, bc.best + bc.q0[r], sizeof(ts_l1_best) * b->nq);
    if (!local && bc.st[r]->lbg.mode == TS_LBG_OFF) s->stats.pairs += full;
    s->stats.full_pairs += full;
    s->stats.batches++;
    s->stats.queries += b->nq;
  }
  s->stats.pairs += local ? local_pairs : bc.lbg_pairs;
  s->stats.round_trips++;
  pthread_mutex_lock(&c->lock);
  c->batches += nreq;
  c->queries += nq;
  pthread_mutex_unlock(&c->lock);
  s->stats.scan_seconds += ts_now() - t0;
  return 0;
}

static int cluster_query(ts_search *s, int id, const ts_query_batch *b, ts_l1_best *out, char *err) {
  ts_search_req r = {id, *b, out};
  return cluster_query_many(s, &r, 1, err);
}

static void set_clear(cluster_search *cs, cl_set *st) {
  ts_cluster *c = cs->c;
  pthread_mutex_lock(&c->lock);
  cl_worker **ws = cs->ws;
  int n = 0;
  if (st->epoch == c->epoch)
    for (int i = 0; i < st->nslices; i++) ws[n++] = st->slices[i].w;
  else /* slices may be on any worker that is still with us */
    n = cl_ready_workers(c, ws);
  cl_unload_set(c, ws, n, st->gid, cs->cancel);
  pthread_mutex_unlock(&c->lock);
  set_free(st);
}

static void cluster_release(ts_search *s, int id) {
  cluster_search *cs = (cluster_search *)s;
  cl_set *st = set_get(cs, id);
  if (st != NULL && st->field) cl_field_clear(cs, st);
  else if (st != NULL) set_clear(cs, st);
}

static void cluster_destroy(ts_search *s) {
  cluster_search *cs = (cluster_search *)s;
  for (int i = 0; i < CL_MAX_SETS; i++) cluster_release(s, i);
  for (int i = 0; i < CL_MAX_IMAGES; i++) cluster_image_close(s, i);
  ts_query_scratch_free(&cs->scratch);
  free(cs->best);
  free(cs->ws);
  free(cs);
}

/* The pool's calibrated rate: the ready workers' summed (each measured
 * when it joined), or with none the coordinator's own threads' (measured
 * once, when first asked). */
static double cluster_rate(ts_search *s) {
  ts_cluster *c = ((cluster_search *)s)->c;
  double rate = 0;
  uint64_t pairs, nanos;
  pthread_mutex_lock(&c->lock);
  for (int i = 0; i < c->nw; i++)
    if (c->w[i]->state == TS_WORKER_READY) rate += c->w[i]->calib_rate;
  if (rate == 0 && c->local_rate == 0 && ts_calib_run(c->local_pool, c->simd, CL_LOCAL_CALIB_MILLIS, &pairs, &nanos) == 0)
    c->local_rate = ts_calib_bytes_per_second(pairs, nanos);
  if (rate == 0) rate = c->local_rate;
  pthread_mutex_unlock(&c->lock);
  return rate;
}

static const ts_search_ops cluster_ops = {
    .name = "cluster",
    .prepare = cluster_prepare,
    .image_open = cluster_image_open,
    .image_next = cluster_image_next,
    .place = cluster_place,
    .image_close = cluster_image_close,
    .query = cluster_query,
    .query_many = cluster_query_many,
    .field_pass = cl_field_pass,
    .rate = cluster_rate,
    .release = cluster_release,
    .destroy = cluster_destroy,
};

int ts_search_cluster_create(ts_search **out, ts_cluster *c, const atomic_int *cancel, char *err) {
  cluster_search *cs = calloc(1, sizeof(*cs));
  if (cs == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  cs->ws = cl_worker_list(c);
  if (cs->ws == NULL) {
    free(cs);
    return ts_error(err, TS_ENOMEM, "out of memory");
  }
  cs->base.ops = &cluster_ops;
  cs->base.simd = c->simd;
  cs->c = c;
  cs->cancel = cancel;
  *out = &cs->base;
  return 0;
}
