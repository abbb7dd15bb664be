/* cluster.c - see cluster.h: the pool of workers - joining, calibration,
 * heartbeats, failures - and the exchanges every request to the workers
 * goes through. The Modbus supervision is in supervise.c, the search
 * backend over the pool in search_cluster.c and the files search_state.h
 * lists; cluster_impl.h says how they share the lock. */
#include <errno.h>
#include <math.h>
#include <poll.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "calib.h"
#include "cluster_impl.h"
#include "error.h"


void ts_cluster_opts_default(ts_cluster_opts *o) {
  o->calib_millis = 200;
  o->tolerance = 0.25;
  o->persist = 3.0;
  o->batch_timeout = 2.0;
  o->max_redispatch = 5;
  o->modbus_poll = 1.0;
  o->rebalance_from = TS_REBALANCE_BATCHES | TS_REBALANCE_MODBUS;
  o->local_threads = 2;
  o->max_frame = TS_FRAME_DEFAULT_MAX;
  o->pipeline_queries = 256;
  o->heartbeat = 2.0;
  o->auth = NULL;
  o->max_workers = 256;
}

/* ---- a worker's outgoing messages -------------------------------------- */

int cl_worker_takes(const cl_worker *w, uint64_t bytes) {
  return bytes <= w->max_payload || (w->pieces && bytes <= w->max_message);
}

/* The next free entry of w's queue (not queued yet), or NULL. */
static cl_msg *queue_slot(cl_worker *w) {
  if (w->nqueue == w->cap_queue) {
    uint32_t cap = w->cap_queue ? 2 * w->cap_queue : 16;
    cl_msg *q = realloc(w->queue, sizeof(*q) * cap);
    if (q == NULL) return NULL;
    w->queue = q;
    w->cap_queue = cap;
  }
  return &w->queue[w->nqueue];
}

/* ---- a worker's requests outstanding ----------------------------------- */

static cl_request *req_at(const cl_worker *w, uint32_t k) { return &w->reqs[(w->req_head + k) % w->cap_reqs]; }

/* Appends a request to w's ring; NULL when out of memory. */
static cl_request *req_push(cl_worker *w) {
  if (w->nreqs == w->cap_reqs) {
    uint32_t cap = w->cap_reqs ? 2 * w->cap_reqs : 64;
    cl_request *r = malloc(sizeof(*r) * cap);
    if (r == NULL) return NULL;
    for (uint32_t k = 0; k < w->nreqs; k++) r[k] = *req_at(w, k);
    free(w->reqs);
    w->reqs = r;
    w->cap_reqs = cap;
    w->req_head = 0;
  }
  return req_at(w, w->nreqs++);
}

static void req_pop(cl_worker *w) {
  w->req_head = (w->req_head + 1) % w->cap_reqs;
  w->nreqs--;
}

/* The request with frame id `id` among the newest ones, or NULL. */
static cl_request *req_by_id(cl_worker *w, uint32_t id) {
  for (uint32_t k = w->nreqs; k-- > 0;)
    if (req_at(w, k)->id == id) return req_at(w, k);
  return NULL;
}

/* Matches a frame w sent to the oldest request outstanding on its
 * connection (which it then leaves): 0 and *rq, or TS_EPROTO naming what
 * is wrong. */
static int req_match(cl_worker *w, const ts_frame *f, cl_request *rq, char *err) {
  /* An 'E' of id 0 answers no request: the worker ends the connection and
   * says why (a sealed frame it refused, say). Its reason is the one to log. */
  if (f->type == TS_MSG_ERROR && f->id == 0) {
    int rc = cl_reply_error(f, err);
    return rc < 0 ? rc : ts_error(err, TS_EPROTO, "protocol: an 'E' frame id 0 of code %d", rc);
  }
  if (w->nreqs == 0)
    return ts_error(err, TS_EPROTO, "protocol: unsolicited '%c' frame id %u (no request outstanding)", f->type, f->id);
  const cl_request *r = req_at(w, 0);
  if (f->id != r->id || (f->type != r->type && f->type != TS_MSG_ERROR))
    return ts_error(err, TS_EPROTO,
                    "protocol: '%c' frame id %u does not answer the oldest request outstanding ('%c' frame id %u)",
                    f->type, f->id, r->type, r->id);
  if (w->sent < r->end)
    return ts_error(err, TS_EPROTO, "protocol: '%c' frame id %u answers a request not sent whole yet", f->type, f->id);
  *rq = *r;
  req_pop(w);
  return 0;
}

/* Queues the message whose arguments fill slot e, if w can take it, as
 * the next request on w's connection. */
