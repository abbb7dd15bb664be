/* main.c - texsyn-worker: holds slices of reference sets and scans them
 * for the coordinator's query batches (proto/PROTOCOL.md).
 *
 * Each connection is served by its own thread with blocking reads; the scan
 * threads form one pool shared by every connection (one batch at a time),
 * so a worker holding slices of several jobs gives each batch all its
 * cores. Slices belong to the connection that loaded them and go when it
 * ends: a coordinator that goes away leaves nothing behind. Every
 * connection authenticates first, whichever side opened it (auth.h). */
#include <getopt.h>
#include <malloc.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "auth.h"
#include "calib.h"
#include "connset.h"
#include "error.h"
#include "gate.h"
#include "l1.h"
#include "log.h"
#include "mbplane.h"
#include "wfield.h"
#include "wmon.h"
#include "msg.h"
#include "net.h"
#include "planted.h"
#include "pool.h"
#include "replica.h"
#include "slice.h"
#include "stop.h"
#include "util.h"

#define WORKER_MAX_SLICES 64 /* per connection */
#define WORKER_MAX_IMAGES 16 /* per connection */
#define HANDSHAKE_MS 10000
/* How long a refused peer gets to read its 'E' before we close. */
#define REFUSE_LINGER_MS 1000

typedef struct {
  int threads;
  uint32_t max_frame;
  uint64_t max_message; /* largest message reassembled from pieces */
  const char *name;
  const ts_l1_impl *simd;
  ts_pool *pool;
  pthread_mutex_t pool_lock; /* ts_pool_run is not reentrant */
  ts_connset conns;
  ts_gate gate; /* --listen connections that have not authenticated yet */
  ts_auth auth;
  int modbus_port; /* 0: no Modbus plane */
  /* Query images: what an 'R' may make this worker allocate, checked
   * before allocating (a 47-byte 'R' could ask for gigabytes), and what
   * every connection's images hold now. */
  uint64_t max_replica;
  atomic_uint_fast64_t replica_held;
} worker;

static worker g_w;
/* Set by the signal handler, read by every thread: an atomic, lock-free
 * here, so safe in a handler (volatile sig_atomic_t is only for the thread
 * the handler interrupts; elsewhere it is a data race). */
static atomic_int g_stop;
_Static_assert(ATOMIC_INT_LOCK_FREE == 2, "the stop flag must be lock-free to be set in a signal handler");

/* ---- one connection ------------------------------------------------------ */

typedef struct {
  ts_conn conn;
  uint32_t peer_caps; /* the coordinator's capabilities (its 'I') */
  ts_slice *slices[WORKER_MAX_SLICES];
  /* Query images: the coordinator's id of each, and the replica. */
  uint32_t image_id[WORKER_MAX_IMAGES];
  ts_replica images[WORKER_MAX_IMAGES];
  int image_used[WORKER_MAX_IMAGES];
  uint64_t image_bytes[WORKER_MAX_IMAGES]; /* counted in g_w.replica_held */
  ts_query_scratch scratch;
  ts_place *places;
  ts_commit *commits;
  uint32_t cap_places;
  ts_l1_best *best;
  uint32_t cap_best;
  ts_wfields fields; /* PatchMatch sources */
} session;

static int send_reply(session *s, uint8_t type, uint32_t id, ts_wr *w) {
  char err[TS_ERR_LEN];
  int rc = ts_wr_status(w) != 0 ? TS_ENOMEM : ts_conn_send(&s->conn, type, id, w->buf, w->len, err);
  ts_wr_free(w);
  return rc;
}

static int send_error(session *s, uint32_t id, int code, const char *text) {
  ts_wmon_error();
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_error_write(&w, code, text);
  return send_reply(s, TS_MSG_ERROR, id, &w);
}

static ts_slice **slot_of(session *s, uint32_t set) {
  for (int i = 0; i < WORKER_MAX_SLICES; i++)
    if (s->slices[i] != NULL && ts_slice_set(s->slices[i]) == set) return &s->slices[i];
  return NULL;
}

/* Frees a slice and takes its vectors off the monitor's count. */
static void drop_slice(ts_slice **slot) {
  if (*slot == NULL) return;
  ts_wmon_vectors(-(int64_t)ts_slice_vectors(*slot));
  ts_slice_free(*slot);
  *slot = NULL;
}

static void unload_all(session *s) {
  for (int i = 0; i < WORKER_MAX_SLICES; i++) drop_slice(&s->slices[i]);
  ts_wfield_drop(&s->fields, TS_UNLOAD_ALL);
}

static ts_replica *image_of(session *s, uint32_t id) {
  for (int i = 0; i < WORKER_MAX_IMAGES; i++)
    if (s->image_used[i] && s->image_id[i] == id) return &s->images[i];
  return NULL;
}

/* ---- the query images' memory budget ----------------------------------- */

/* Bytes a replica of w x h pixels with nplanes planes holds: its planes,
 * its done map, a copy map (8 bytes a pixel) when it has one, plus the
 * coarse (cw x ch) and reference (rw x rh) planes. */
static uint64_t replica_bytes(uint64_t w, uint64_t h, uint64_t nplanes, int copy, uint64_t cw, uint64_t ch,
                              uint64_t rw, uint64_t rh) {
  return w * h * (nplanes + 1 + (copy ? 8 : 0)) + (cw * ch + rw * rh) * nplanes;
}

