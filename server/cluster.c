/* cluster.c - see cluster.h.
 *
 * Locking: one mutex guards the worker list and every exchange with the
 * workers. A batch holds it from sending to the last answer, so the batches
 * of concurrent jobs interleave whole (each connection carries one
 * request/answer stream at a time and never needs demultiplexing). Slow
 * work that involves a single new worker - connecting, identifying,
 * calibrating - happens before the worker enters the list, without the lock.
 */
#include "cluster.h"

#include <errno.h>
#include <math.h>
#include <modbus/modbus.h>
#include <poll.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "calib.h"
#include "error.h"
#include "mbmap.h"
#include "pool.h"
#include "slice.h"
#include "usage.h"

#if __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "usage counters are shipped as in memory: little-endian hosts only"
#endif

#define CL_MAX_WORKERS 64
#define CL_MAX_ADDRS 64
#define CL_MAX_SETS 8
/* Time constant of the measured-rate averages: long enough to smooth the
 * jitter of single small batches, short against `persist`. */
#define CL_RATE_TAU 0.5
/* Batches answered faster than this say nothing reliable about a
 * worker's rate (the round trip dominates). */
#define CL_MIN_SAMPLE_SECONDS 0.0002
/* A batch may take this many times its expected scan time before the
 * workers still owing answers are dropped (see batch_deadline). */
#define CL_DEADLINE_SLACK 8.0

typedef struct {
  int id;
  ts_conn conn;
  ts_msg_ident ident;
  int state; /* TS_WORKER_* */
  double calib_rate;  /* comparisons/s from calibration */
  double slice_rate;  /* rate the current slices were sized with */
  double ewma_rate;   /* measured on batches */
  double ewma_weight; /* seconds of batches in the average (saturates) */
  uint64_t batches;
  uint32_t share; /* per mille of the last set sliced */
  /* One exchange's state. */
  ts_wr out;
  size_t out_off;
  int expect;
  uint64_t expected_pairs; /* comparisons the batch asks of it */
  uint64_t answered_pairs; /* comparisons the batch's answers report */
  double answered_at;      /* when the last answer arrived */
  double heard_at;         /* when the worker last sent anything */
  double mb_heard_at;      /* when its Modbus plane last answered */
  double cpu_share;        /* share of CPU its threads get (Modbus), < 0 unknown */
  double share_sized;      /* the share when its slices were last sized, < 0 none */
} cl_worker;

typedef struct {
  char addr[TS_NET_ADDR_LEN];
  int worker_id; /* live worker from this address, or 0 */
  int failing;   /* dialling it failed since it last joined (logged once) */
} cl_addr;

struct ts_cluster {
  pthread_mutex_t lock;
  ts_cluster_opts o;
  cl_worker *w[CL_MAX_WORKERS];
  int nw;
  cl_addr addrs[CL_MAX_ADDRS];
  int naddrs;
  int next_worker_id;
  uint32_t next_set, next_frame;
  uint64_t epoch; /* bumped when the slicing must change */
  double deviating_since; /* start of the current rate deviation, or 0 */
  double load_deviating_since; /* the same for CPU-share changes */
  uint64_t rebalances;
  ts_pool *local_pool; /* in-process scanning with no worker */
  const ts_l1_impl *simd;
  void (*log)(const char *msg);
  pthread_t thread, supervisor;
  int stop, supervising;
  pthread_cond_t wake;
  uint64_t batches, queries; /* answered for jobs */
};

static void default_log(const char *msg) { fprintf(stderr, "texsyn-server: %s\n", msg); }

static void cl_log(ts_cluster *c, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void cl_log(ts_cluster *c, const char *fmt, ...) {
  char buf[1024];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(buf, sizeof(buf), fmt, ap);
  va_end(ap);
  c->log(buf);
}

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
}

/* ---- frames into an output buffer ------------------------------------- */

static size_t frame_begin(ts_wr *w, uint8_t type, uint32_t id) {
  size_t at = w->len;
  uint8_t h[TS_FRAME_HEADER];
  ts_frame_header(h, type, id, 0);
  ts_wr_bytes(w, h, sizeof(h));
  return at;
}

static void frame_end(ts_wr *w, size_t at) {
  if (w->failed) return;
  uint32_t len = (uint32_t)(w->len - at - TS_FRAME_HEADER);
  ts_frame_header(w->buf + at, w->buf[at + 3], w->buf[at + 8] | w->buf[at + 9] << 8 |
                                                   w->buf[at + 10] << 16 | (uint32_t)w->buf[at + 11] << 24,
                  len);
}

/* ---- workers ----------------------------------------------------------- */

static void worker_free(cl_worker *w) {
  ts_conn_close(&w->conn);
  ts_wr_free(&w->out);
  free(w);
}

/* Marks a worker failed (under the lock): it leaves every slicing. */
static void worker_fail(ts_cluster *c, cl_worker *w, const char *why) {
  if (w->state == TS_WORKER_FAILED) return;
  cl_log(c, "worker %d (%s) dropped: %s", w->id, w->conn.peer, why);
  w->state = TS_WORKER_FAILED;
  shutdown(w->conn.fd, SHUT_RDWR);
  c->epoch++;
}

