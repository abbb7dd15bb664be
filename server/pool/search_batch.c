/* search_batch.c - see search_batch.h. */
#include "search_batch.h"

#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "search_replica.h"
#include "search_sets.h"
#include "slice.h"

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
  w->ewma_rate = fmin(w->ewma_bytes / w->ewma_secs, w->calib_rate * CL_RATE_CAP);
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
      int rc = cl_ensure_slices(cs, bc->st[r], err);
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
  (void)bc;
  return y != NULL && y->seq == im->rep.seq ? 0 : cl_queue_image_load(w, im, err);
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
  *st = cl_set_get(cs, r->id);
  if (*st == NULL || (*st)->field) return ts_error(err, TS_EINVAL, "unknown reference set %d", r->id);
  if (r->b.usage_k != 0 && !(*st)->with_usage)
    return ts_error(err, TS_EINVAL, "a usage penalty on a set prepared without usage");
  return 0;
}

int cl_query_many(ts_search *s, const ts_search_req *req, uint32_t nreq, char *err) {
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

int cl_query(ts_search *s, int id, const ts_query_batch *b, ts_l1_best *out, char *err) {
  ts_search_req r = {id, *b, out};
  return cl_query_many(s, &r, 1, err);
}