/* Takes n bytes of the budget: 0, or TS_ELIMIT with a message. */
static int reserve_replica(uint64_t n, int w, int h, char *err) {
  uint64_t held = atomic_fetch_add(&g_w.replica_held, n);
  if (held + n <= g_w.max_replica) return 0;
  atomic_fetch_sub(&g_w.replica_held, n);
  return ts_error(err, TS_ELIMIT,
                  "a %dx%d query image needs %.1f MiB; this worker holds %.1f MiB of query images and its "
                  "--max-replica-memory is %.1f MiB",
                  w, h, n / 1048576.0, held / 1048576.0, g_w.max_replica / 1048576.0);
}

static void release_replica(uint64_t n) { atomic_fetch_sub(&g_w.replica_held, n); }

static void free_image(session *s, int i) {
  ts_replica_free(&s->images[i]);
  release_replica(s->image_bytes[i]);
  s->image_bytes[i] = 0;
  s->image_used[i] = 0;
}

static void close_images(session *s) {
  for (int i = 0; i < WORKER_MAX_IMAGES; i++) free_image(s, i);
  ts_query_scratch_free(&s->scratch);
  free(s->places);
  free(s->commits);
  s->places = NULL;
  s->commits = NULL;
  s->cap_places = 0;
}

/* Applies decoded placements to an image and their usage commits to every
 * slice that queries it. */
static int place_on(session *s, uint32_t id, ts_replica *r, const uint8_t *places, uint32_t n, char *err) {
  if (n > s->cap_places) {
    free(s->places);
    free(s->commits);
    s->places = malloc(sizeof(ts_place) * n);
    s->commits = malloc(sizeof(ts_commit) * 2 * n);
    s->cap_places = s->places && s->commits ? n : 0;
    if (s->cap_places == 0) return ts_error(err, TS_ENOMEM, "out of memory for %u placements", n);
  }
  for (uint32_t i = 0; i < n; i++) ts_msg_place_at(places, i, &s->places[i]);
  uint32_t nc;
  int rc = ts_replica_place(r, s->places, n, s->commits, &nc, err);
  for (int i = 0; rc == 0 && i < WORKER_MAX_SLICES; i++)
    if (s->slices[i] != NULL && ts_slice_image(s->slices[i]) == id) rc = ts_slice_commit(s->slices[i], s->commits, nc, err);
  return rc;
}

