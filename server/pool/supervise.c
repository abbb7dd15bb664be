/* supervise.c - the coordinator reads every worker's Modbus plane
 * (proto/mbmap.h) apart from the data plane: drain coils, liveness when
 * the data plane is silent, and load (CPU share) changes that resize the
 * slices. See cluster.h. */
#include <math.h>
#include <modbus/modbus.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "cluster_impl.h"
#include "mbmap.h"


typedef struct {
  int id;
  char host[TS_NET_ADDR_LEN];
  char port[8];
  int ok;                               /* its plane answered */
  uint16_t regs[TS_MB_IR_COMMON_END];  /* what it said */
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
  cl_unload_set(c, &w, 1, TS_UNLOAD_ALL, NULL); /* leased after the batch it may be serving */
  cl_log(c, "worker %d (%s) draining: its slices are handed back and it gets no new ones", w->id, w->conn.peer);
}

/* An 'H' answer's drain flag into *ctx (an int: 1 drains, 0 does not). */
static int read_drain_flag(void *ctx, cl_worker *w, const ts_frame *f, const cl_request *rq, char *err) {
  (void)w;
  (void)rq;
  if (f->type == TS_MSG_ERROR) return cl_reply_error(f, err);
  if (f->type != TS_MSG_HEARTBEAT || f->len != 1)
    return ts_error(err, TS_EPROTO, "malformed 'H' answer: one byte of flags expected");
  *(int *)ctx = (f->payload[0] & TS_HEARTBEAT_DRAINING) != 0;
  return 0;
}

/* Whether w's authenticated data plane says it drains (lock held): 1, 0,
 * or -1 when it did not answer (then it has failed). Modbus carries no
 * authentication, so its registers are hints: what would take a worker
 * out of the slicing, or put it back, is asked again here. */
static int drain_confirmed(ts_cluster *c, cl_worker *w) {
  int draining = -1;
  cl_lease(c, &w, 1);
  if (w->state == TS_WORKER_READY || w->state == TS_WORKER_DRAINING) {
    cl_queue_heartbeat(c, w);
    cl_traffic tr = {0, 0};
    cl_exchange(c, &w, 1, c->o.batch_timeout, NULL, 0, read_drain_flag, &draining, &tr);
  }
  cl_release(c, &w, 1);
  return draining;
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
      cl_worker_fail(c, w, "its Modbus and data planes are both silent");
    return;
  }
  w->mb_heard_at = now;
  w->cpu_share = regs[TS_MB_IR_CPU_SHARE] == TS_MB_UNKNOWN ? -1.0 : regs[TS_MB_IR_CPU_SHARE] / 1000.0;
  int draining = regs[TS_MB_IR_STATE] == TS_MB_DRAINING;
  if (draining != (w->state == TS_WORKER_DRAINING)) {
    int confirmed = drain_confirmed(c, w);
    if (confirmed < 0 || (w->state != TS_WORKER_READY && w->state != TS_WORKER_DRAINING)) return;
    if (confirmed != draining) {
      cl_log(c, "worker %d (%s): its Modbus plane says %s but its data plane does not; ignored (a forged or "
             "stale Modbus answer)", w->id, w->conn.peer, draining ? "draining" : "not draining");
      return;
    }
  }
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
  int n = 0;
  for (int i = 0; i < c->nw; i++) {
    cl_worker *w = c->w[i];
    if (w->state != TS_WORKER_READY) continue;
    if (w->cpu_share <= 0) return; /* idle or no Modbus plane: nothing to compare */
    if (w->share_sized <= 0) w->share_sized = w->cpu_share; /* the baseline */
    n++;
  }
  if (n < 2) return;
  double mean = 0, dev = 0;
  for (int i = 0; i < c->nw; i++)
    if (c->w[i]->state == TS_WORKER_READY) mean += c->w[i]->cpu_share / c->w[i]->share_sized;
  mean /= n;
  for (int i = 0; i < c->nw; i++)
    if (c->w[i]->state == TS_WORKER_READY)
      dev = fmax(dev, fabs(c->w[i]->cpu_share / c->w[i]->share_sized / mean - 1.0));
  double now = ts_now();
  if (dev <= c->o.tolerance) {
    c->load_deviating_since = 0;
    return;
  }
  if (c->load_deviating_since == 0) c->load_deviating_since = now;
  if (now - c->load_deviating_since < c->o.persist) return;
  for (int i = 0; i < c->nw; i++) {
    cl_worker *w = c->w[i];
    if (w->state != TS_WORKER_READY) continue;
    w->slice_rate *= w->cpu_share / w->share_sized;
    w->share_sized = w->cpu_share;
  }
  c->load_deviating_since = 0;
  c->rebalances++;
  c->epoch++;
  cl_log(c, "rebalance %llu: the workers' CPU shares (Modbus) changed unevenly by %.0f%% for %.1fs",
         (unsigned long long)c->rebalances, dev * 100, c->o.persist);
}

void *cl_supervisor_thread(void *arg) {
  ts_cluster *c = arg;
  /* Whom to read and what they said, one entry a worker. */
  mb_target *t = calloc(c->o.max_workers, sizeof(*t));
  if (t == NULL) {
    cl_log(c, "out of memory: the workers' Modbus planes are not read");
    return NULL;
  }
  pthread_mutex_lock(&c->lock);
  while (!c->stop) {
    int n = mb_targets(c, t);
    pthread_mutex_unlock(&c->lock);
    for (int i = 0; i < n; i++) t[i].ok = mb_read(&t[i], t[i].regs) == 0;
    pthread_mutex_lock(&c->lock);
    for (int i = 0; i < n && !c->stop; i++) mb_apply(c, t[i].id, t[i].ok, t[i].regs);
    if (n > 0) check_load_balance(c);
    struct timespec ts = ts_wait_until(c->o.modbus_poll);
    if (!c->stop) pthread_cond_timedwait(&c->wake, &c->lock, &ts);
  }
  pthread_mutex_unlock(&c->lock);
  free(t);
  return NULL;
}
