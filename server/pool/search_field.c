/* search_field.c - PatchMatch passes over the pool (patchmatch.h): every
 * worker holds a field set's source whole ('G', once), and a pass's tiles
 * are cut among the ready workers in proportion to their rates ('T'),
 * each worker reading the target from its replica of the query image. A
 * tile's result depends only on the pass's input field and seed, so the
 * tiles of a worker that fails are swept again by the others (or by the
 * coordinator, with none left) and the field is the same bytes whoever
 * swept what - and the same as the local backend's. */
#include "search_field.h"

#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include <sodium.h>

#include "error.h"
#include "search_replica.h"

/* Candidates a pixel tries in a pass (current, two neighbours, about 12
 * random), for deadlines only. */
#define PASS_CANDIDATES 15.0

static void source_message(const cl_set *st, uint32_t gid, ts_msg_field *m) {
  memset(m, 0, sizeof(*m));
  m->set = gid;
  m->win = st->rs.window->spec;
  m->w = st->rs.ref->fine[0]->w;
  m->h = st->rs.ref->fine[0]->h;
  m->nplanes = st->rs.window->spec.nplanes[TS_SRC_FINE];
  for (int k = 0; k < m->nplanes; k++) m->plane[k] = st->rs.ref->fine[k]->px;
}

/* What a worker would hold of the source: the hash of its 'G' message
 * with set id 0 (header, then the planes as they lie). */