/* An 'R' LOAD: the copy map arrives as little-endian bytes. */
static int load_image(ts_replica *r, ts_msg_image *m, char *err) {
  uint32_t *copy = NULL;
  size_t n = 2 * (size_t)m->d.w * (size_t)m->d.h;
  /* The planes came in the message; the copy map's words are unpacked. */
  if (m->d.block != 0 && m->copy_le != NULL) {
    copy = malloc(sizeof(uint32_t) * n);
    if (copy == NULL) return ts_error(err, TS_ENOMEM, "out of memory for a %dx%d copy map", m->d.w, m->d.h);
    for (size_t i = 0; i < n; i++) {
      const uint8_t *p = m->copy_le + 4 * i;
      copy[i] = (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
    }
    m->d.copy = copy;
  }
  int rc = ts_replica_init(r, &m->d, err);
  free(copy);
  r->seq = m->seq;
  return rc;
}

/* 'R' LOAD into slot i: the budget first, then the replica. */
static int image_load(session *s, int i, ts_msg_image *m, char *err) {
  const ts_replica_desc *d = &m->d;
  if (d->w <= 0 || d->h <= 0) return ts_error(err, TS_EINVAL, "a query image of %dx%d", d->w, d->h);
  uint64_t need = replica_bytes((uint64_t)d->w, (uint64_t)d->h, (uint64_t)d->nplanes, d->block != 0 && m->copy_le,
                                d->cw > 0 ? (uint64_t)d->cw : 0, d->ch > 0 ? (uint64_t)d->ch : 0,
                                d->block && d->rw > 0 ? (uint64_t)d->rw : 0, d->block && d->rh > 0 ? (uint64_t)d->rh : 0);
  int rc = reserve_replica(need, d->w, d->h, err);
  if (rc == 0 && (rc = load_image(&s->images[i], m, err)) != 0) release_replica(need);
  if (rc != 0) return rc;
  s->image_used[i] = 1;
  s->image_id[i] = m->image;
  s->image_bytes[i] = need;
  return 0;
}

/* 'R' NEXT on slot i: the new level is allocated while the old one is
 * still held, so both count until it is done. */
static int image_next(session *s, int i, const ts_msg_image *m, char *err) {
  ts_replica *r = &s->images[i];
  if (m->w <= 0 || m->h <= 0 || m->rw <= 0 || m->rh <= 0)
    return ts_error(err, TS_EINVAL, "a next level of %dx%d from %dx%d", m->w, m->h, m->rw, m->rh);
  uint64_t need = replica_bytes((uint64_t)m->w, (uint64_t)m->h, (uint64_t)r->nplanes, 1, (uint64_t)r->w,
                                (uint64_t)r->h, (uint64_t)m->rw, (uint64_t)m->rh);
  int rc = reserve_replica(need, m->w, m->h, err);
  if (rc != 0) return rc;
  rc = place_on(s, m->image, r, m->places, m->nplace, err);
  if (rc == 0) rc = ts_replica_next_level(r, m->w, m->h, m->rw, m->rh, m->d.ref, err);
  if (rc != 0) {
    release_replica(need);
    return rc;
  }
  release_replica(s->image_bytes[i]);
  s->image_bytes[i] = need;
  return 0;
}

/* 'R': loads, advances or frees a query image. */
static int on_image(session *s, const ts_frame *f, char *err) {
  ts_msg_image m;
  int rc = ts_msg_image_read(f, &m, err);
  if (rc != 0) return rc;
  ts_replica *r = image_of(s, m.image);
  int i = r != NULL ? (int)(r - s->images) : 0;
  if (m.op == TS_IMAGE_LOAD) {
    while (r == NULL && i < WORKER_MAX_IMAGES && s->image_used[i]) i++;
    if (r == NULL && i == WORKER_MAX_IMAGES)
      return send_error(s, f->id, TS_ETOOBIG, "too many query images on one connection") == 0 ? 1 : TS_ECONN;
    free_image(s, i);
    if ((rc = image_load(s, i, &m, err)) != 0) return send_error(s, f->id, rc, err) == 0 ? 1 : TS_ECONN;
  } else if (m.op == TS_IMAGE_NEXT) {
    if (r == NULL || r->seq != m.seq) {
      snprintf(err, TS_ERR_LEN, "query image %u is not at state %llu", m.image, (unsigned long long)m.seq);
      return send_error(s, f->id, TS_EINVAL, err) == 0 ? 1 : TS_ECONN;
    }
    if ((rc = image_next(s, i, &m, err)) != 0) return send_error(s, f->id, rc, err) == 0 ? 1 : TS_ECONN;
  } else if (r != NULL) { /* CLOSE */
    free_image(s, i);
  }
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_image_ack_write(&w, m.image);
  return send_reply(s, TS_MSG_IMAGE, f->id, &w);
}

/* Semantic failures return 1 after an 'E' reply (the connection stays);
 * a negative return closes it. */
static int on_calibrate(session *s, const ts_frame *f, char *err) {
  ts_msg_calib_req req;
  int rc = ts_msg_calib_req_read(f, &req, err);
  if (rc != 0) return rc;
  ts_msg_calib cal = {0};
  pthread_mutex_lock(&g_w.pool_lock);
  rc = ts_calib_run(g_w.pool, g_w.simd, req.millis, &cal.pairs, &cal.nanos);
  pthread_mutex_unlock(&g_w.pool_lock);
  if (rc != 0) return send_error(s, f->id, rc, "out of memory for calibration") == 0 ? 1 : rc;
  ts_log("calibrated for %s: scans %.3g bytes/s", s->conn.peer, (double)cal.pairs * TS_CALIB_CHUNKS * TS_L1_CHUNK / (cal.nanos * 1e-9));
  ts_wmon_calibrated(cal.nanos > 0 ? (uint64_t)((double)cal.pairs * TS_CALIB_CHUNKS * TS_L1_CHUNK / (cal.nanos * 1e-9)) : 0);
  if (s->peer_caps & TS_CAP_PIECES) { /* it splits what exceeds these */
    cal.max_payload = g_w.max_frame;
    cal.max_message = g_w.max_message;
  }
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_calib_write(&w, &cal);
  return send_reply(s, TS_MSG_CALIBRATE, f->id, &w);
}

static int on_slice(session *s, const ts_frame *f, char *err) {
  ts_slice_desc m;
  int rc = ts_msg_slice_read(f, &m, err);
  if (rc != 0) return rc;
  if (m.fine_from_image && (rc = ts_replica_slice_rows(image_of(s, m.image), &m, err)) != 0)
    return send_error(s, f->id, rc, err) == 0 ? 1 : TS_ECONN;
  ts_slice *sl;
  ts_slice **slot = slot_of(s, m.set); /* the slice it replaces, which it may keep rows of */
  ts_wmon_loading(1);
  pthread_mutex_lock(&g_w.pool_lock); /* the build runs on the scan threads */
  rc = ts_slice_load(&sl, &m, slot != NULL ? *slot : NULL, g_w.pool, err);
  pthread_mutex_unlock(&g_w.pool_lock);
  ts_wmon_loading(-1);
  if (rc != 0) return send_error(s, f->id, TS_EINVAL, err) == 0 ? 1 : TS_ECONN;
  for (int i = 0; slot == NULL && i < WORKER_MAX_SLICES; i++)
    if (s->slices[i] == NULL) slot = &s->slices[i];
  if (slot == NULL) {
    ts_slice_free(sl);
    return send_error(s, f->id, TS_ETOOBIG, "too many slices on one connection") == 0 ? 1 : TS_ECONN;
  }
  drop_slice(slot);
  *slot = sl;
  ts_wmon_vectors((int64_t)ts_slice_vectors(sl));
  if (s->conn.pieces.count > 0)
    ts_log("set %u generation %u: %llu vectors from a message of %u bytes in %u pieces", m.set, m.gen,
           (unsigned long long)ts_slice_vectors(sl), f->len, s->conn.pieces.count);
  if (m.base_gen != 0)
    ts_log("set %u generation %u: %llu vectors from a message of %u bytes, fine rows %d..%d kept from generation %u",
           m.set, m.gen, (unsigned long long)ts_slice_vectors(sl), f->len, m.kfy0, m.kfy1 - 1, m.base_gen);
  ts_msg_loaded ack = {m.set, m.gen, ts_slice_vectors(sl)};
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_loaded_write(&w, &ack);
  return send_reply(s, TS_MSG_SLICE, f->id, &w);
}

static double now_nanos(void) { return ts_now() * 1e9; }

/* The frame's placements, then its queries' vectors out of the image. */
static int query_vectors(session *s, ts_slice *slice, const ts_msg_query *q, uint32_t *pos, ts_vec_batch *vb,
                         char *err) {
  ts_replica *r = image_of(s, q->image);
  if (r == NULL || ts_slice_image(slice) != q->image)
    return ts_error(err, TS_EINVAL, "query image %u is not loaded for set %u", q->image, q->set);
  if (r->seq + (q->nplace > 0) != q->seq)
    return ts_error(err, TS_EINVAL, "query image %u is at state %llu, the queries need %llu", q->image,
                    (unsigned long long)r->seq, (unsigned long long)q->seq);
  if (q->nplace > 0) {
    int rc = place_on(s, q->image, r, q->places, q->nplace, err);
    if (rc != 0) return rc;
    r->seq++;
  }
  for (uint32_t i = 0; i < q->nq; i++) pos[i] = ts_msg_pos_at(q, i);
  ts_query_batch b = {q->nq, pos, (q->flags & TS_QUERY_MASKS) != 0, q->klass, q->usage_k};
  return ts_query_vectors(&s->scratch, r, ts_slice_window(slice), &b, vb, err);
}

static int on_query(session *s, const ts_frame *f, char *err) {
  ts_planted_fault();
  ts_msg_query q;
  int rc = ts_msg_query_read(f, &q, err);
  if (rc != 0) return rc;
  ts_slice **slot = slot_of(s, q.set);
  if (slot == NULL || ts_slice_gen(*slot) != q.gen) {
    snprintf(err, TS_ERR_LEN, "set %u generation %u is not loaded (have %d)", q.set, q.gen,
             slot ? (int)ts_slice_gen(*slot) : -1);
    return send_error(s, f->id, TS_EINVAL, err) == 0 ? 1 : TS_ECONN;
  }
  if (q.nq > s->cap_best) {
    ts_l1_best *b = realloc(s->best, sizeof(ts_l1_best) * q.nq);
    if (b == NULL) return send_error(s, f->id, TS_ENOMEM, "out of memory for the answers") == 0 ? 1 : TS_ECONN;
    s->best = b;
    s->cap_best = q.nq;
  }
  uint64_t pairs = 0;
  double t0 = 0;
  ts_vec_batch b;
  uint32_t *pos = malloc(sizeof(uint32_t) * (q.nq ? q.nq : 1));
  rc = pos != NULL ? query_vectors(s, *slot, &q, pos, &b, err) : ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0) {
    pthread_mutex_lock(&g_w.pool_lock);
    t0 = now_nanos();
    rc = ts_slice_scan(*slot, g_w.pool, 0, g_w.simd, &b, s->best, &pairs, err);
    t0 = now_nanos() - t0;
    pthread_mutex_unlock(&g_w.pool_lock);
  }
  free(pos);
  if (rc != 0) return send_error(s, f->id, rc, err) == 0 ? 1 : TS_ECONN;
  ts_wmon_batch(q.nq, pairs * ts_slice_vbytes(*slot), (uint64_t)t0);
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_answer_write(&w, q.set, q.gen, (uint64_t)t0, pairs, s->best, q.nq);
  return send_reply(s, TS_MSG_QUERY, f->id, &w);
}