static int queue_push(cl_worker *w, cl_msg *e, uint8_t type, uint32_t tag, ts_payload_fn *fn, char *err) {
  if (w->next_id == UINT32_MAX) /* never reuse an id on a connection: a new one starts at 1 */
    return ts_error(err, TS_ELIMIT, "2^32 requests on one connection: it is dialled again");
  e->write = fn;
  int rc = ts_outmsg_init(&e->m, type, w->next_id, fn, &e->arg, w->max_payload, w->pieces, err);
  if (rc == 0 && !cl_worker_takes(w, e->m.total))
    rc = ts_error(err, TS_ETOOBIG, "a '%c' message of %llu bytes is over what the worker takes (%llu bytes%s)",
                  type, (unsigned long long)e->m.total,
                  (unsigned long long)(w->pieces ? w->max_message : w->max_payload),
                  w->pieces ? ", texsyn-worker --max-message" : " in one frame; it is too old to take pieces");
  cl_request *r = rc == 0 ? req_push(w) : NULL;
  if (rc == 0 && r == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory for a request to a worker");
  if (rc != 0) return rc;
  *r = (cl_request){w->next_id++, type, 0, tag, UINT64_MAX};
  w->nqueue++;
  w->expect++;
  return 0;
}

#define NO_SLOT(err) ts_error(err, TS_ENOMEM, "out of memory for a message to a worker")

static void write_slice(ts_wr *w, const void *arg) { ts_msg_slice_write(w, arg); }

int cl_queue_slice(cl_worker *w, uint32_t tag, const ts_slice_desc *m, char *err) {
  cl_msg *e = queue_slot(w);
  if (e == NULL) return NO_SLOT(err);
  e->arg.slice = *m;
  return queue_push(w, e, TS_MSG_SLICE, tag, write_slice, err);
}

uint64_t cl_slice_bytes(const ts_slice_desc *m) { return ts_payload_size(write_slice, m); }

static void write_query(ts_wr *w, const void *arg) {
  const cl_query_frame *q = arg;
  ts_msg_query_write(w, q->set, q->gen, q->image, q->seq, q->place, q->nplace, q->b, q->q0, q->q1);
}

int cl_queue_query(cl_worker *w, uint32_t tag, const cl_query_frame *q, char *err) {
  cl_msg *e = queue_slot(w);
  if (e == NULL) return NO_SLOT(err);
  e->arg.query = *q;
  return queue_push(w, e, TS_MSG_QUERY, tag, write_query, err);
}

static void write_image(ts_wr *w, const void *arg) { ts_msg_image_write(w, arg); }

int cl_queue_image(cl_worker *w, uint32_t tag, const ts_msg_image *m, char *err) {
  cl_msg *e = queue_slot(w);
  if (e == NULL) return NO_SLOT(err);
  e->arg.image = *m;
  return queue_push(w, e, TS_MSG_IMAGE, tag, write_image, err);
}

static void write_field(ts_wr *w, const void *arg) { ts_msg_field_write(w, arg); }

int cl_queue_field(cl_worker *w, uint32_t tag, const ts_msg_field *m, char *err) {
  cl_msg *e = queue_slot(w);
  if (e == NULL) return NO_SLOT(err);
  e->arg.field = *m;
  return queue_push(w, e, TS_MSG_FIELD, tag, write_field, err);
}

static void write_pass(ts_wr *w, const void *arg) { ts_msg_pass_write(w, arg); }

int cl_queue_pass(cl_worker *w, uint32_t tag, const ts_msg_pass *m, char *err) {
  cl_msg *e = queue_slot(w);
  if (e == NULL) return NO_SLOT(err);
  e->arg.pass = *m;
  return queue_push(w, e, TS_MSG_PASS, tag, write_pass, err);
}

uint64_t cl_image_bytes(const ts_msg_image *m) { return ts_payload_size(write_image, m); }

static void write_unload(ts_wr *w, const void *arg) { ts_msg_unload_write(w, arg); }

/* Queues a 'Q' to w (leased); a worker it cannot be queued to is failed. */
static void cl_queue_unload(ts_cluster *c, cl_worker *w, uint32_t set) {
  char err[TS_ERR_LEN] = "out of memory for a message to a worker";
  cl_msg *e = queue_slot(w);
  if (e != NULL) e->arg.unload.set = set;
  w->unloads++; /* a re-slice keeps nothing from a slice it may have freed */
  if (set == TS_UNLOAD_ALL) w->wipes++;
  if (e == NULL || queue_push(w, e, TS_MSG_UNLOAD, set, write_unload, err) != 0) cl_worker_fail(c, w, err);
}

void cl_queue_heartbeat(ts_cluster *c, cl_worker *w) {
  char err[TS_ERR_LEN] = "out of memory for a message to a worker";
  cl_msg *e = queue_slot(w);
  if (e == NULL || queue_push(w, e, TS_MSG_HEARTBEAT, 0, NULL, err) != 0) cl_worker_fail(c, w, err);
}

void cl_out_reset(cl_worker *w) {
  w->nqueue = w->qhead = 0;
  w->sent += w->out.len - w->out_off; /* dropped unsent: nothing waits on it */
  w->out.len = w->out_off = 0;
  w->expect = 0;
  while (w->nreqs > 0 && !req_at(w, w->nreqs - 1)->abandoned) w->nreqs--;
}

/* Produces w's queued messages into its output buffer until CL_OUT_HIGH
 * bytes wait unsent there or nothing is left to produce. */
static int fill_out(cl_worker *w, char *err) {
  if (w->qhead == w->nqueue || w->out.len - w->out_off >= CL_OUT_HIGH) return 0;
  if (w->out_off > 0) { /* what was sent makes room: the unsent rest (< CL_OUT_HIGH) moves to the front */
    memmove(w->out.buf, w->out.buf + w->out_off, w->out.len - w->out_off);
    w->out.len -= w->out_off;
    w->out_off = 0;
  }
  while (w->qhead < w->nqueue && w->out.len < CL_OUT_HIGH) {
    cl_msg *e = &w->queue[w->qhead];
    size_t len0 = w->out.len;
    /* A sealed connection's bytes are produced plain, then sealed. */
    ts_wr *to = w->conn.seal != NULL ? &w->plain : &w->out;
    w->plain.len = 0;
    int rc = ts_outmsg_produce(&e->m, e->write, &e->arg, to, CL_OUT_CHUNK, err);
    if (rc >= 0 && to == &w->plain) {
      int sr = ts_conn_wrap(&w->conn, &w->out, w->plain.buf, w->plain.len, err);
      if (sr < 0) rc = sr;
    }
    if (rc < 0) return rc;
    w->produced += w->out.len - len0;
    if (rc == 1) {
      cl_request *r = req_by_id(w, e->m.id);
      if (r != NULL) r->end = w->produced;
      w->qhead++;
    }
  }
  return 0;
}

/* ---- workers ----------------------------------------------------------- */

static void worker_free(cl_worker *w) {
  ts_conn_close(&w->conn);
  ts_wr_free(&w->out);
  ts_wr_free(&w->plain);
  free(w->queue);
  free(w->frames);
  free(w->reqs);
  free(w);
}

/* Marks a worker failed (under the lock): it leaves every slicing. */
void cl_worker_fail(ts_cluster *c, cl_worker *w, const char *why) {
  if (w->state == TS_WORKER_FAILED) return;
  cl_log(c, "worker %d (%s) dropped: %s", w->id, w->conn.peer, why);
  w->state = TS_WORKER_FAILED;
  w->died_ms = ts_clock_ms();
  shutdown(w->conn.fd, SHUT_RDWR);
  c->epoch++;
}

/* The worker's --name: its identity's words after the software and the
 * version (PROTOCOL.md, 'I'); "" without one. */
static void worker_name(const cl_worker *w, char *out, size_t cap) {
  const char *p = w->ident.name;
  for (int word = 0; word < 2 && p != NULL; word++) {
    p = strchr(p, ' ');
    if (p != NULL) p++;
  }
  snprintf(out, cap, "%s", p != NULL ? p : "");
}

/* What `texsyn workers` shows of a worker (lock held): a draining or
 * failed one holds no slice, whatever its last share was. */
static void worker_info(const cl_worker *w, ts_worker_info *o) {
  memset(o, 0, sizeof(*o));
  snprintf(o->addr, sizeof(o->addr), "%s", w->conn.peer);
  worker_name(w, o->name, sizeof(o->name));
  o->threads = w->ident.threads;
  o->simd = w->ident.simd;
  o->state = (uint8_t)w->state;
  o->calibrated = (uint64_t)w->calib_rate;
  o->rate = (uint64_t)w->slice_rate;
  o->share = w->state == TS_WORKER_READY ? (uint16_t)w->share : 0;
  o->batches = w->batches;
  o->died_ms = w->state == TS_WORKER_FAILED ? w->died_ms : 0;
}

/* Drops the dead workers' records that are CL_DEAD_KEEP_MS old, and
 * (name or addr non-NULL) those a joining worker of that name or address
 * replaces (lock held). */
static void forget_dead(ts_cluster *c, const char *name, const char *addr) {
  uint64_t now = ts_clock_ms();
  int k = 0;
  for (int i = 0; i < c->ndead; i++) {
    const ts_worker_info *d = &c->dead[i];
    int same = (name != NULL && name[0] != '\0' && strcmp(d->name, name) == 0) ||
               (addr != NULL && strcmp(d->addr, addr) == 0);
    if (!same && now - d->died_ms < CL_DEAD_KEEP_MS) c->dead[k++] = *d;
  }
  c->ndead = k;
}

/* Keeps a failed worker's record as it leaves the list (lock held); the
 * oldest goes when every slot is taken. */
static void mourn(ts_cluster *c, const cl_worker *w) {
  if (c->ndead == (int)c->o.max_workers) memmove(c->dead, c->dead + 1, sizeof(*c->dead) * (size_t)--c->ndead);
  worker_info(w, &c->dead[c->ndead++]);
}

/* Removes failed workers from the list (under the lock, outside exchanges). */
static void reap_failed(ts_cluster *c) {
  int k = 0;
  for (int i = 0; i < c->nw; i++) {
    if (c->w[i]->state != TS_WORKER_FAILED || c->w[i]->refs > 0) {
      c->w[k++] = c->w[i];
      continue;
    }
    for (int a = 0; a < c->naddrs; a++)
      if (c->addrs[a].worker_id == c->w[i]->id) c->addrs[a].worker_id = 0;
    mourn(c, c->w[i]);
    worker_free(c->w[i]);
  }
  c->nw = k;
  forget_dead(c, NULL, NULL);
}

static int send_frame(ts_conn *conn, uint8_t type, uint32_t id, const ts_wr *w, char *err) {
  if (ts_wr_status(w) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
  return ts_conn_send(conn, type, id, w->buf, w->len, err);
}

/* Waits for the reply of the given type to request `id` (no lock held). */
static int await_reply(ts_conn *conn, uint8_t type, uint32_t id, int timeout_ms, ts_frame *f, char *err) {
  int rc = ts_conn_recv(conn, f, timeout_ms, err);
  if (rc < 0) return rc;
  if (f->id != id && !(f->type == TS_MSG_ERROR && f->id == 0)) /* id 0: why the worker ends the connection */
    return ts_error(err, TS_EPROTO, "%s: protocol: '%c' frame id %u answers no request (awaiting '%c' frame id %u)",
                    conn->peer, f->type, f->id, type, id);
  if (f->type == TS_MSG_ERROR) {
    ts_msg_error e;
    if (ts_msg_error_read(f, &e, err) != 0) return TS_EPROTO;
    return ts_error(err, e.code, "%s: %s", conn->peer, e.text);
  }
  if (f->type != type) return ts_error(err, TS_EPROTO, "%s: expected '%c', got '%c'", conn->peer, type, f->type);
  return 0;
}

/* Says why to a worker the pool refuses, so its log tells its operator. */
static void tell_refused(cl_worker *w, const char *why) {
  ts_wr wr;
  ts_wr_init(&wr);
  ts_msg_error_write(&wr, TS_ELIMIT, why);
  char err[TS_ERR_LEN];
  send_frame(&w->conn, TS_MSG_ERROR, 0, &wr, err);
  ts_wr_free(&wr);
}

/* TS_ELIMIT when every slot of the pool is taken (lock held). */
static int pool_full(const ts_cluster *c, char *err) {
  if (c->nw + c->admitting < (int)c->o.max_workers) return 0;
  return ts_error(err, TS_ELIMIT, "the pool is full (%u workers, texsyn-server --max-workers)", c->o.max_workers);
}

cl_worker **cl_worker_list(const ts_cluster *c) { return malloc(sizeof(cl_worker *) * c->o.max_workers); }

static int calibrate(ts_cluster *c, cl_worker *w, char *err) {
  ts_wr wr;
  ts_wr_init(&wr);
  ts_msg_calib_req req = {c->o.calib_millis};
  ts_msg_calib_req_write(&wr, &req);
  int rc = send_frame(&w->conn, TS_MSG_CALIBRATE, 1, &wr, err);
  ts_wr_free(&wr);
  ts_frame f;
  ts_msg_calib cal;
  if (rc == 0) rc = await_reply(&w->conn, TS_MSG_CALIBRATE, 1, (int)c->o.calib_millis * 10 + 5000, &f, err);
  if (rc == 0) rc = ts_msg_calib_read(&f, &cal, err);
  if (rc != 0) return rc;
  /* A worker that says nothing of its limits is an older one: the default
   * frame limit, and no pieces. */
  w->pieces = (w->ident.caps & TS_CAP_PIECES) && cal.max_payload != 0;
  w->max_payload = cal.max_payload != 0 ? cal.max_payload : TS_FRAME_DEFAULT_MAX;
  w->max_message = w->pieces ? cal.max_message : w->max_payload;
  w->calib_rate = ts_calib_bytes_per_second(cal.pairs, cal.nanos);
  w->slice_rate = w->ewma_rate = w->calib_rate;
  return 0;
}

/* Calibrates an identified worker and adds it to the pool; takes conn. */
static int admit(ts_cluster *c, ts_conn *conn, const ts_msg_ident *ident, int addr_slot, char *err) {
  cl_worker *w = calloc(1, sizeof(*w));
  if (w == NULL) {
    ts_conn_close(conn);
    return ts_error(err, TS_ENOMEM, "out of memory");
  }
  w->conn = *conn;
  w->ident = *ident;
  w->cpu_share = w->share_sized = -1;
  w->state = TS_WORKER_CALIBRATING;
  w->next_id = 2; /* 1 is the calibration's */
  ts_wr_init(&w->out);
  ts_wr_init(&w->plain);
  /* A slot first: a full pool refuses before spending a calibration. */
  pthread_mutex_lock(&c->lock);
  int rc = pool_full(c, err);
  if (rc == 0) c->admitting++;
  pthread_mutex_unlock(&c->lock);
  if (rc == 0) rc = calibrate(c, w, err);
  pthread_mutex_lock(&c->lock);
  if (rc != TS_ELIMIT) c->admitting--;
  if (rc == 0) {
    w->id = ++c->next_worker_id;
    w->state = TS_WORKER_READY;
    w->heard_at = ts_now();
    c->w[c->nw++] = w;
    char name[TS_MSG_NAME_MAX];
    worker_name(w, name, sizeof(name));
    forget_dead(c, name, w->conn.peer); /* back: no longer listed as dead */
    if (addr_slot >= 0) c->addrs[addr_slot].worker_id = w->id;
    c->epoch++;
    cl_log(c, "worker %d (%s, %u threads, %s) ready: scans %.3g bytes/s", w->id, w->conn.peer,
         (unsigned)ident->threads, ident->simd < TS_SIMD_COUNT ? ts_l1_impl_get((ts_simd)ident->simd) ? ts_l1_impl_get((ts_simd)ident->simd)->name : "?" : "?",
         w->calib_rate);
  }
  pthread_mutex_unlock(&c->lock);
  if (rc == TS_ELIMIT) tell_refused(w, err);
  if (rc != 0) worker_free(w);
  return rc;
}

static void ident_self(ts_msg_ident *m) {
  memset(m, 0, sizeof(*m));
  m->role = TS_ROLE_COORD;
  m->caps = TS_CAP_ALL | TS_CAP_PIECES;
  snprintf(m->name, sizeof(m->name), "texsyn-server 0.3");
}

int ts_cluster_adopt(ts_cluster *c, ts_conn *conn, const ts_msg_ident *ident, char *err) {
  return admit(c, conn, ident, -1, err);
}

/* Connects to a listening worker, identifies and authenticates both ways
 * (no lock). */
static int dial(ts_cluster *c, const char *addr, ts_conn *conn, ts_msg_ident *ident, char *err) {
  int fd;
  int rc = ts_net_connect(addr, 2000, &fd, err);
  if (rc != 0) return rc;
  ts_conn_init(conn, fd, c->o.max_frame, addr);
  ts_msg_ident me;
  ident_self(&me);
  rc = ts_auth_connect(conn, c->o.auth, &me, ident, 5000, err);
  if (rc == 0 && ident->role != TS_ROLE_WORKER) rc = ts_error(err, TS_EPROTO, "%s is not a texsyn worker", addr);
  if (rc != 0) ts_conn_close(conn);
  return rc;
}


/* Pings the workers that have been silent for a heartbeat interval, so a
 * worker that died or hung between jobs leaves the pool (and is dialled
 * again) before the next batch waits on it (lock held). */
static void heartbeat_idle(ts_cluster *c) {
  cl_worker **ws = c->o.heartbeat > 0 ? cl_worker_list(c) : NULL;
  if (ws == NULL) return;
  int n = 0;
  double now = ts_now();
  for (int i = 0; i < c->nw; i++) {
    cl_worker *w = c->w[i];
    if ((w->state != TS_WORKER_READY && w->state != TS_WORKER_DRAINING) || w->busy ||
        now - w->heard_at < c->o.heartbeat)
      continue;
    ws[n++] = w;
  }
  cl_lease(c, ws, n); /* none is leased: no wait */
  for (int i = 0; i < n; i++) cl_queue_heartbeat(c, ws[i]);
  cl_traffic tr = {0, 0};
  if (n > 0) cl_exchange(c, ws, n, 2 * c->o.heartbeat + 1.0, NULL, 0, NULL, NULL, &tr);
  cl_release(c, ws, n);
  free(ws);
}

/* The cluster's thread: (re)connects configured addresses, pings idle
 * workers, reaps failed ones. */
static void *cluster_thread(void *arg) {
  ts_cluster *c = arg;
  pthread_mutex_lock(&c->lock);
  while (!c->stop) {
    heartbeat_idle(c);
    reap_failed(c);
    for (int a = 0; a < c->naddrs && !c->stop; a++) {
      if (c->addrs[a].worker_id != 0) continue;
      char addr[TS_NET_ADDR_LEN], err[TS_ERR_LEN];
      if (pool_full(c, err) != 0) {
        /* Dial nobody: a worker could only be refused, after its calibration. */
        if (!c->addrs[a].failing) cl_log(c, "worker %s: %s; not dialled while it is", c->addrs[a].addr, err);
        c->addrs[a].failing = 1;
        continue;
      }
      snprintf(addr, sizeof(addr), "%s", c->addrs[a].addr);
      c->addrs[a].worker_id = -1; /* being dialled */
      pthread_mutex_unlock(&c->lock);
      ts_conn conn;
      ts_msg_ident ident;
      int rc = dial(c, addr, &conn, &ident, err);
      if (rc == 0) rc = admit(c, &conn, &ident, a, err);
      pthread_mutex_lock(&c->lock);
      if (rc != 0) {
        c->addrs[a].worker_id = 0;
        /* A dead worker's address is dialled every 0.5 s: say so once. */
        if (!c->addrs[a].failing) cl_log(c, "worker %s: %s (dialling it again every 0.5 s)", addr, err);
        c->addrs[a].failing = 1;
      } else {
        c->addrs[a].failing = 0;
      }
    }
    struct timespec ts = ts_wait_until(0.5);
    pthread_cond_timedwait(&c->wake, &c->lock, &ts);
  }
  pthread_mutex_unlock(&c->lock);
  return NULL;
}


static void cluster_free(ts_cluster *c) {
  ts_pool_destroy(c->local_pool);
  for (int i = 0; i < CL_MAX_SOURCES; i++) free(c->sources[i].held);
  free(c->w);
  free(c->dead);
  free(c->addrs);
  free(c);
}

int ts_cluster_create(ts_cluster **out, const ts_cluster_opts *o, char *err) {
  *out = NULL;
  if (o->max_workers < 1 || o->max_workers > TS_CLUSTER_MAX_WORKERS)
    return ts_error(err, TS_EINVAL, "--max-workers %u: need 1..%d", o->max_workers, TS_CLUSTER_MAX_WORKERS);
  ts_cluster *c = calloc(1, sizeof(*c));
  if (c == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  c->o = *o;
  c->w = calloc(o->max_workers, sizeof(*c->w));
  c->addrs = calloc(TS_CLUSTER_MAX_WORKERS, sizeof(*c->addrs));
  c->dead = calloc(o->max_workers, sizeof(*c->dead));
  int ok = c->w != NULL && c->addrs != NULL && c->dead != NULL;
  for (int i = 0; ok && i < CL_MAX_SOURCES; i++) ok = (c->sources[i].held = calloc(o->max_workers, sizeof(cl_holder))) != NULL;
  int rc = ok ? ts_l1_select(&c->simd, err) : ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0 && ts_pool_create(&c->local_pool, o->local_threads) != 0)
    rc = ts_error(err, TS_ENOMEM, "cannot start %d scan threads", o->local_threads);
  if (rc != 0) {
    cluster_free(c);
    return rc;
  }
  pthread_mutex_init(&c->lock, NULL);
  pthread_cond_init(&c->wake, NULL);
  pthread_cond_init(&c->released, NULL);
  if (pthread_create(&c->thread, NULL, cluster_thread, c) != 0) {
    cluster_free(c);
    return ts_error(err, TS_ENOMEM, "cannot start the cluster thread");
  }
  c->supervising = o->modbus_poll > 0 && pthread_create(&c->supervisor, NULL, cl_supervisor_thread, c) == 0;
  *out = c;
  return 0;
}

void ts_cluster_destroy(ts_cluster *c) {
  if (c == NULL) return;
  pthread_mutex_lock(&c->lock);
  c->stop = 1;
  pthread_cond_broadcast(&c->wake);
  pthread_mutex_unlock(&c->lock);
  pthread_join(c->thread, NULL);
  if (c->supervising) pthread_join(c->supervisor, NULL);
  for (int i = 0; i < c->nw; i++) worker_free(c->w[i]);
  pthread_mutex_destroy(&c->lock);
  pthread_cond_destroy(&c->wake);
  pthread_cond_destroy(&c->released);
  cluster_free(c);
}

int ts_cluster_add_address(ts_cluster *c, const char *addr, char *err) {
  char host[TS_NET_ADDR_LEN];
  int port;
  int rc = ts_net_split(addr, host, sizeof(host), &port, err);
  if (rc != 0) return rc;
  pthread_mutex_lock(&c->lock);
  if (c->naddrs == TS_CLUSTER_MAX_WORKERS)
    rc = ts_error(err, TS_ETOOBIG, "more than %d worker addresses", TS_CLUSTER_MAX_WORKERS);
  else snprintf(c->addrs[c->naddrs++].addr, TS_NET_ADDR_LEN, "%s", addr);
  pthread_cond_signal(&c->wake);
  pthread_mutex_unlock(&c->lock);
  return rc;
}

uint32_t ts_cluster_info(ts_cluster *c, ts_worker_info *out, uint32_t cap) {
  pthread_mutex_lock(&c->lock);
  uint32_t n = 0;
  forget_dead(c, NULL, NULL);
  for (int i = 0; i < c->nw && n < cap; i++) worker_info(c->w[i], &out[n++]);
  for (int i = 0; i < c->ndead && n < cap; i++) out[n++] = c->dead[i];
  pthread_mutex_unlock(&c->lock);
  return n;
}

int ts_cluster_ready(ts_cluster *c) {
  pthread_mutex_lock(&c->lock);
  int n = 0;
  for (int i = 0; i < c->nw; i++) n += c->w[i]->state == TS_WORKER_READY;
  pthread_mutex_unlock(&c->lock);
  return n;
}

uint64_t ts_cluster_rebalances(ts_cluster *c) {
  pthread_mutex_lock(&c->lock);
  uint64_t n = c->rebalances;
  pthread_mutex_unlock(&c->lock);
  return n;
}

void ts_cluster_stats_get(ts_cluster *c, ts_cluster_stats *out) {
  memset(out, 0, sizeof(*out));
  pthread_mutex_lock(&c->lock);
  for (int i = 0; i < c->nw; i++)
    if (c->w[i]->state == TS_WORKER_READY) {
      out->ready++;
      out->rate += (uint64_t)c->w[i]->slice_rate;
    }
  out->batches = c->batches;
  out->queries = c->queries;
  pthread_mutex_unlock(&c->lock);
}

int cl_ready_workers(ts_cluster *c, cl_worker **ws) {
  int n = 0;
  for (int i = 0; i < c->nw; i++)
    if (c->w[i]->state == TS_WORKER_READY) ws[n++] = c->w[i];
  return n;
}

/* ---- exchanges --------------------------------------------------------- */

/* Fails a worker from inside an exchange, where the lock is not held. */
static void fail_unlocked(ts_cluster *c, cl_worker *w, const char *why) {
  pthread_mutex_lock(&c->lock);
  cl_worker_fail(c, w, why);
  pthread_mutex_unlock(&c->lock);
}

/* One exchange's view of its workers: who is gone, each one's deadline. */
typedef struct {
  ts_cluster *c;
  cl_worker **ws;
  int n;
  char *gone;
  double *due;
  int failed, canceled;
  unsigned flags;
} xchg;

static void x_fail(xchg *x, int i, const char *why) {
  fail_unlocked(x->c, x->ws[i], why);
  x->gone[i] = 1;
  x->failed = 1;
}

/* The job was canceled: w's requests not begun are dropped (but with
 * CL_X_SEND_ALL), those under way are sent whole and their answers
 * abandoned, due by its deadline. */
static void x_abandon(xchg *x, int i) {
  cl_worker *w = x->ws[i];
  uint32_t begun = w->qhead + (w->qhead < w->nqueue && w->queue[w->qhead].m.done > 0);
  if (!(x->flags & CL_X_SEND_ALL)) {
    w->nreqs -= w->nqueue - begun; /* the newest requests: unsent */
    w->nqueue = begun;
  }
  for (uint32_t k = 0; k < w->nreqs; k++) req_at(w, k)->abandoned = 1;
  w->expect = 0;
  if (w->nreqs > 0) w->abandoned_due = fmax(w->abandoned_due, x->due[i]);
}

/* Every frame w has sent so far (no lock held): each must answer its
 * oldest request outstanding; the answers to this exchange's go to fn,
 * those to abandoned ones are dropped. Reads no further than w's deadline. */
static void x_read(xchg *x, int i, cl_reply_fn *fn, void *ctx, cl_traffic *tr) {
  cl_worker *w = x->ws[i];
  char err[TS_ERR_LEN];
  ts_frame f;
  cl_request rq;
  int rc;
  while (!x->gone[i] && ts_now() < x->due[i] && (rc = ts_conn_pump(&w->conn, &f, err)) != 0) {
    if (rc > 0) rc = req_match(w, &f, &rq, err);
    if (rc == 0 && rq.abandoned && f.type == TS_MSG_ERROR)
      cl_log(x->c, "worker %d (%s) refused a request of a canceled job ('%c' frame id %u)", w->id, w->conn.peer,
             rq.type, rq.id);
    if (rc == 0 && !rq.abandoned) {
      w->expect--;
      rc = fn != NULL ? fn(ctx, w, &f, &rq, err) : f.type == TS_MSG_ERROR ? cl_reply_error(&f, err) : 0;
    }
    if (rc < 0) {
      x_fail(x, i, err);
      return;
    }
    tr->bytes_in += TS_FRAME_HEADER + f.len;
    w->io_heard_at = ts_now();
  }
}

/* Sends what w's socket takes of its output. */
static void x_send(xchg *x, int i, cl_traffic *tr) {
  cl_worker *w = x->ws[i];
  ssize_t s = send(w->conn.fd, w->out.buf + w->out_off, w->out.len - w->out_off, MSG_DONTWAIT | MSG_NOSIGNAL);
  if (s > 0) {
    w->out_off += (size_t)s;
    w->sent += (uint64_t)s;
    tr->bytes_out += (uint64_t)s;
  } else if (s < 0 && errno != EAGAIN && errno != EINTR) {
    char err[TS_ERR_LEN];
    snprintf(err, sizeof(err), "send: %s", strerror(errno));
    x_fail(x, i, err);
  }
}

/* Whether worker i still has bytes to send or answers to await. */
static int x_pending(const xchg *x, int i) {
  const cl_worker *w = x->ws[i];
  return !x->gone[i] && (w->expect > 0 || w->out_off < w->out.len || w->qhead < w->nqueue);
}

/* Sends every leased worker's queued requests, produced as its socket
 * drains, and feeds each answer to fn until every request is answered. A
 * worker that fails (connection, protocol, fn's error, deadline) is marked
 * failed and the others carry on, so their streams stay in step. Each
 * worker's deadline is `timeout` from now, later by what its abandoned
 * requests may still take. Called with the lock held; bytes travel without
 * it. Whether a worker is gone is tracked here, not read from its state: a
 * failure seen elsewhere (Modbus, heartbeat) shuts its socket, which this
 * loop then sees. */
int cl_exchange(ts_cluster *c, cl_worker **ws, int n, double timeout, const atomic_int *cancel, unsigned flags,
                cl_reply_fn *fn, void *ctx, cl_traffic *tr) {
  double now = ts_now();
  xchg x = {c, ws, n, calloc((size_t)n, 1), malloc(sizeof(double) * (size_t)n), 0, 0, flags};
  struct pollfd *pf = malloc(sizeof(*pf) * (size_t)n);
  int *pi = malloc(sizeof(*pi) * (size_t)n); /* worker of each pollfd */
  int polled = n; /* workers the loop below looks at */
  if (pf == NULL || pi == NULL || x.gone == NULL || x.due == NULL) {
    for (int i = 0; i < n; i++) cl_worker_fail(c, ws[i], "the coordinator is out of memory");
    x.failed = 1;
    polled = 0;
  }
  for (int i = 0; i < polled; i++) {
    x.gone[i] = ws[i]->state == TS_WORKER_FAILED;
    x.due[i] = now + timeout + (ws[i]->nreqs > ws[i]->nqueue ? fmax(0, ws[i]->abandoned_due - now) : 0);
    ws[i]->io_heard_at = ws[i]->heard_at;
  }
  pthread_mutex_unlock(&c->lock);
  for (;;) {
    if (!x.canceled && cancel != NULL && atomic_load(cancel)) {
      x.canceled = 1;
      for (int i = 0; i < polled; i++)
        if (!x.gone[i]) x_abandon(&x, i);
    }
    int np = 0;
    double left = 1e9;
    now = ts_now();
    for (int i = 0; i < polled; i++) {
      cl_worker *w = ws[i];
      char err[TS_ERR_LEN];
      if (!x.gone[i] && fill_out(w, err) != 0) x_fail(&x, i, err);
      if (!x_pending(&x, i)) continue;
      if (now >= x.due[i]) {
        x_fail(&x, i, x.canceled ? "its requests under way were not taken before their deadline (a job's cancel)"
                                 : "no answer before the batch deadline");
        continue;
      }
      left = fmin(left, x.due[i] - now);
      pi[np] = i;
      pf[np].fd = w->conn.fd;
      pf[np].events = (short)(POLLIN | (w->out_off < w->out.len ? POLLOUT : 0));
      pf[np].revents = 0;
      np++;
    }
    if (np == 0) break;
    if (cancel != NULL && left > CL_CANCEL_POLL) left = CL_CANCEL_POLL; /* to see *cancel */
    int k = poll(pf, (nfds_t)np, (int)(left * 1000) + 1);
    if (k < 0 && errno != EINTR) {
      /* Nothing says which worker owes what: every one still owing answers
       * is dropped, and the batch is asked again. Returning here as if
       * all had answered would merge a partial answer: a wrong result. */
      char why[TS_ERR_LEN];
      snprintf(why, sizeof(why), "poll: %s (the batch is asked again)", strerror(errno));
      for (int p = 0; p < np; p++) x_fail(&x, pi[p], why);
      break;
    }
    for (int p = 0; p < np && k > 0; p++) {
      int i = pi[p];
      if (pf[p].revents & POLLOUT) x_send(&x, i, tr);
      if (!x.gone[i] && (pf[p].revents & (POLLIN | POLLERR | POLLHUP))) x_read(&x, i, fn, ctx, tr);
    }
  }
  pthread_mutex_lock(&c->lock);
  for (int i = 0; i < n; i++) {
    cl_out_reset(ws[i]);
    if (ws[i]->io_heard_at > ws[i]->heard_at) ws[i]->heard_at = ws[i]->io_heard_at;
  }
  free(pf);
  free(pi);
  free(x.gone);
  free(x.due);
  return x.failed ? TS_ECONN : x.canceled ? TS_ECANCELED : 0;
}

void cl_lease(ts_cluster *c, cl_worker **ws, int n) {
  for (int i = 0; i < n; i++) ws[i]->refs++;
  for (;;) {
    int i = 0;
    while (i < n && !ws[i]->busy) i++;
    if (i == n) break;
    pthread_cond_wait(&c->released, &c->lock);
  }
  for (int i = 0; i < n; i++) ws[i]->busy = 1;
}

void cl_release(ts_cluster *c, cl_worker **ws, int n) {
  for (int i = 0; i < n; i++) {
    ws[i]->busy = 0;
    ws[i]->refs--;
  }
  pthread_cond_broadcast(&c->released);
}

/* An 'E' reply as an error. */
int cl_reply_error(const ts_frame *f, char *err) {
  ts_msg_error e;
  if (ts_msg_error_read(f, &e, err) != 0) return TS_EPROTO;
  return ts_error(err, e.code, "worker error: %s", e.text);
}

void cl_unload_set(ts_cluster *c, cl_worker **ws, int n, uint32_t set, const atomic_int *cancel) {
  cl_lease(c, ws, n);
  for (int i = 0; i < n; i++) cl_queue_unload(c, ws[i], set);
  cl_traffic tr = {0, 0};
  if (n > 0) cl_exchange(c, ws, n, c->o.batch_timeout, cancel, CL_X_SEND_ALL, NULL, NULL, &tr);
  cl_release(c, ws, n);
}