/* Removes failed workers from the list (under the lock, outside exchanges). */
static void reap_failed(ts_cluster *c) {
  int k = 0;
  for (int i = 0; i < c->nw; i++) {
    if (c->w[i]->state != TS_WORKER_FAILED) {
      c->w[k++] = c->w[i];
      continue;
    }
    for (int a = 0; a < c->naddrs; a++)
      if (c->addrs[a].worker_id == c->w[i]->id) c->addrs[a].worker_id = 0;
    worker_free(c->w[i]);
  }
  c->nw = k;
}

static int send_frame(ts_conn *conn, uint8_t type, uint32_t id, const ts_wr *w, char *err) {
  if (ts_wr_status(w) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
  return ts_net_send(conn->fd, type, id, w->buf, w->len, err);
}

/* Waits for the reply of the given type to a request (no lock held). */
static int await_reply(ts_conn *conn, uint8_t type, int timeout_ms, ts_frame *f, char *err) {
  int rc = ts_conn_recv(conn, f, timeout_ms, err);
  if (rc < 0) return rc;
  if (f->type == TS_MSG_ERROR) {
    ts_msg_error e;
    if (ts_msg_error_read(f, &e, err) != 0) return TS_EPROTO;
    return ts_error(err, e.code, "%s: %s", conn->peer, e.text);
  }
  if (f->type != type) return ts_error(err, TS_EPROTO, "%s: expected '%c', got '%c'", conn->peer, type, f->type);
  return 0;
}

static int calibrate(ts_cluster *c, cl_worker *w, char *err) {
  ts_wr wr;
  ts_wr_init(&wr);
  ts_msg_calib_req req = {c->o.calib_millis};
  ts_msg_calib_req_write(&wr, &req);
  int rc = send_frame(&w->conn, TS_MSG_CALIBRATE, 1, &wr, err);
  ts_wr_free(&wr);
  ts_frame f;
  ts_msg_calib cal;
  if (rc == 0) rc = await_reply(&w->conn, TS_MSG_CALIBRATE, (int)c->o.calib_millis * 10 + 5000, &f, err);
  if (rc == 0) rc = ts_msg_calib_read(&f, &cal, err);
  if (rc != 0) return rc;
  w->calib_rate = (double)cal.pairs / ((double)cal.nanos * 1e-9);
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
  ts_wr_init(&w->out);
  int rc = calibrate(c, w, err);
  pthread_mutex_lock(&c->lock);
  if (rc == 0 && c->nw == CL_MAX_WORKERS) rc = ts_error(err, TS_ETOOBIG, "pool full (%d workers)", CL_MAX_WORKERS);
  if (rc == 0) {
    w->id = ++c->next_worker_id;
    w->state = TS_WORKER_READY;
    w->heard_at = ts_now();
    c->w[c->nw++] = w;
    if (addr_slot >= 0) c->addrs[addr_slot].worker_id = w->id;
    c->epoch++;
    cl_log(c, "worker %d (%s, %u threads, %s) ready: %.3g comparisons/s", w->id, w->conn.peer,
         (unsigned)ident->threads, ident->simd < TS_SIMD_COUNT ? ts_l1_impl_get((ts_simd)ident->simd) ? ts_l1_impl_get((ts_simd)ident->simd)->name : "?" : "?",
         w->calib_rate);
  }
  pthread_mutex_unlock(&c->lock);
  if (rc != 0) worker_free(w);
  return rc;
}

static void ident_self(ts_msg_ident *m) {
  memset(m, 0, sizeof(*m));
  m->role = TS_ROLE_COORD;
  m->caps = TS_CAP_ALL;
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

typedef int cl_reply_fn(void *ctx, cl_worker *w, const ts_frame *f, char *err);
typedef struct {
  uint64_t bytes_out, bytes_in;
} cl_traffic;
static int exchange(ts_cluster *c, cl_worker **ws, int n, double timeout, cl_reply_fn *fn, void *ctx,
                    cl_traffic *tr);

static int heartbeat_reply(void *ctx, cl_worker *w, const ts_frame *f, char *err) {
  (void)ctx;
  (void)err;
  if (f->type == TS_MSG_HEARTBEAT) w->expect--;
  return 0; /* anything else is a stale answer of an abandoned batch */
}

/* Pings the workers that have been silent for a heartbeat interval, so a
 * worker that died or hung between jobs leaves the pool (and is dialled
 * again) before the next batch waits on it (lock held). */
static void heartbeat_idle(ts_cluster *c) {
  if (c->o.heartbeat <= 0) return;
  cl_worker *ws[CL_MAX_WORKERS];
  int n = 0;
  double now = ts_now();
  for (int i = 0; i < c->nw; i++) {
    cl_worker *w = c->w[i];
    if ((w->state != TS_WORKER_READY && w->state != TS_WORKER_DRAINING) || now - w->heard_at < c->o.heartbeat)
      continue;
    frame_begin(&w->out, TS_MSG_HEARTBEAT, ++c->next_frame); /* empty payload */
    w->expect = 1;
    ws[n++] = w;
  }
  cl_traffic tr = {0, 0};
  if (n > 0) exchange(c, ws, n, 2 * c->o.heartbeat + 1.0, heartbeat_reply, NULL, &tr);
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
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    ts.tv_nsec += 500000000;
    if (ts.tv_nsec >= 1000000000) {
      ts.tv_sec++;
      ts.tv_nsec -= 1000000000;
    }
    pthread_cond_timedwait(&c->wake, &c->lock, &ts);
  }
  pthread_mutex_unlock(&c->lock);
  return NULL;
}

static void *supervisor_thread(void *arg);

int ts_cluster_create(ts_cluster **out, const ts_cluster_opts *o, char *err) {
  *out = NULL;
  ts_cluster *c = calloc(1, sizeof(*c));
  if (c == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  c->o = *o;
  c->log = default_log;
  int rc = ts_l1_select(&c->simd, err);
  if (rc == 0 && ts_pool_create(&c->local_pool, o->local_threads) != 0)
    rc = ts_error(err, TS_ENOMEM, "cannot start %d scan threads", o->local_threads);
  if (rc != 0) {
    free(c);
    return rc;
  }
  pthread_mutex_init(&c->lock, NULL);
  pthread_cond_init(&c->wake, NULL);
  if (pthread_create(&c->thread, NULL, cluster_thread, c) != 0) {
    ts_pool_destroy(c->local_pool);
    free(c);
    return ts_error(err, TS_ENOMEM, "cannot start the cluster thread");
  }
  c->supervising = o->modbus_poll > 0 && pthread_create(&c->supervisor, NULL, supervisor_thread, c) == 0;
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
  ts_pool_destroy(c->local_pool);
  pthread_mutex_destroy(&c->lock);
  pthread_cond_destroy(&c->wake);
  free(c);
}

void ts_cluster_set_log(ts_cluster *c, void (*log)(const char *msg)) { c->log = log; }

int ts_cluster_add_address(ts_cluster *c, const char *addr, char *err) {
  char host[TS_NET_ADDR_LEN];
  int port;
  int rc = ts_net_split(addr, host, sizeof(host), &port, err);
  if (rc != 0) return rc;
  pthread_mutex_lock(&c->lock);
  if (c->naddrs == CL_MAX_ADDRS) rc = ts_error(err, TS_ETOOBIG, "more than %d worker addresses", CL_MAX_ADDRS);
  else snprintf(c->addrs[c->naddrs++].addr, TS_NET_ADDR_LEN, "%s", addr);
  pthread_cond_signal(&c->wake);
  pthread_mutex_unlock(&c->lock);
  return rc;
}

uint32_t ts_cluster_info(ts_cluster *c, ts_worker_info *out, uint32_t cap) {
  pthread_mutex_lock(&c->lock);
  uint32_t n = 0;
  for (int i = 0; i < c->nw && n < cap; i++) {
    const cl_worker *w = c->w[i];
    ts_worker_info *o = &out[n++];
    memset(o, 0, sizeof(*o));
    snprintf(o->addr, sizeof(o->addr), "%s", w->conn.peer);
    o->threads = w->ident.threads;
    o->simd = w->ident.simd;
    o->state = (uint8_t)w->state;
    o->calibrated = (uint64_t)w->calib_rate;
    o->rate = (uint64_t)w->slice_rate;
    o->share = (uint16_t)w->share;
    o->batches = w->batches;
  }
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

/* ---- supervision over Modbus ------------------------------------------- */

static int unloaded_reply(void *ctx, cl_worker *w, const ts_frame *f, char *err);

typedef struct {
  int id;
  char host[TS_NET_ADDR_LEN];
  char port[8];
} mb_target;

/* Whom to read (lock held): live workers that announced a Modbus port,
 * at the host their data connection comes from. */
static int mb_targets(ts_cluster *c, mb_target *t) {
  int n = 0;
  for (int i = 0; i < c->nw; i++) {
    cl_worker *w = c->w[i];
    if (w->ident.modbus_port == 0 || (w->state != TS_WORKER_READY && w->state != TS_WORKER_DRAINING)) continue;
    t[n].id = w->id;
    snprintf(t[n].host, sizeof(t[n].host), "%s", w->conn.peer);
    char *colon = strrchr(t[n].host, ':'); /* "ip:port", "[v6]:port" or "v6:port" */
    if (colon != NULL) *colon = '\0';
    if (t[n].host[0] == '[') {
      memmove(t[n].host, t[n].host + 1, strlen(t[n].host));
      t[n].host[strcspn(t[n].host, "]")] = '\0';
    }
    snprintf(t[n].port, sizeof(t[n].port), "%u", (unsigned)w->ident.modbus_port);
    n++;
  }
  return n;
}

/* Reads a worker's common register block (no lock): 0, or -1 if its plane
 * does not answer within half a second. */
static int mb_read(const mb_target *t, uint16_t *regs) {
  modbus_t *m = modbus_new_tcp_pi(t->host, t->port);
  if (m == NULL) return -1;
  modbus_set_response_timeout(m, 0, 500000);
  int rc = modbus_connect(m) == 0 &&
                   modbus_read_input_registers(m, 0, TS_MB_IR_COMMON_END, regs) == TS_MB_IR_COMMON_END
               ? 0
               : -1;
  modbus_close(m);
  modbus_free(m);
  return rc;
}

/* Takes a worker out of the slicing and has it free every slice (lock
 * held, so no batch is in flight): the next batch re-slices without it. */
static void begin_drain(ts_cluster *c, cl_worker *w) {
  w->state = TS_WORKER_DRAINING;
  c->epoch++;
  ts_msg_unload m = {TS_UNLOAD_ALL};
  size_t at = frame_begin(&w->out, TS_MSG_UNLOAD, ++c->next_frame);
  ts_msg_unload_write(&w->out, &m);
  frame_end(&w->out, at);
  w->expect = 1;
  cl_traffic tr = {0, 0};
  exchange(c, &w, 1, c->o.batch_timeout, unloaded_reply, NULL, &tr);
  cl_log(c, "worker %d (%s) draining: its slices are handed back and it gets no new ones", w->id, w->conn.peer);
}

/* Acts on one worker's registers, or on their absence (lock held). */
static void mb_apply(ts_cluster *c, int id, int ok, const uint16_t *regs) {
  cl_worker *w = NULL;
  for (int i = 0; i < c->nw && w == NULL; i++)
    if (c->w[i]->id == id) w = c->w[i];
  if (w == NULL || (w->state != TS_WORKER_READY && w->state != TS_WORKER_DRAINING)) return;
  double now = ts_now(), silent = 3 * c->o.modbus_poll;
  if (!ok) {
    if (now - w->mb_heard_at > silent && now - w->heard_at > fmax(silent, c->o.heartbeat))
      worker_fail(c, w, "its Modbus and data planes are both silent");
    return;
  }
  w->mb_heard_at = now;
  w->cpu_share = regs[TS_MB_IR_CPU_SHARE] == TS_MB_UNKNOWN ? -1.0 : regs[TS_MB_IR_CPU_SHARE] / 1000.0;
  int draining = regs[TS_MB_IR_STATE] == TS_MB_DRAINING;
  if (draining && w->state == TS_WORKER_READY) {
    begin_drain(c, w);
  } else if (!draining && w->state == TS_WORKER_DRAINING) {
    w->state = TS_WORKER_READY;
    c->epoch++;
    cl_log(c, "worker %d (%s) no longer draining: it gets slices again", w->id, w->conn.peer);
  }
}

/* Load drift seen over Modbus (lock held). Each worker's CPU share is
 * compared with its share when its slices were last sized: a worker whose
 * machine got busier gets less CPU and scans slower, whatever its slice
 * size (unlike its wall-clock scan rate, which a smaller slice inflates).
 * When these changes differ between workers by more than the tolerance
 * for --rebalance-after seconds, each rate is scaled by its change. */
static void check_load_balance(ts_cluster *c) {
  if (!(c->o.rebalance_from & TS_REBALANCE_MODBUS)) return;
  cl_worker *ws[CL_MAX_WORKERS];
  int n = 0;
  for (int i = 0; i < c->nw; i++) {
    cl_worker *w = c->w[i];
    if (w->state != TS_WORKER_READY) continue;
    if (w->cpu_share <= 0) return; /* idle or no Modbus plane: nothing to compare */
    if (w->share_sized <= 0) w->share_sized = w->cpu_share; /* the baseline */
    ws[n++] = w;
  }
  if (n < 2) return;
  double mean = 0, dev = 0;
  for (int i = 0; i < n; i++) mean += ws[i]->cpu_share / ws[i]->share_sized;
  mean /= n;
  for (int i = 0; i < n; i++) dev = fmax(dev, fabs(ws[i]->cpu_share / ws[i]->share_sized / mean - 1.0));
  double now = ts_now();
  if (dev <= c->o.tolerance) {
    c->load_deviating_since = 0;
    return;
  }
  if (c->load_deviating_since == 0) c->load_deviating_since = now;
  if (now - c->load_deviating_since < c->o.persist) return;
  for (int i = 0; i < n; i++) {
    ws[i]->slice_rate *= ws[i]->cpu_share / ws[i]->share_sized;
    ws[i]->share_sized = ws[i]->cpu_share;
  }
  c->load_deviating_since = 0;
  c->rebalances++;
  c->epoch++;
  cl_log(c, "rebalance %llu: the workers' CPU shares (Modbus) changed unevenly by %.0f%% for %.1fs",
         (unsigned long long)c->rebalances, dev * 100, c->o.persist);
}

static void *supervisor_thread(void *arg) {
  ts_cluster *c = arg;
  pthread_mutex_lock(&c->lock);
  while (!c->stop) {
    mb_target t[CL_MAX_WORKERS];
    int n = mb_targets(c, t);
    pthread_mutex_unlock(&c->lock);
    uint16_t regs[CL_MAX_WORKERS][TS_MB_IR_COMMON_END];
    int ok[CL_MAX_WORKERS];
    for (int i = 0; i < n; i++) ok[i] = mb_read(&t[i], regs[i]) == 0;
    pthread_mutex_lock(&c->lock);
    for (int i = 0; i < n && !c->stop; i++) mb_apply(c, t[i].id, ok[i], regs[i]);
    if (n > 0) check_load_balance(c);
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    double at = (double)ts.tv_sec + ts.tv_nsec * 1e-9 + c->o.modbus_poll;
    ts.tv_sec = (time_t)at;
    ts.tv_nsec = (long)((at - (double)ts.tv_sec) * 1e9);
    if (!c->stop) pthread_cond_timedwait(&c->wake, &c->lock, &ts);
  }
  pthread_mutex_unlock(&c->lock);
  return NULL;
}

/* ---- exchanges --------------------------------------------------------- */

/* Sends every worker's queued output and feeds each reply to fn until
 * every worker has answered its `expect` frames. A worker that fails
 * (connection, protocol, fn's error, deadline) is marked failed and the
 * others carry on, so their streams stay in step. Returns 0, or TS_ECONN if
 * any worker failed. Lock held. */
static int exchange(ts_cluster *c, cl_worker **ws, int n, double timeout, cl_reply_fn *fn, void *ctx,
                    cl_traffic *tr) {
  double deadline = ts_now() + timeout;
  int failed = 0;
  for (;;) {
    struct pollfd pf[CL_MAX_WORKERS];
    cl_worker *pw[CL_MAX_WORKERS];
    int np = 0;
    for (int i = 0; i < n; i++) {
      cl_worker *w = ws[i];
      if (w->state == TS_WORKER_FAILED || (w->expect == 0 && w->out_off == w->out.len)) continue;
      pw[np] = w;
      pf[np].fd = w->conn.fd;
      pf[np].events = (short)(POLLIN | (w->out_off < w->out.len ? POLLOUT : 0));
      pf[np].revents = 0;
      np++;
    }
    if (np == 0) break;
    double left = deadline - ts_now();
    if (left <= 0) {
      for (int i = 0; i < np; i++) worker_fail(c, pw[i], "no answer before the batch deadline");
      failed = 1;
      break;
    }
    int k = poll(pf, (nfds_t)np, (int)(left * 1000) + 1);
    if (k < 0 && errno != EINTR) break;
    for (int i = 0; i < np && k > 0; i++) {
      cl_worker *w = pw[i];
      char err[TS_ERR_LEN];
      if (pf[i].revents & POLLOUT) {
        ssize_t s = send(w->conn.fd, w->out.buf + w->out_off, w->out.len - w->out_off, MSG_DONTWAIT | MSG_NOSIGNAL);
        if (s > 0) {
          w->out_off += (size_t)s;
          tr->bytes_out += (uint64_t)s;
        } else if (s < 0 && errno != EAGAIN && errno != EINTR) {
          snprintf(err, sizeof(err), "send: %s", strerror(errno));
          worker_fail(c, w, err);
          failed = 1;
          continue;
        }
      }
      if (!(pf[i].revents & (POLLIN | POLLERR | POLLHUP))) continue;
      ts_frame f;
      int rc;
      while (w->state != TS_WORKER_FAILED && (rc = ts_conn_pump(&w->conn, &f, err)) != 0) {
        if (rc < 0 || (rc = fn(ctx, w, &f, err)) < 0) {
          worker_fail(c, w, err);
          failed = 1;
          break;
        }
        tr->bytes_in += TS_FRAME_HEADER + f.len;
        w->heard_at = ts_now();
      }
    }
  }
  for (int i = 0; i < n; i++) {
    ws[i]->out.len = 0;
    ws[i]->out_off = 0;
    ws[i]->expect = 0;
  }
  return failed ? TS_ECONN : 0;
}

/* An 'E' reply as an error. */
static int reply_error(const ts_frame *f, char *err) {
  ts_msg_error e;
  if (ts_msg_error_read(f, &e, err) != 0) return TS_EPROTO;
  return ts_error(err, e.code, "worker error: %s", e.text);
}

/* ---- the search backend ------------------------------------------------- */

typedef struct {
  cl_worker *w;
  uint32_t i0[4], i1[4];
} cl_slice;

typedef struct {
  int used;
  uint32_t gid; /* set id on the wire, unique in the cluster */
  uint32_t gen; /* slicing generation */
  ts_refset rs;
  const ts_refgrid *grid;
  int with_usage;
  ts_usage usage; /* the coordinator's replica: the counts new slices get */
  ts_commit *pending;
  uint32_t npending, cap_pending;
  uint64_t epoch; /* cluster epoch of the slicing below */
  int sliced;
  cl_slice slices[CL_MAX_WORKERS];
  int nslices;
  ts_slice *local; /* in-process slice when no worker is ready */
} cl_set;

typedef struct {
  ts_search base;
  ts_cluster *c;
  const volatile int *cancel;
  cl_set sets[CL_MAX_SETS];
  ts_l1_best *best;
  uint32_t cap_best;
} cluster_search;

static cl_set *set_get(cluster_search *cs, int id) {
  if (id < 0 || id >= CL_MAX_SETS || !cs->sets[id].used) return NULL;
  return &cs->sets[id];
}

/* Cuts every class into contiguous ranges in proportion to the workers'
 * rates, on group (8-vector) boundaries so every slice scans whole groups. */
static void cut_ranges(const ts_refgrid *g, cl_worker **ws, int n, cl_slice *out) {
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

static int ready_workers(ts_cluster *c, cl_worker **ws) {
  int n = 0;
  for (int i = 0; i < c->nw; i++)
    if (c->w[i]->state == TS_WORKER_READY) ws[n++] = c->w[i];
  return n;
}

static int loaded_reply(void *ctx, cl_worker *w, const ts_frame *f, char *err) {
  const cl_set *st = ctx;
  ts_msg_loaded m;
  if (f->type == TS_MSG_ERROR) return reply_error(f, err);
  if (f->type != TS_MSG_SLICE) return 0; /* a stale answer of an abandoned batch */
  if (ts_msg_loaded_read(f, &m, err) != 0) return TS_EPROTO;
  if (m.set == st->gid && m.gen == st->gen) w->expect--;
  return 0;
}

static int load_local(cl_set *st, char *err) {
  uint32_t i0[4] = {0};
  ts_slice_desc m;
  ts_slice_describe(&m, &st->rs, &st->usage, st->gid, st->gen, i0, st->grid->count);
  return ts_slice_load(&st->local, &m, err);
}

/* Makes the set's slicing match the current pool (lock held): every ready
 * worker gets a fresh slice (new generation) with the replica's counts; with
 * none, the coordinator loads the whole set itself. */
static int ensure_slices(cluster_search *cs, cl_set *st, char *err) {
  ts_cluster *c = cs->c;
  while (!st->sliced || st->epoch != c->epoch) {
    cl_worker *ws[CL_MAX_WORKERS];
    int n = ready_workers(c, ws);
    st->epoch = c->epoch;
    st->gen++;
    ts_slice_free(st->local);
    st->local = NULL;
    st->nslices = 0;
    st->sliced = 1;
    if (n == 0) return load_local(st, err);
    cut_ranges(st->grid, ws, n, st->slices);
    cl_traffic tr = {0, 0};
    double total = 0;
    for (int i = 0; i < n; i++) total += ws[i]->slice_rate;
    for (int i = 0; i < n; i++) {
      ts_slice_desc m;
      ts_slice_describe(&m, &st->rs, &st->usage, st->gid, st->gen, st->slices[i].i0, st->slices[i].i1);
      size_t at = frame_begin(&ws[i]->out, TS_MSG_SLICE, ++c->next_frame);
      ts_msg_slice_write(&ws[i]->out, &m);
      frame_end(&ws[i]->out, at);
      ws[i]->expect = 1;
      ws[i]->share = (uint32_t)llround(1000.0 * ws[i]->slice_rate / total);
    }
    st->nslices = n;
    exchange(c, ws, n, c->o.batch_timeout + 30.0, loaded_reply, st, &tr);
    cs->base.stats.bytes_out += tr.bytes_out;
    cs->base.stats.bytes_in += tr.bytes_in;
    /* A failure bumped the epoch: loop and slice again without it. */
  }
  return 0;
}

static int cluster_prepare(ts_search *s, const ts_refset *rs, int *id, char *err) {
  cluster_search *cs = (cluster_search *)s;
  int slot = 0;
  while (slot < CL_MAX_SETS && cs->sets[slot].used) slot++;
  if (slot == CL_MAX_SETS) return ts_error(err, TS_ENOMEM, "too many reference sets prepared at once");
  cl_set *st = &cs->sets[slot];
  memset(st, 0, sizeof(*st));
  st->rs = *rs;
  st->grid = rs->grid;
  st->with_usage = rs->usage;
  if (rs->usage && ts_usage_init(&st->usage, rs->grid, rs->shape->wb, 0) != 0)
    return ts_error(err, TS_ENOMEM, "out of memory for the usage replica");
  if (rs->usage && rs->counts != NULL) ts_usage_load(&st->usage, rs->counts->count);
  pthread_mutex_lock(&cs->c->lock);
  st->gid = ++cs->c->next_set;
  st->used = 1;
  int rc = ensure_slices(cs, st, err);
  pthread_mutex_unlock(&cs->c->lock);
  *id = slot;
  return rc;
}

static int cluster_commit(ts_search *s, int id, const ts_commit *cm, uint32_t n, char *err) {
  cl_set *st = set_get((cluster_search *)s, id);
  if (st == NULL) return ts_error(err, TS_EINVAL, "unknown reference set %d", id);
  if (!st->with_usage) return 0;
  for (uint32_t i = 0; i < n; i++) {
    if (cm[i].x < 0 || cm[i].y < 0 || cm[i].x + cm[i].w > st->grid->w || cm[i].y + cm[i].h > st->grid->h)
      return ts_error(err, TS_EINVAL, "commit outside the reference");
    if (cm[i].delta != 1 && cm[i].delta != -1) return ts_error(err, TS_EINVAL, "commit delta %d", (int)cm[i].delta);
  }
  if (st->npending + n > st->cap_pending) {
    uint32_t cap = st->cap_pending ? st->cap_pending : 1024;
    while (cap < st->npending + n) cap *= 2;
    ts_commit *p = realloc(st->pending, sizeof(ts_commit) * cap);
    if (p == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
    st->pending = p;
    st->cap_pending = cap;
  }
  memcpy(st->pending + st->npending, cm, sizeof(ts_commit) * n);
  st->npending += n;
  return 0;
}

/* The pending commits reach the replica once they are on their way to the
 * workers: slices loaded later start from counts that include them. */
static void flush_pending(cl_set *st) {
  for (uint32_t i = 0; i < st->npending; i++) {
    const ts_commit *k = &st->pending[i];
    ts_usage_commit(&st->usage, k->x, k->y, k->w, k->h, k->delta);
  }
  st->npending = 0;
}

/* V frame ids: the exchange's sequence number in the top byte (a stale
 * answer never matches) and the frame's first query below, counted over
 * the concatenated queries of every request of the exchange. */
#define CL_ID_QUERY_BITS 24
#define CL_ID_QUERY_MASK ((1u << CL_ID_QUERY_BITS) - 1)
#define CL_MAX_REQS 64

typedef struct {
  cl_set *st[CL_MAX_REQS];
  uint32_t q0[CL_MAX_REQS + 1]; /* request r holds queries q0[r]..q0[r+1]-1 */
  uint32_t nreq;
  ts_l1_best *best;
  uint32_t seq;
} batch_ctx;

static void merge_best(ts_l1_best *into, const ts_l1_best *b) {
  if (b->dist < into->dist || (b->dist == into->dist && b->index < into->index)) *into = *b;
}

/* A worker's rate as the coordinator sees it: the comparisons of its
 * answers over the time from sending the batch to its last answer. That
 * is what balancing must equalise, and it includes whatever slows the
 * worker - other load, a throttled CPU, its network - not only its scan. */
static void track_rate(cl_worker *w, double sent_at) {
  w->batches++;
  double dt = w->answered_at - sent_at;
  if (dt < CL_MIN_SAMPLE_SECONDS || w->answered_pairs == 0) return;
  double rate = (double)w->answered_pairs / dt;
  double k = 1.0 - exp(-dt / CL_RATE_TAU);
  w->ewma_rate += k * (rate - w->ewma_rate);
  w->ewma_weight += dt;
}

static int answer_reply(void *ctx, cl_worker *w, const ts_frame *f, char *err) {
  batch_ctx *b = ctx;
  if (f->type == TS_MSG_ERROR) return reply_error(f, err);
  if (f->type != TS_MSG_QUERY) return 0; /* stale reply of an abandoned exchange */
  ts_msg_answer a;
  if (ts_msg_answer_read(f, &a, err) != 0) return TS_EPROTO;
  if (f->id >> CL_ID_QUERY_BITS != (b->seq & 0xFF)) return 0;
  uint32_t q0 = f->id & CL_ID_QUERY_MASK, r = 0;
  while (r < b->nreq && q0 >= b->q0[r + 1]) r++;
  if (r == b->nreq) return ts_error(err, TS_EPROTO, "answer for queries outside the batch");
  const cl_set *st = b->st[r];
  if (a.set != st->gid || a.gen != st->gen) return 0;
  if (a.nq > b->q0[r + 1] - q0) return ts_error(err, TS_EPROTO, "answer for queries outside the batch");
  for (uint32_t i = 0; i < a.nq; i++) {
    ts_l1_best res;
    ts_msg_result_at(&a, i, &res);
    if (res.index != UINT32_MAX && res.index >= st->grid->total)
      return ts_error(err, TS_EPROTO, "answer index %u outside the set", res.index);
    merge_best(&b->best[q0 + i], &res);
  }
  w->answered_pairs += a.pairs;
  if (--w->expect == 0) w->answered_at = ts_now();
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
static int query_local(ts_cluster *c, cl_set *st, const ts_query_batch *b, ts_l1_best *out, uint64_t *pairs,
                       char *err) {
  int rc = ts_slice_commit(st->local, st->pending, st->npending, err);
  flush_pending(st);
  if (rc == 0) rc = ts_slice_scan(st->local, c->local_pool, 0, c->simd, b, out, pairs, err);
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

/* Queues every request's V frames to the workers holding its slices; the
 * workers involved are collected in ws. */
static int queue_frames(ts_cluster *c, const batch_ctx *bc, const ts_search_req *req, cl_worker **ws, int *nw,
                        char *err) {
  *nw = 0;
  for (uint32_t r = 0; r < bc->nreq; r++) {
    cl_set *st = bc->st[r];
    const ts_query_batch *b = &req[r].b;
    uint32_t vbytes = ts_shape_bytes(st->rs.shape);
    for (int i = 0; i < st->nslices; i++) {
      cl_worker *w = st->slices[i].w;
      int k = 0;
      while (k < *nw && ws[k] != w) k++;
      if (k == *nw) {
        ws[(*nw)++] = w;
        w->answered_pairs = w->expected_pairs = 0;
      }
      for (uint32_t q = 0; q < b->nq; q++) {
        int cls = b->klass ? b->klass[q] : 0;
        w->expected_pairs += st->slices[i].i1[cls] - st->slices[i].i0[cls];
      }
      for (uint32_t q0 = 0; q0 < b->nq; q0 += c->o.pipeline_queries) {
        uint32_t q1 = q0 + c->o.pipeline_queries < b->nq ? q0 + c->o.pipeline_queries : b->nq;
        size_t at = frame_begin(&w->out, TS_MSG_QUERY, (bc->seq & 0xFF) << CL_ID_QUERY_BITS | (bc->q0[r] + q0));
        /* The set's pending commits ride with its first frame. */
        if (q0 == 0) ts_msg_query_write(&w->out, st->gid, st->gen, st->pending, st->npending, b, vbytes, q0, q1);
        else ts_msg_query_write(&w->out, st->gid, st->gen, NULL, 0, b, vbytes, q0, q1);
        frame_end(&w->out, at);
        w->expect++;
      }
      if (ts_wr_status(&w->out) != 0) return ts_error(err, TS_ENOMEM, "out of memory for a batch");
    }
  }
  return 0;
}

/* A batch's deadline: CL_DEADLINE_SLACK times what the slowest worker
 * should need at the lower of its sized and measured rates, never below
 * the --batch-timeout floor. A worker missing it is taken for stalled. */
static double batch_deadline(const ts_cluster *c, cl_worker **ws, int n) {
  double need = 0;
  for (int i = 0; i < n; i++) {
    double rate = fmin(ws[i]->slice_rate, ws[i]->ewma_rate);
    if (rate > 0) need = fmax(need, (double)ws[i]->expected_pairs / rate);
  }
  return fmax(c->o.batch_timeout, CL_DEADLINE_SLACK * need);
}

/* Every request in one exchange with the pool (lock held). Returns 0,
 * TS_ECONN when a worker failed (re-slice and retry), or an error. */
static int exchange_batch(cluster_search *cs, batch_ctx *bc, const ts_search_req *req, char *err) {
  ts_cluster *c = cs->c;
  cl_worker *ws[CL_MAX_WORKERS];
  int n;
  bc->seq = ++c->next_frame;
  ts_l1_best_reset(bc->best, bc->q0[bc->nreq]);
  double sent_at = ts_now();
  int rc = queue_frames(c, bc, req, ws, &n, err);
  if (rc != 0) {
    for (int i = 0; i < n; i++) ws[i]->out.len = ws[i]->out_off = 0, ws[i]->expect = 0;
    return rc;
  }
  for (uint32_t r = 0; r < bc->nreq; r++) flush_pending(bc->st[r]);
  cl_traffic tr = {0, 0};
  rc = exchange(c, ws, n, batch_deadline(c, ws, n), answer_reply, bc, &tr);
  cs->base.stats.bytes_out += tr.bytes_out;
  cs->base.stats.bytes_in += tr.bytes_in;
  if (rc == 0) {
    for (int i = 0; i < n; i++) track_rate(ws[i], sent_at);
    check_balance(c, ws, n);
  }
  return rc;
}

/* Checks a request against its set; *st = the set. */
static int check_req(cluster_search *cs, const ts_search_req *r, cl_set **st, char *err) {
  *st = set_get(cs, r->id);
  if (*st == NULL) return ts_error(err, TS_EINVAL, "unknown reference set %d", r->id);
  if (r->b.usage_k != 0 && !(*st)->with_usage)
    return ts_error(err, TS_EINVAL, "a usage penalty on a set prepared without usage");
  return 0;
}

static int cluster_query_many(ts_search *s, const ts_search_req *req, uint32_t nreq, char *err) {
  cluster_search *cs = (cluster_search *)s;
  ts_cluster *c = cs->c;
  if (nreq > CL_MAX_REQS) return ts_error(err, TS_ETOOBIG, "%u requests at once (at most %d)", nreq, CL_MAX_REQS);
  batch_ctx bc = {.nreq = nreq};
  for (uint32_t r = 0; r < nreq; r++) {
    int rc = check_req(cs, &req[r], &bc.st[r], err);
    if (rc != 0) return rc;
    if (req[r].b.nq > CL_ID_QUERY_MASK - bc.q0[r]) return ts_error(err, TS_ETOOBIG, "too many queries at once");
    bc.q0[r + 1] = bc.q0[r] + req[r].b.nq;
  }
  uint32_t nq = bc.q0[nreq];
  if (nq == 0) return 0;
  if (cs->cancel != NULL && *cs->cancel) return ts_error(err, TS_ECANCELED, "job canceled");
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
        rc = query_local(c, bc.st[r], &req[r].b, req[r].out, &pairs, err);
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
  } while (rc == TS_ECONN);
  pthread_mutex_unlock(&c->lock);
  if (rc != 0) return rc;
  for (uint32_t r = 0; r < nreq; r++) {
    const ts_query_batch *b = &req[r].b;
    if (!local) memcpy(req[r].out, bc.best + bc.q0[r], sizeof(ts_l1_best) * b->nq);
    for (uint32_t i = 0; i < b->nq && !local; i++) s->stats.pairs += bc.st[r]->grid->count[b->klass ? b->klass[i] : 0];
    s->stats.batches++;
    s->stats.queries += b->nq;
  }
  s->stats.pairs += local_pairs;
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

static int unloaded_reply(void *ctx, cl_worker *w, const ts_frame *f, char *err) {
  (void)ctx;
  (void)err;
  if (f->type == TS_MSG_UNLOAD) w->expect--;
  return 0;
}

static void set_clear(cluster_search *cs, cl_set *st) {
  ts_cluster *c = cs->c;
  pthread_mutex_lock(&c->lock);
  cl_worker *ws[CL_MAX_WORKERS];
  int n = 0;
  if (st->epoch == c->epoch)
    for (int i = 0; i < st->nslices; i++) ws[n++] = st->slices[i].w;
  else /* slices may be on any worker that is still with us */
    n = ready_workers(c, ws);
  for (int i = 0; i < n; i++) {
    ts_msg_unload m = {st->gid};
    size_t at = frame_begin(&ws[i]->out, TS_MSG_UNLOAD, ++c->next_frame);
    ts_msg_unload_write(&ws[i]->out, &m);
    frame_end(&ws[i]->out, at);
    ws[i]->expect = 1;
  }
  cl_traffic tr = {0, 0};
  if (n > 0) exchange(c, ws, n, c->o.batch_timeout, unloaded_reply, NULL, &tr);
  pthread_mutex_unlock(&c->lock);
  ts_slice_free(st->local);
  ts_usage_free(&st->usage);
  free(st->pending);
  memset(st, 0, sizeof(*st));
}

static void cluster_release(ts_search *s, int id) {
  cluster_search *cs = (cluster_search *)s;
  cl_set *st = set_get(cs, id);
  if (st != NULL) set_clear(cs, st);
}

static void cluster_destroy(ts_search *s) {
  cluster_search *cs = (cluster_search *)s;
  for (int i = 0; i < CL_MAX_SETS; i++)
    if (cs->sets[i].used) set_clear(cs, &cs->sets[i]);
  free(cs->best);
  free(cs);
}

static const ts_search_ops cluster_ops = {
    .name = "cluster",
    .prepare = cluster_prepare,
    .commit = cluster_commit,
    .query = cluster_query,
    .query_many = cluster_query_many,
    .release = cluster_release,
    .destroy = cluster_destroy,
};

int ts_search_cluster_create(ts_search **out, ts_cluster *c, const volatile int *cancel, char *err) {
  cluster_search *cs = calloc(1, sizeof(*cs));
  if (cs == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  cs->base.ops = &cluster_ops;
  cs->base.simd = c->simd;
  cs->c = c;
  cs->cancel = cancel;
  *out = &cs->base;
  return 0;
}