static int on_unload(session *s, const ts_frame *f, char *err) {
  ts_msg_unload m;
  int rc = ts_msg_unload_read(f, &m, err);
  if (rc != 0) return rc;
  if (m.set == TS_UNLOAD_ALL) {
    unload_all(s);
  } else {
    ts_slice **slot = slot_of(s, m.set);
    if (slot != NULL) drop_slice(slot);
    ts_wfield_drop(&s->fields, m.set);
  }
  /* Slices are freed whole when a job is done with them: glibc keeps what
   * is freed for reuse, and an idle worker kept the RSS of its largest job
   * (230 MiB after two colour jobs, bench/soak.py). Give it back. */
  malloc_trim(0);
  ts_wr w;
  ts_wr_init(&w);
  return send_reply(s, TS_MSG_UNLOAD, f->id, &w);
}

/* 'G': a PatchMatch source, held whole. */
static int on_field(session *s, const ts_frame *f, char *err) {
  ts_msg_field *m = malloc(sizeof(*m));
  if (m == NULL) return send_error(s, f->id, TS_ENOMEM, "out of memory") == 0 ? 1 : TS_ECONN;
  int rc = ts_msg_field_read(f, m, err);
  if (rc != 0) {
    free(m);
    return rc;
  }
  uint32_t set = m->set;
  rc = ts_wfield_load(&s->fields, m, g_w.threads, err);
  if (rc == 0) ts_log("patchmatch source %u: %dx%d, %d planes", set, m->w, m->h, m->nplanes);
  free(m);
  if (rc != 0) return send_error(s, f->id, rc, err) == 0 ? 1 : TS_ECONN;
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_field_ack_write(&w, set);
  return send_reply(s, TS_MSG_FIELD, f->id, &w);
}

