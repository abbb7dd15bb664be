/* search_sets.c - see search_sets.h. */
#include "search_sets.h"

#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "search_field.h"
#include "search_replica.h"
#include "slice.h"
#include "usage.h"

#if __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "usage counters are shipped as in memory: little-endian hosts only"
#endif

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
int cl_ensure_slices(cluster_search *cs, cl_set *st, char *err) {
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
      if (first && cl_queue_image_load(ws[i], &cs->images[st->rs.image], why) != 0) cl_worker_fail(c, ws[i], why);
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

int cl_set_prepare(ts_search *s, const ts_refset *rs, int *id, char *err) {
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
  if (cl_image_get(cs, rs->image) == NULL) return ts_error(err, TS_EINVAL, "unknown query image %d", rs->image);
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
  rc = cl_ensure_slices(cs, st, err);
  pthread_mutex_unlock(&cs->c->lock);
  *id = slot;
  return rc;
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

void cl_set_release(ts_search *s, int id) {
  cluster_search *cs = (cluster_search *)s;
  cl_set *st = cl_set_get(cs, id);
  if (st != NULL && st->field) cl_field_clear(cs, st);
  else if (st != NULL) set_clear(cs, st);
}