static int source_key(const cl_set *st, uint8_t key[CL_SOURCE_KEY], char *err) {
  ts_msg_field *m = malloc(sizeof(*m));
  if (m == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  source_message(st, 0, m);
  int nplanes = m->nplanes;
  m->nplanes = 0; /* the header alone */
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_field_write(&w, m);
  int rc = ts_wr_status(&w) ? ts_error(err, TS_ENOMEM, "out of memory") : 0;
  crypto_generichash_state h;
  crypto_generichash_init(&h, NULL, 0, CL_SOURCE_KEY);
  crypto_generichash_update(&h, w.buf, w.len);
  uint8_t n = (uint8_t)nplanes;
  crypto_generichash_update(&h, &n, 1);
  for (int k = 0; k < nplanes; k++) crypto_generichash_update(&h, m->plane[k], (size_t)m->w * (size_t)m->h);
  crypto_generichash_final(&h, key, CL_SOURCE_KEY);
  ts_wr_free(&w);
  free(m);
  return rc;
}

/* Tells the workers holding an unused entry to free its source (lock
 * held) and empties it. */
static void source_evict(cluster_search *cs, cl_source *e) {
  ts_cluster *c = cs->c;
  cl_worker **ws = cs->ws;
  int all = cl_ready_workers(c, ws), n = 0;
  for (int i = 0; i < all; i++)
    for (int h = 0; h < e->nheld; h++)
      if (e->held[h].worker == ws[i]->id && e->held[h].wipes == ws[i]->wipes) ws[n++] = ws[i];
  cl_log(c, "patchmatch source %u: freed on %d worker%s to make room", e->gid, n, n == 1 ? "" : "s");
  cl_unload_set(c, ws, n, e->gid, cs->cancel);
  e->used = 0;
  e->nheld = 0;
}

/* The entry of a source with that key (lock held): the one that has it,
 * else a free one, else the least recently used unused one, emptied.
 * -1 when every entry is in use. */
static int source_entry(cluster_search *cs, const uint8_t *key) {
  ts_cluster *c = cs->c;
  int found = -1, spare = -1;
  for (int i = 0; i < CL_MAX_SOURCES && found < 0; i++) {
    cl_source *e = &c->sources[i];
    if (e->used && memcmp(e->key, key, CL_SOURCE_KEY) == 0) found = i;
    else if (!e->used && spare < 0) spare = i;
  }
  if (found >= 0) return found;
  if (spare < 0) {
    for (int i = 0; i < CL_MAX_SOURCES; i++)
      if (c->sources[i].refs == 0 && (spare < 0 || c->sources[i].last_use < c->sources[spare].last_use)) spare = i;
    if (spare < 0) return -1;
    /* The unload waits for leases with the lock released: the entry is
     * taken first (in use, no key), so no other job finds or takes it. */
    cl_source *e = &c->sources[spare];
    memset(e->key, 0, CL_SOURCE_KEY);
    e->refs = 1;
    source_evict(cs, e);
    e->refs = 0;
  }
  cl_source *e = &c->sources[spare];
  memcpy(e->key, key, CL_SOURCE_KEY);
  e->gid = ++c->next_set;
  e->used = 1;
  e->nheld = 0;
  return spare;
}

int cl_field_prepare(cluster_search *cs, cl_set *st, char *err) {
  const ts_plane *p0 = st->rs.ref->fine[0];
  int patch;
  uint8_t key[CL_SOURCE_KEY];
  int rc = ts_pm_window_check(st->rs.window, &patch, err);
  if (rc != 0) return rc;
  if (p0->w > TS_PASS_MAX_SIDE || p0->h > TS_PASS_MAX_SIDE)
    return ts_error(err, TS_ETOOBIG, "a %dx%d patchmatch source is over the wire's %d pixels a side", p0->w, p0->h,
                    TS_PASS_MAX_SIDE);
  if ((rc = source_key(st, key, err)) != 0) return rc;
  ts_cluster *c = cs->c;
  pthread_mutex_lock(&c->lock);
  int i = source_entry(cs, key);
  if (i >= 0) {
    c->sources[i].refs++;
    c->sources[i].last_use = ++c->source_clock;
    st->source = i;
    st->gid = c->sources[i].gid;
    st->field = 1;
    st->used = 1;
  }
  pthread_mutex_unlock(&c->lock);
  if (i < 0)
    return ts_error(err, TS_ELIMIT, "%d patchmatch sources are in use at once, the most workers hold; run fewer "
                    "jobs at once (texsyn-server --jobs)", CL_MAX_SOURCES);
  return 0;
}

/* Whether w holds st's source (it loaded it and freed it since by no
 * drain). */
static int holds(const ts_cluster *c, const cl_set *st, const cl_worker *w) {
  const cl_source *e = &c->sources[st->source];
  for (int i = 0; i < e->nheld; i++)
    if (e->held[i].worker == w->id && e->held[i].wipes == w->wipes) return 1;
  return 0;
}

static void note_holder(ts_cluster *c, cl_set *st, const cl_worker *w) {
  cl_source *e = &c->sources[st->source];
  for (int i = 0; i < e->nheld; i++)
    if (e->held[i].worker == w->id) {
      e->held[i].wipes = w->wipes;
      return;
    }
  if (e->nheld < (int)c->o.max_workers) e->held[e->nheld++] = (cl_holder){w->id, w->wipes};
}

/* The workers keep the source for the next set with its key. */
void cl_field_clear(cluster_search *cs, cl_set *st) {
  ts_cluster *c = cs->c;
  pthread_mutex_lock(&c->lock);
  c->sources[st->source].refs--;
  pthread_mutex_unlock(&c->lock);
  if (st->local_field != NULL) ts_pm_field_free(st->local_field);
  free(st->local_field);
  memset(st, 0, sizeof(*st));
}

/* ---- with no worker: the coordinator sweeps the tiles itself ------------ */

static int pass_local(cluster_search *cs, cl_set *st, cl_image *im, const ts_pm_job *j, const uint32_t *tiles,
                      int n, uint32_t *out, char *err) {
  ts_cluster *c = cs->c;
  int rc = 0;
  if (st->local_field == NULL) {
    st->local_field = calloc(1, sizeof(*st->local_field));
    if (st->local_field == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
    rc = ts_pm_field_init(st->local_field, st->rs.window, st->rs.ref->fine, ts_pool_size(c->local_pool), err);
    if (rc != 0) {
      free(st->local_field);
      st->local_field = NULL;
      return rc;
    }
    st->local_image = 0;
  }
  if (st->local_image != im->gid || st->local_seq != im->rep.seq) {
    const ts_plane *t[TS_WIN_MAX_PLANES];
    for (int k = 0; k < im->rep.nplanes; k++) t[k] = &im->rep.fine[k];
    st->local_image = 0;
    if ((rc = ts_pm_field_target(st->local_field, t, err)) != 0) return rc;
    st->local_image = im->gid;
    st->local_seq = im->rep.seq;
  }
  return ts_pm_field_pass(st->local_field, j, tiles, n, c->local_pool, out, err);
}

/* ---- one exchange ------------------------------------------------------- */

/* A worker's part of the exchange: its tiles, and what it was sent. */
typedef struct {
  cl_worker *w;
  const uint32_t *tiles;
  uint32_t ntiles;
  int sent_field, sent_image;
  int field_acked, image_acked, answered;
} part;

typedef struct {
  cluster_search *cs;
  cl_set *st;
  cl_image *im;
  const ts_field_pass *fp;
  part *parts;
  int n;
  uint8_t *done; /* per tile */
} pass_ctx;

static part *part_of(pass_ctx *x, const cl_worker *w) {
  for (int i = 0; i < x->n; i++)
    if (x->parts[i].w == w) return &x->parts[i];
  return NULL;
}

/* A tile's pixel rectangle. */
static void tile_rect(int tw, int th, uint32_t t, int *x0, int *y0, int *x1, int *y1) {
  int ntx = (tw + TS_PM_TILE - 1) / TS_PM_TILE;
  *x0 = (int)(t % (uint32_t)ntx) * TS_PM_TILE;
  *y0 = (int)(t / (uint32_t)ntx) * TS_PM_TILE;
  *x1 = *x0 + TS_PM_TILE < tw ? *x0 + TS_PM_TILE : tw;
  *y1 = *y0 + TS_PM_TILE < th ? *y0 + TS_PM_TILE : th;
}

static uint32_t le16(const uint8_t *p) { return (uint32_t)p[0] | (uint32_t)p[1] << 8; }

/* The answer's entries into the field, tile by tile; every entry must be a
 * patch centre of the source (the engine indexes the source with them). */
static int take_answer(pass_ctx *x, part *pt, const ts_msg_pass_answer *a, char *err) {
  const ts_field_pass *fp = x->fp;
  const ts_plane *src = x->st->rs.ref->fine[0];
  int patch;
  if (ts_pm_window_check(x->st->rs.window, &patch, err) != 0) return TS_EPROTO;
  int r = patch / 2;
  uint32_t k = 0;
  for (uint32_t i = 0; i < pt->ntiles; i++) {
    int x0, y0, x1, y1;
    tile_rect(fp->tw, fp->th, pt->tiles[i], &x0, &y0, &x1, &y1);
    if (a->nentries - k < (uint32_t)((x1 - x0) * (y1 - y0)))
      return ts_error(err, TS_EPROTO, "a patchmatch answer of %u entries for %u tiles", a->nentries, pt->ntiles);
    for (int y = y0; y < y1; y++)
      for (int xx = x0; xx < x1; xx++, k++) {
        uint32_t cx = le16(a->entries + 4 * (size_t)k), cy = le16(a->entries + 4 * (size_t)k + 2);
        if (cx < (uint32_t)r || cy < (uint32_t)r || cx >= (uint32_t)(src->w - r) || cy >= (uint32_t)(src->h - r))
          return ts_error(err, TS_EPROTO, "a patchmatch answer names (%u, %u), no patch centre", cx, cy);
        fp->out[2 * ((size_t)y * (size_t)fp->tw + (size_t)xx)] = cx;
        fp->out[2 * ((size_t)y * (size_t)fp->tw + (size_t)xx) + 1] = cy;
      }
  }
  if (k != a->nentries)
    return ts_error(err, TS_EPROTO, "a patchmatch answer of %u entries for %u tiles", a->nentries, pt->ntiles);
  for (uint32_t i = 0; i < pt->ntiles; i++) x->done[pt->tiles[i]] = 1;
  return 0;
}

/* An answer of a worker of the pass (rq: the 'G', 'R' or 'T' it answers). */
static int pass_reply(void *ctx, cl_worker *w, const ts_frame *f, const cl_request *rq, char *err) {
  pass_ctx *x = ctx;
  part *pt = part_of(x, w);
  if (f->type == TS_MSG_ERROR) return cl_reply_error(f, err);
  if (f->type == TS_MSG_FIELD) {
    uint32_t set;
    if (ts_msg_field_ack_read(f, &set, err) != 0) return TS_EPROTO;
    if (set != rq->tag)
      return ts_error(err, TS_EPROTO, "protocol: 'G' frame id %u loaded source %u; it was sent source %u", f->id, set,
                      rq->tag);
    pt->field_acked = 1;
    return 0;
  }
  if (f->type == TS_MSG_IMAGE) {
    int rc = cl_image_ack(f, rq, err);
    pt->image_acked = rc == 0;
    return rc;
  }
  ts_msg_pass_answer a;
  if (ts_msg_pass_answer_read(f, &a, err) != 0) return TS_EPROTO;
  if (a.set != x->st->gid || a.pass != x->fp->pass)
    return ts_error(err, TS_EPROTO, "protocol: a patchmatch answer for set %u pass %u to set %u pass %u", a.set,
                    a.pass, x->st->gid, x->fp->pass);
  int rc = take_answer(x, pt, &a, err);
  pt->answered = rc == 0;
  return rc;
}

/* The tiles left, cut in order among the parts by the workers' rates. */
static void cut_tiles(part *parts, int n, const uint32_t *left, uint32_t nleft) {
  double total = 0, cum = 0;
  for (int i = 0; i < n; i++) total += parts[i].w->slice_rate > 0 ? parts[i].w->slice_rate : 1;
  uint32_t start = 0;
  for (int i = 0; i < n; i++) {
    cum += parts[i].w->slice_rate > 0 ? parts[i].w->slice_rate : 1;
    uint32_t end = i == n - 1 ? nleft : (uint32_t)llround((double)nleft * cum / total);
    if (end < start) end = start;
    parts[i].tiles = left + start;
    parts[i].ntiles = end - start;
    start = end;
  }
}

/* What the slowest worker's tiles should take at its rate (bytes of
 * vectors compared a second), CL_DEADLINE_SLACK times over, plus the
 * loads' floor. */
static double pass_deadline(const ts_cluster *c, const pass_ctx *x) {
  double need = 0, vbytes = ts_window_bytes(x->st->rs.window);
  for (int i = 0; i < x->n; i++) {
    double rate = x->parts[i].w->slice_rate, pixels = (double)x->parts[i].ntiles * TS_PM_TILE * TS_PM_TILE;
    if (rate > 0) need = fmax(need, pixels * PASS_CANDIDATES * vbytes / rate);
  }
  return c->o.batch_timeout + 30.0 + CL_DEADLINE_SLACK * need;
}

/* Queues a part's messages: the source if the worker lacks it, the image
 * if it does not hold its state, the pass. */
static int queue_part(pass_ctx *x, part *pt, const ts_msg_field *src, char *err) {
  ts_cluster *c = x->cs->c;
  cl_worker *w = pt->w;
  if (!holds(c, x->st, w)) {
    int rc = cl_queue_field(w, src->set, src, err);
    if (rc != 0) return rc;
    pt->sent_field = 1;
  }
  cl_synced *y = cl_synced_of(x->im, w);
  if (y == NULL || y->seq != x->im->rep.seq) {
    ts_msg_image m;
    cl_load_message(x->im, &m);
    int rc = cl_queue_image(w, x->im->gid, &m, err);
    if (rc != 0) return rc;
    pt->sent_image = 1;
  }
  const ts_field_pass *fp = x->fp;
  ts_msg_pass m = {x->st->gid, x->im->gid, x->im->rep.seq, (uint32_t)fp->tw, (uint32_t)fp->th, fp->usage_k,
                   fp->seed, fp->pass, pt->ntiles, pt->tiles, fp->in, NULL, NULL};
  return cl_queue_pass(w, 0, &m, err);
}

/* One exchange over the ready workers ws[0..n) (lock held) for the tiles
 * left; the tiles answered are marked done. */
static int exchange_pass(pass_ctx *x, cl_worker **ws, int n, const uint32_t *left, uint32_t nleft, char *err) {
  ts_cluster *c = x->cs->c;
  part *parts = calloc((size_t)n, sizeof(*parts));
  ts_msg_field *src = malloc(sizeof(*src));
  if (parts == NULL || src == NULL) {
    free(parts);
    free(src);
    return ts_error(err, TS_ENOMEM, "out of memory for a patchmatch pass");
  }
  source_message(x->st, x->st->gid, src);
  cl_lease(c, ws, n);
  for (int i = 0; i < n; i++) parts[i].w = ws[i];
  cut_tiles(parts, n, left, nleft);
  x->parts = parts;
  x->n = n;
  for (int i = 0; i < n; i++) {
    char why[TS_ERR_LEN];
    if (ws[i]->state == TS_WORKER_FAILED) continue;
    if (queue_part(x, &parts[i], src, why) != 0) {
      cl_out_reset(ws[i]);
      cl_worker_fail(c, ws[i], why);
    }
  }
  cl_traffic tr = {0, 0};
  int rc = cl_exchange(c, ws, n, pass_deadline(c, x), x->cs->cancel, 0, pass_reply, x, &tr);
  for (int i = 0; i < n; i++) {
    if (ws[i]->state == TS_WORKER_FAILED || rc == TS_ECANCELED) continue; /* canceled: what they took is unknown */
    if (parts[i].field_acked) note_holder(c, x->st, ws[i]);
    if (parts[i].image_acked || (!parts[i].sent_image && parts[i].answered))
      cl_mark_synced(c, x->im, ws[i], x->im->rep.seq);
  }
  cl_release(c, ws, n);
  x->cs->base.stats.bytes_out += tr.bytes_out;
  x->cs->base.stats.bytes_in += tr.bytes_in;
  x->parts = NULL;
  free(parts);
  free(src);
  return rc;
}

/* The tiles not done yet, in order: how many. */
static uint32_t tiles_left(const uint8_t *done, uint32_t ntiles, uint32_t *left) {
  uint32_t n = 0;
  for (uint32_t t = 0; t < ntiles; t++)
    if (!done[t]) left[n++] = t;
  return n;
}

static int check_pass(cluster_search *cs, const ts_field_pass *fp, cl_set **st, cl_image **im, char *err) {
  *st = fp->set >= 0 && fp->set < CL_MAX_SETS && cs->sets[fp->set].used ? &cs->sets[fp->set] : NULL;
  if (*st == NULL || !(*st)->field) return ts_error(err, TS_EINVAL, "unknown patchmatch set %d", fp->set);
  *im = fp->image >= 0 && fp->image < CL_MAX_IMAGES && cs->images[fp->image].used ? &cs->images[fp->image] : NULL;
  if (*im == NULL) return ts_error(err, TS_EINVAL, "unknown query image %d", fp->image);
  if (fp->tw < 1 || fp->th < 1 || fp->tw > TS_PASS_MAX_SIDE || fp->th > TS_PASS_MAX_SIDE)
    return ts_error(err, TS_ETOOBIG, "a %dx%d patchmatch field is over the wire's %d pixels a side", fp->tw, fp->th,
                    TS_PASS_MAX_SIDE);
  return 0;
}

int cl_field_pass(ts_search *s, const ts_field_pass *fp, char *err) {
  cluster_search *cs = (cluster_search *)s;
  ts_cluster *c = cs->c;
  cl_set *st = NULL;
  cl_image *im = NULL;
  int rc = check_pass(cs, fp, &st, &im, err);
  if (rc != 0) return rc;
  if (cl_canceled(cs)) return ts_error(err, TS_ECANCELED, "job canceled");
  uint32_t ntiles = (uint32_t)ts_pm_tiles(fp->tw, fp->th);
  uint8_t *done = calloc(ntiles, 1);
  uint32_t *left = malloc(sizeof(uint32_t) * ntiles);
  if (done == NULL || left == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory for a patchmatch pass");
  double t0 = ts_now();
  pass_ctx x = {cs, st, im, fp, NULL, 0, done};
  pthread_mutex_lock(&c->lock);
  if (rc == 0) rc = cl_flush_image(cs, fp->image, err);
  for (int lost = 0; rc == 0;) {
    if (cl_canceled(cs)) {
      rc = ts_error(err, TS_ECANCELED, "job canceled");
      break;
    }
    uint32_t nleft = tiles_left(done, ntiles, left);
    if (nleft == 0) break;
    cl_worker **ws = cs->ws;
    int n = cl_ready_workers(c, ws);
    if (n == 0) {
      ts_pm_job j = {fp->tw, fp->th, fp->in, fp->usage_k, fp->seed, fp->pass, c->simd->id == TS_SIMD_SCALAR};
      rc = pass_local(cs, st, im, &j, left, (int)nleft, fp->out, err);
      break;
    }
    rc = exchange_pass(&x, ws, n, left, nleft, err);
    if (rc == TS_ECANCELED) {
      rc = ts_error(err, TS_ECANCELED, "job canceled");
      break;
    }
    /* Workers that failed left their tiles undone: sweep them again
     * elsewhere - unless passes keep killing workers. */
    if (tiles_left(done, ntiles, left) > 0 && ++lost >= (int)c->o.max_redispatch) {
      rc = ts_error(err, TS_ECONN, "a patchmatch pass lost workers %d times in a row; giving up on this job to "
                    "protect the pool", lost);
      break;
    }
    rc = 0;
  }
  pthread_mutex_unlock(&c->lock);
  free(done);
  free(left);
  if (rc != 0) return rc;
  s->stats.batches++;
  s->stats.queries += (uint64_t)fp->tw * (uint64_t)fp->th;
  s->stats.round_trips++;
  s->stats.scan_seconds += ts_now() - t0;
  return 0;
}