/* 'T': tiles of a PatchMatch pass, on the scan threads. */
static int on_pass(session *s, const ts_frame *f, char *err) {
  ts_planted_fault();
  ts_msg_pass m;
  int rc = ts_msg_pass_read(f, &m, err);
  if (rc != 0) return rc;
  ts_wr w;
  ts_wr_init(&w);
  pthread_mutex_lock(&g_w.pool_lock);
  rc = ts_wfield_pass(&s->fields, &m, image_of(s, m.image), g_w.pool, g_w.simd->id == TS_SIMD_SCALAR, &w, err);
  pthread_mutex_unlock(&g_w.pool_lock);
  if (rc != 0) {
    ts_wr_free(&w);
    return send_error(s, f->id, rc, err) == 0 ? 1 : TS_ECONN;
  }
  ts_wmon_pass();
  return send_reply(s, TS_MSG_PASS, f->id, &w);
}

static int handle(session *s, const ts_frame *f, char *err) {
  switch (f->type) {
  case TS_MSG_CALIBRATE: return on_calibrate(s, f, err);
  case TS_MSG_SLICE: return on_slice(s, f, err);
  case TS_MSG_QUERY: return on_query(s, f, err);
  case TS_MSG_UNLOAD: return on_unload(s, f, err);
  case TS_MSG_IMAGE: return on_image(s, f, err);
  case TS_MSG_FIELD: return on_field(s, f, err);
  case TS_MSG_PASS: return on_pass(s, f, err);
  case TS_MSG_HEARTBEAT: {
    if (f->len != 0) return ts_error(err, TS_EPROTO, "malformed 'H' message: payload must be empty");
    /* The drain coil's state, on the authenticated link: the coordinator
     * acts on a drain only when this confirms what Modbus says. */
    ts_wr w;
    ts_wr_init(&w);
    ts_wr_u8(&w, ts_wmon_draining() ? TS_HEARTBEAT_DRAINING : 0);
    return send_reply(s, TS_MSG_HEARTBEAT, f->id, &w);
  }
  default:
    return ts_error(err, TS_EPROTO, "unexpected message type 0x%02x", f->type);
  }
}

/* Identify and authenticate: a coordinator that connected to us speaks
 * first, after protected mode let it in (addr: its address); when we
 * joined a coordinator (addr NULL), we do. */
static int handshake(session *s, const struct sockaddr *addr, char *err) {
  ts_msg_ident me = {TS_ROLE_WORKER, TS_CAP_ALL | TS_CAP_PIECES, (uint16_t)g_w.threads, (uint8_t)g_w.simd->id, "",
                     (uint16_t)g_w.modbus_port},
               peer;
  snprintf(me.name, sizeof(me.name), "texsyn-worker 0.3 %s", g_w.name);
  int rc;
  if (addr == NULL) {
    rc = ts_auth_connect(&s->conn, &g_w.auth, &me, &peer, HANDSHAKE_MS, err);
  } else {
    rc = ts_auth_peer_allowed(&g_w.auth, addr, err);
    if (rc == 0) rc = ts_auth_accept(&s->conn, &g_w.auth, &me, &peer, NULL, TS_GATE_HANDSHAKE_MS, err);
    if (rc == 0) ts_gate_leave(&g_w.gate, s->conn.fd); /* else when it is closed */
  }
  if (rc == 0 && peer.role != TS_ROLE_COORD) rc = ts_error(err, TS_EPROTO, "peer is not a coordinator");
  if (rc == 0) s->peer_caps = peer.caps;
  return rc;
}

/* Serves one connection until it ends; returns the handshake's result
 * (0: the connection was established). */
static int serve(int fd, const char *peer, const struct sockaddr *addr) {
  session *s = calloc(1, sizeof(*s));
  if (s == NULL) {
    close(fd);
    return TS_ENOMEM;
  }
  ts_conn_init(&s->conn, fd, g_w.max_frame, peer);
  ts_conn_accept_pieces(&s->conn, g_w.max_message); /* once the connection has started */
  char err[TS_ERR_LEN] = "";
  int rc = handshake(s, addr, err);
  if (rc == TS_EAUTH) {
    /* We refused the peer, or the coordinator we joined refused us. */
    if (addr != NULL) ts_warn("refused %s: %s", peer, err);
    else ts_warn("join %s refused: %s", peer, err);
    if (addr != NULL) send_error(s, 0, rc, err);
    ts_connset_remove(&g_w.conns, fd);
    ts_conn_linger(&s->conn, REFUSE_LINGER_MS); /* counted as pending meanwhile */
    ts_gate_leave(&g_w.gate, fd);
    ts_conn_close(&s->conn);
    free(s);
    return rc;
  }
  int started = rc;
  if (rc == 0) ts_log("coordinator %s connected", peer);
  /* A start that failed on our port is no news unless it says something:
   * a peer that left (or was closed to make room, gate.h) is not logged,
   * and slow or silent ones only a line per TS_LOG_LIMIT_SECONDS. */
  static ts_log_limit timeouts = TS_LOG_LIMIT_INIT;
  if (addr != NULL && (rc == TS_ECONN || rc == TS_ETIMEDOUT)) {
    if (rc == TS_ETIMEDOUT) ts_log_limited(&timeouts, "closed %s: %s", peer, err);
    ts_connset_remove(&g_w.conns, fd);
    ts_gate_leave(&g_w.gate, fd);
    ts_conn_close(&s->conn);
    free(s);
    return rc;
  }
  while (rc >= 0 && !atomic_load(&g_stop)) {
    ts_frame f;
    rc = ts_conn_recv(&s->conn, &f, 1000, err);
    if (rc == TS_ETIMEDOUT) {
      rc = 0;
      continue;
    }
    if (rc >= 0) rc = handle(s, &f, err);
  }
  if (rc == TS_ECONN) ts_log("%s", err[0] ? err : "connection closed");
  else if (rc < 0) {
    ts_wmon_error();
    ts_log("protocol error from %s: %s; closing", peer, err);
    send_error(s, 0, rc, err);
  }
  ts_connset_remove(&g_w.conns, fd);
  ts_gate_leave(&g_w.gate, fd); /* a start that broke the protocol */
  unload_all(s);
  close_images(s);
  ts_conn_close(&s->conn);
  free(s->best);
  free(s);
  return started;
}

/* ---- listening and joining ----------------------------------------------- */

typedef struct {
  int fd;
  char peer[TS_NET_ADDR_LEN];
  struct sockaddr_storage addr;
} accepted;

static void *serve_thread(void *arg) {
  accepted a = *(accepted *)arg;
  free(arg);
  serve(a.fd, a.peer, (const struct sockaddr *)&a.addr);
  return NULL;
}

/* A join address is retried for ever, so a malformed one is refused at
 * start instead of in the retry loop's log. */
static int check_join(const char *addr, char *err) {
  char host[TS_NET_ADDR_LEN];
  int port;
  int rc = ts_net_split(addr, host, sizeof(host), &port, err);
  if (rc != 0) return rc;
  if (host[0] == '\0' || port == 0)
    return ts_error(err, TS_EINVAL, "needs the coordinator's host and port (1..65535), e.g. coord:7070");
  return 0;
}

static void *join_thread(void *arg) {
  const char *addr = arg;
  double backoff = 0.2;
  while (!atomic_load(&g_stop)) {
    char err[TS_ERR_LEN];
    int fd;
    if (ts_net_connect(addr, 2000, &fd, err) == 0) {
      /* A refused handshake backs off like a failed connect. */
      if (ts_connset_add(&g_w.conns, fd) != 0) close(fd);
      else if (serve(fd, addr, NULL) == 0) backoff = 0.2;
    } else {
      ts_log("join %s: %s; retrying in %.1fs", addr, err, backoff);
    }
    for (double t = 0; t < backoff && !atomic_load(&g_stop); t += 0.05) usleep(50000);
    backoff = backoff * 2 > 5.0 ? 5.0 : backoff * 2;
  }
  return NULL;
}

static void usage(FILE *f) {
  fprintf(f,
          "usage: texsyn-worker (--listen ADDR:PORT | --join HOST:PORT) [options]\n"
          "\n"
          "Holds slices of reference vector sets for a texsyn-server and scans them for its\n"
          "query batches with SIMD L1 kernels on all its threads.\n"
          "\n"
          "  --listen ADDR:PORT   wait for the coordinator here (give the address to\n"
          "                       texsyn-server --workers); port 0 picks a free port\n"
          "  --join HOST:PORT     connect to the coordinator and announce this worker;\n"
          "                       reconnects with backoff (0.2 s doubling to 5 s) when lost\n"
          "  --threads N          scan threads, 1..1024 (default: online CPUs, %ld here)\n"
          "  --max-frame BYTES    largest frame payload taken, >= %u (default %u);\n"
          "                       larger messages come in pieces\n"
          "  --max-message BYTES  largest message taken in pieces (default %llu)\n"
          "  --max-replica-memory BYTES\n"
          "                       query images every coordinator's messages may make this\n"
          "                       worker hold, checked before allocating, e.g. 4G\n"
          "                       (default: half the physical memory)\n"
          "  --name NAME          name shown in logs and to the coordinator\n"
          "  --secret-file PATH   this worker's key (a worker or admin key, or the shared\n"
          "                       secret; owner-only file): proved to the coordinator,\n"
          "                       which proves it back; without one a --listen worker\n"
          "                       accepts loopback peers only (protected mode)\n"
          "  --modbus [ADDR:]PORT serve the monitoring register map over Modbus TCP\n"
          "                       (off by default; PORT or :PORT listens on loopback,\n"
          "                       *:PORT on every interface)\n"
          "  --modbus-allow CIDR,...\n"
          "                       peers besides loopback that may connect to the Modbus\n"
          "                       plane (others are closed at accept): the coordinator's\n"
          "                       address, monitoring hosts\n"
          "  --modbus-control     accept coil writes (drain) on the Modbus plane; needs\n"
          "                       --modbus-allow (give 127.0.0.1 for loopback only)\n"
          "  --quiet              no log lines\n"
          "  --version            the texsyn release and wire protocol version\n"
          "\n"
          "TEXSYN_SIMD=scalar|mmx|sse2|avx2|avx512 forces a kernel variant.\n",
          sysconf(_SC_NPROCESSORS_ONLN), TS_FRAME_LIMIT_MIN, TS_FRAME_DEFAULT_MAX,
          (unsigned long long)TS_PIECES_DEFAULT_MAX);
}

static int parse_num(const char *opt, const char *s, long lo, long hi, long *out) {
  if (ts_parse_long(s, lo, hi, out) != 0) {
    fprintf(stderr, "texsyn-worker: %s %s: need a whole number in %ld..%ld\n", opt, s, lo, hi);
    return -1;
  }
  return 0;
}

/* Starts the Modbus plane; at gets HOST:PORT for the ready line. */
static int start_modbus(const char *arg, int control, const ts_mb_allow *allow, char *at, char *err) {
  char addr[TS_NET_ADDR_LEN], host[TS_NET_ADDR_LEN - 8];
  int port;
  int rc = ts_mb_listen_addr(arg, addr, sizeof(addr), host, sizeof(host), err);
  if (rc == 0) rc = ts_wmon_start_modbus(addr, control, allow->n > 0 ? allow : NULL, ts_warn_msg, &port, err);
  if (rc != 0) return rc;
  g_w.modbus_port = port;
  snprintf(at, TS_NET_ADDR_LEN, "%s:%d", host, port);
  ts_log("modbus plane on %s%s", at, control ? ", coil writes accepted" : "");
  return 0;
}

int main(int argc, char **argv) {
  enum { O_LISTEN = 256, O_JOIN, O_THREADS, O_FRAME, O_MESSAGE, O_REPLICA, O_NAME, O_SECRET, O_MODBUS, O_MB_ALLOW, O_MB_CONTROL, O_QUIET, O_HELP, O_VERSION };
  static const struct option longopts[] = {
      {"listen", required_argument, 0, O_LISTEN}, {"join", required_argument, 0, O_JOIN},
      {"threads", required_argument, 0, O_THREADS}, {"max-frame", required_argument, 0, O_FRAME},
      {"max-message", required_argument, 0, O_MESSAGE}, {"max-replica-memory", required_argument, 0, O_REPLICA},
      {"name", required_argument, 0, O_NAME}, {"secret-file", required_argument, 0, O_SECRET},
      {"modbus", required_argument, 0, O_MODBUS}, {"modbus-control", no_argument, 0, O_MB_CONTROL},
      {"modbus-allow", required_argument, 0, O_MB_ALLOW}, {"quiet", no_argument, 0, O_QUIET},
      {"help", no_argument, 0, O_HELP}, {"version", no_argument, 0, O_VERSION}, {0, 0, 0, 0}};
  const char *listen_addr = NULL, *join_addr = NULL, *secret_file = NULL, *modbus_addr = NULL;
  int modbus_control = 0, quiet = 0;
  ts_mb_allow modbus_allow = {0};
  char err[TS_ERR_LEN];
  long v;
  g_w.threads = (int)sysconf(_SC_NPROCESSORS_ONLN);
  if (g_w.threads < 1) g_w.threads = 1;
  g_w.max_frame = TS_FRAME_DEFAULT_MAX;
  g_w.max_message = TS_PIECES_DEFAULT_MAX;
  g_w.name = "";
  g_w.max_replica = (uint64_t)sysconf(_SC_PHYS_PAGES) * (uint64_t)sysconf(_SC_PAGE_SIZE) / 2;
  opterr = 0;
  int c;
  while ((c = getopt_long(argc, argv, "h", longopts, NULL)) != -1) {
    switch (c) {
    case O_LISTEN: listen_addr = optarg; break;
    case O_JOIN: join_addr = optarg; break;
    case O_THREADS: if (parse_num("--threads", optarg, 1, 1024, &v) != 0) return 2; g_w.threads = (int)v; break;
    case O_FRAME: if (parse_num("--max-frame", optarg, TS_FRAME_LIMIT_MIN, 0xFFFFFFFFL, &v) != 0) return 2; g_w.max_frame = (uint32_t)v; break;
    case O_MESSAGE: if (parse_num("--max-message", optarg, TS_FRAME_LIMIT_MIN, 0xFFFFFFFFL, &v) != 0) return 2; g_w.max_message = (uint64_t)v; break;
    case O_REPLICA:
      if (ts_parse_bytes(optarg, &g_w.max_replica) != 0 || g_w.max_replica == 0) {
        fprintf(stderr, "texsyn-worker: --max-replica-memory %s: need a byte count above 0 such as 512M or 4G\n",
                optarg);
        return 2;
      }
      break;
    case O_NAME: g_w.name = optarg; break;
    case O_SECRET: secret_file = optarg; break;
    case O_MODBUS: modbus_addr = optarg; break;
    case O_MB_CONTROL: modbus_control = 1; break;
    case O_MB_ALLOW:
      if (ts_mb_allow_parse(optarg, &modbus_allow, err) != 0) {
        fprintf(stderr, "texsyn-worker: %s\n", err);
        return 2;
      }
      break;
    case O_QUIET: quiet = 1; break;
    case O_HELP: case 'h': usage(stdout); return 0;
    case O_VERSION: ts_version_print("texsyn-worker"); return 0;
    default:
      fprintf(stderr, "texsyn-worker: %s: unknown option or missing value (see --help)\n", argv[optind - 1]);
      return 2;
    }
  }
  if (optind < argc || (listen_addr == NULL && join_addr == NULL)) {
    fprintf(stderr, "texsyn-worker: give --listen ADDR:PORT and/or --join HOST:PORT (see --help)\n");
    return 2;
  }
  if (modbus_control && modbus_allow.n == 0) {
    fprintf(stderr, "texsyn-worker: --modbus-control needs --modbus-allow CIDR,... naming who may write coils "
                    "(--modbus-allow 127.0.0.1 for loopback only): Modbus TCP carries no password\n");
    return 2;
  }
  ts_log_init("texsyn-worker", stderr, quiet);
  if (join_addr != NULL && check_join(join_addr, err) != 0) {
    fprintf(stderr, "texsyn-worker: --join %s: %s\n", join_addr, err);
    return 2;
  }
  if (ts_auth_init(err) != 0 || (secret_file != NULL && ts_auth_load(&g_w.auth, secret_file, err) != 0)) {
    fprintf(stderr, "texsyn-worker: %s\n", err);
    return 2;
  }
  if (g_w.auth.enabled && !ts_auth_kind_allows(g_w.auth.who.kind, TS_ROLE_WORKER)) {
    fprintf(stderr, "texsyn-worker: --secret-file %s is a %s key; a worker needs a worker key (texsyn-server "
            "--gen-secret worker PATH) or an admin key\n", secret_file, ts_auth_kind_name(g_w.auth.who.kind));
    return 2;
  }
  if (ts_l1_select(&g_w.simd, err) != 0) {
    fprintf(stderr, "texsyn-worker: %s\n", err);
    return 2;
  }
  if (ts_pool_create(&g_w.pool, g_w.threads) != 0) {
    fprintf(stderr, "texsyn-worker: cannot start %d scan threads\n", g_w.threads);
    return 1;
  }
  pthread_mutex_init(&g_w.pool_lock, NULL);
  ts_wmon_init(g_w.threads, g_w.simd->id);
  char modbus_at[TS_NET_ADDR_LEN] = "";
  if (modbus_addr != NULL && start_modbus(modbus_addr, modbus_control, &modbus_allow, modbus_at, err) != 0) {
    fprintf(stderr, "texsyn-worker: --modbus %s: %s\n", modbus_addr, err);
    return 1;
  }
  ts_connset_init(&g_w.conns);
  ts_gate_init(&g_w.gate, "worker port", ts_warn_msg);
  ts_stop_on_signals(&g_stop);
  signal(SIGPIPE, SIG_IGN);
  int lfd = -1;
  if (listen_addr != NULL) {
    int port, given;
    char host[TS_NET_ADDR_LEN];
    if (ts_net_split(listen_addr, host, sizeof(host), &given, err) != 0 ||
        ts_net_listen(listen_addr, &lfd, &port, err) != 0) {
      fprintf(stderr, "texsyn-worker: %s\n", err);
      return 1;
    }
    ts_stop_listener(lfd);
    ts_log("listening on %s:%d, %d threads, %s kernels, %s", host, port, g_w.threads, g_w.simd->name,
         g_w.auth.enabled ? "peers must prove the shared secret" : "no secret: loopback peers only");
    if (ts_auth_listen_warning(&g_w.auth, lfd, err)) ts_warn("%s", err);
    printf("texsyn-worker listening on %s:%d%s%s%s\n", host, port, modbus_at[0] ? " (modbus " : "", modbus_at,
           modbus_at[0] ? ")" : ""); /* last: the log is written */
    fflush(stdout);
  } else if (modbus_at[0]) {
    printf("texsyn-worker modbus on %s\n", modbus_at);
    fflush(stdout);
  }
  pthread_t joiner;
  int joining = join_addr != NULL && pthread_create(&joiner, NULL, join_thread, (void *)join_addr) == 0;
  while (!atomic_load(&g_stop)) {
    if (lfd < 0) {
      usleep(100000);
      continue;
    }
    accepted *a = malloc(sizeof(*a));
    if (a == NULL || ts_gate_accept(&g_w.gate, lfd, &a->fd, a->peer, sizeof(a->peer), &a->addr) != 0) {
      free(a);
      continue;
    }
    pthread_t t;
    int added = ts_connset_add(&g_w.conns, a->fd) == 0;
    if (added) ts_gate_enter(&g_w.gate, a->fd, (const struct sockaddr *)&a->addr);
    if (!added || pthread_create(&t, NULL, serve_thread, a) != 0) {
      if (added) ts_gate_leave(&g_w.gate, a->fd);
      ts_connset_remove(&g_w.conns, a->fd);
      close(a->fd);
      free(a);
      continue;
    }
    pthread_detach(t);
  }
  ts_log("shutting down");
  ts_stop_listener(-1); /* a second signal must not shut a reused fd number */
  if (lfd >= 0) close(lfd);
  ts_connset_close_all(&g_w.conns);
  if (joining) pthread_join(joiner, NULL);
  ts_connset_close_all(&g_w.conns);
  ts_wmon_stop_modbus();
  ts_pool_destroy(g_w.pool);
  ts_auth_clear(&g_w.auth);
  return 0;
}
