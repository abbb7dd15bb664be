/* main.c - texsyn-server, the coordinator.
 *
 * One listening port serves both planes: a connection's first frame ('I')
 * says whether the peer is a worker joining the pool or a client. Every
 * peer authenticates first (auth.h; without a secret only loopback peers
 * are let in). Workers go to the cluster (cluster.c), clients get a thread
 * that answers their requests against the job queue (jobs.c). A bad peer
 * loses its own connection, never the daemon. */
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <inttypes.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include "auth.h"
#include "cluster.h"
#include "connset.h"
#include "error.h"
#include "gate.h"
#include "http.h"
#include "http_page.h"
#include "image.h"
#include "jobs.h"
#include "keyring.h"
#include "log.h"
#include "mbplane.h"
#include "smon.h"
#include "msg.h"
#include "net.h"
#include "stop.h"
#include "util.h"

/* How long a refused peer gets to read its 'E' before we close. */
#define REFUSE_LINGER_MS 1000

typedef struct {
  ts_cluster *cluster;
  ts_jobs *jobs;
  uint32_t max_frame;
  int quiet;
  ts_auth auth; /* enabled with a ring of keys (keyring.h), or none */
} server;

/* Who a client connection acts as: the name its jobs are owned and counted
 * by, and whether it may act on every job (an admin key, or no keys at
 * all: protected mode trusts its loopback peers). */
typedef struct {
  char owner[TS_MSG_NAME_MAX];
  int all_jobs;
} principal;

/* TS_CAP_PIECES: joining workers announce their limits in their 'C' replies. */
static const ts_msg_ident kSelf = {TS_ROLE_COORD, TS_CAP_ALL | TS_CAP_PIECES, 0, 0, "texsyn-server 0.3"};

static server g_server;
/* Set by the signal handler, read by every thread: an atomic, lock-free
 * here, so safe in a handler (volatile sig_atomic_t is only for the thread
 * the handler interrupts; elsewhere it is a data race). */
static atomic_int g_stop;
_Static_assert(ATOMIC_INT_LOCK_FREE == 2, "the stop flag must be lock-free to be set in a signal handler");

static ts_connset g_conns;
static ts_gate g_gate; /* connections that have not authenticated yet */

/* ---- replies ------------------------------------------------------------ */

static int reply(ts_conn *c, uint8_t type, uint32_t id, ts_wr *w) {
  char err[TS_ERR_LEN];
  int rc = ts_wr_status(w) != 0 ? TS_ENOMEM : ts_conn_send(c, type, id, w->buf, w->len, err);
  ts_wr_free(w);
  return rc;
}

static int reply_error(ts_conn *c, uint32_t id, int code, const char *text) {
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_error_write(&w, code, text);
  return reply(c, TS_MSG_ERROR, id, &w);
}

static int serve_submit(ts_conn *c, const ts_frame *f, const principal *p) {
  const char *client = p->owner;
  char err[TS_ERR_LEN];
  ts_msg_submit m;
  int rc = ts_msg_submit_read(f, &m, err);
  uint64_t id = 0;
  if (rc == 0) rc = ts_jobs_submit(g_server.jobs, client, &m, &id, err);
  if (rc != 0) {
    ts_log("refused a job from %s: %s", c->peer, err);
    return reply_error(c, f->id, rc, err);
  }
  ts_log("job %" PRIu64 " queued from %s (%s)", id, c->peer, client);
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_jobid_write(&w, id);
  return reply(c, TS_MSG_SUBMIT, f->id, &w);
}

/* 0 if p may act on job id: its owner, or an admin. An unknown job is
 * left to the action, which names it. */
static int owner_check(const principal *p, uint64_t id, const char *verb, char *err) {
  ts_job_status st;
  if (p->all_jobs || ts_jobs_status(g_server.jobs, id, &st, NULL) != 0 || strcmp(st.owner, p->owner) == 0) return 0;
  return ts_error(err, TS_EAUTH, "job %" PRIu64 " belongs to %s: only its owner or an admin key may %s it", id,
                  st.owner, verb);
}

/* Another owner's job in a listing: its state and progress, not what it
 * is doing nor what its result is called. */
static void redact(const principal *p, ts_job_status *st) {
  if (p->all_jobs || strcmp(st->owner, p->owner) == 0) return;
  st->text[0] = '\0';
  snprintf(st->output, sizeof(st->output), "-");
}

static int send_status(ts_conn *c, uint32_t id, const ts_job_status *s, uint32_t n) {
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_status_write(&w, s, n);
  return reply(c, TS_MSG_STATUS, id, &w);
}

static int serve_status(ts_conn *c, const ts_frame *f, const principal *who) {
  char err[TS_ERR_LEN];
  ts_msg_status_req m;
  if (ts_msg_status_req_read(f, &m, err) != 0) return reply_error(c, f->id, TS_EPROTO, err);
  if (m.id == 0) {
    /* Every job, however long the spool's history: a capped listing would
     * leave out the newest. Jobs queued after the count are in the next one. */
    uint32_t counts[TS_JOB_STATE_COUNT], cap = 1; /* 1: no malloc(0) on an empty spool */
    ts_jobs_counts(g_server.jobs, counts);
    for (int s = 0; s < TS_JOB_STATE_COUNT; s++) cap += counts[s];
    ts_job_status *all = malloc(sizeof(*all) * cap);
    if (all == NULL) return reply_error(c, f->id, TS_ENOMEM, "out of memory");
    uint32_t n = ts_jobs_list(g_server.jobs, all, cap);
    for (uint32_t i = 0; i < n; i++) redact(who, &all[i]);
    int rc = send_status(c, f->id, all, n);
    free(all);
    return rc;
  }
  ts_job_status st;
  uint64_t version;
  if (ts_jobs_status(g_server.jobs, m.id, &st, &version) != 0) {
    snprintf(err, sizeof(err), "no job %" PRIu64, m.id);
    return reply_error(c, f->id, TS_ENOENT, err);
  }
  redact(who, &st);
  int rc = send_status(c, f->id, &st, 1);
  /* Watch: one record per change until the job ends. */
  while (rc == 0 && m.follow && st.state <= TS_JOB_RUNNING && !atomic_load(&g_stop)) {
    uint64_t seen = version;
    ts_jobs_wait(g_server.jobs, m.id, &version, 1000, &st);
    redact(who, &st);
    if (version != seen || st.state > TS_JOB_RUNNING) rc = send_status(c, f->id, &st, 1);
  }
  return rc;
}

/* Reads file i of a fetch: whole when it is small enough to go inline,
 * else only its size (the client takes it in 'B' ranges). */
static int fetch_file(const char *path, ts_msg_files *m, uint32_t i, uint8_t **buf, char *err) {
  struct stat st;
  if (stat(path, &st) != 0) return ts_error(err, TS_EIO, "%s: %s", path, strerror(errno));
  m->size[i] = (uint64_t)st.st_size;
  if (m->size[i] > TS_FETCH_INLINE) return 0;
  size_t len;
  int rc = ts_file_read(path, TS_FETCH_INLINE, buf, &len, err);
  if (rc == 0 && len != m->size[i]) rc = ts_error(err, TS_EIO, "%s changed while it was read", path);
  m->data[i] = *buf;
  m->len[i] = (uint32_t)len;
  m->size[i] = len;
  return rc;
}

static int serve_fetch(ts_conn *c, const ts_frame *f, const principal *who) {
  char err[TS_ERR_LEN];
  uint64_t id;
  if (ts_msg_jobid_read(f, &id, err) != 0) return reply_error(c, f->id, TS_EPROTO, err);
  if (owner_check(who, id, "fetch", err) != 0) return reply_error(c, f->id, TS_EAUTH, err);
  ts_msg_files m;
  memset(&m, 0, sizeof(m));
  char (*p)[4096] = malloc(sizeof(char[TS_FETCH_MAX_FILES][4096]));
  if (p == NULL) return reply_error(c, f->id, TS_ENOMEM, "out of memory");
  int rc = ts_jobs_files(g_server.jobs, id, m.name, p, &m.n, err);
  uint8_t *bufs[TS_FETCH_MAX_FILES] = {0};
  for (uint32_t i = 0; rc == 0 && i < m.n; i++) rc = fetch_file(p[i], &m, i, &bufs[i], err);
  if (rc == 0) {
    ts_wr w;
    ts_wr_init(&w);
    ts_msg_files_write(&w, &m);
    rc = reply(c, TS_MSG_FETCH, f->id, &w);
  } else {
    rc = reply_error(c, f->id, rc, err);
  }
  for (uint32_t i = 0; i < TS_FETCH_MAX_FILES; i++) free(bufs[i]);
  free(p);
  return rc;
}

/* The bytes of a range of a finished job's file (pread: the coordinator
 * holds one range, never the file). */
static int read_range(const ts_msg_range *m, const char *path, uint8_t *buf, char *err) {
  int fd = open(path, O_RDONLY | O_CLOEXEC);
  if (fd < 0) return ts_error(err, TS_EIO, "%s: %s", path, strerror(errno));
  struct stat st;
  int rc = fstat(fd, &st) != 0 ? ts_error(err, TS_EIO, "%s: %s", path, strerror(errno)) : 0;
  if (rc == 0 && m->offset + m->len > (uint64_t)st.st_size)
    rc = ts_error(err, TS_EINVAL, "job %" PRIu64 "'s %s has %lld bytes: no range [%" PRIu64 ", %" PRIu64 ")", m->id,
                  m->name, (long long)st.st_size, m->offset, m->offset + m->len);
  for (uint32_t got = 0; rc == 0 && got < m->len;) {
    ssize_t n = pread(fd, buf + got, m->len - got, (off_t)(m->offset + got));
    if (n <= 0) rc = ts_error(err, TS_EIO, "%s: %s", path, n < 0 ? strerror(errno) : "shorter than it was");
    else got += (uint32_t)n;
  }
  close(fd);
  return rc;
}

static int serve_range(ts_conn *c, const ts_frame *f, const principal *who) {
  char err[TS_ERR_LEN];
  ts_msg_range m;
  if (ts_msg_range_read(f, &m, err) != 0) return reply_error(c, f->id, TS_EPROTO, err);
  if (owner_check(who, m.id, "fetch", err) != 0) return reply_error(c, f->id, TS_EAUTH, err);
  char names[TS_FETCH_MAX_FILES][TS_MSG_NAME_MAX];
  char (*p)[4096] = malloc(sizeof(char[TS_FETCH_MAX_FILES][4096]));
  uint8_t *buf = malloc(m.len);
  uint32_t n = 0;
  int rc = p != NULL && buf != NULL ? ts_jobs_files(g_server.jobs, m.id, names, p, &n, err)
                                    : ts_error(err, TS_ENOMEM, "out of memory");
  uint32_t i = 0;
  while (rc == 0 && i < n && strcmp(names[i], m.name) != 0) i++;
  if (rc == 0 && i == n) rc = ts_error(err, TS_ENOENT, "job %" PRIu64 " has no file %s", m.id, m.name);
  if (rc == 0) rc = read_range(&m, p[i], buf, err);
  if (rc == 0) rc = ts_conn_send(c, TS_MSG_RANGE, f->id, buf, m.len, err);
  else rc = reply_error(c, f->id, rc, err);
  free(buf);
  free(p);
  return rc;
}

static int serve_cancel(ts_conn *c, const ts_frame *f, const principal *who) {
  char err[TS_ERR_LEN];
  uint64_t id;
  int rc = ts_msg_jobid_read(f, &id, err);
  if (rc == 0) rc = owner_check(who, id, "cancel", err);
  if (rc == 0) rc = ts_jobs_cancel(g_server.jobs, id, err);
  if (rc != 0) return reply_error(c, f->id, rc, err);
  ts_log("job %" PRIu64 " canceled by %s (%s)", id, c->peer, who->owner);
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_jobid_write(&w, id);
  return reply(c, TS_MSG_CANCEL, f->id, &w);
}

static int serve_delete(ts_conn *c, const ts_frame *f, const principal *who) {
  char err[TS_ERR_LEN];
  uint64_t id;
  int rc = ts_msg_jobid_read(f, &id, err);
  if (rc == 0) rc = owner_check(who, id, "delete", err);
  if (rc == 0) rc = ts_jobs_delete(g_server.jobs, id, err);
  if (rc != 0) return reply_error(c, f->id, rc, err);
  ts_log("job %" PRIu64 " deleted by %s (%s)", id, c->peer, who->owner);
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_jobid_write(&w, id);
  return reply(c, TS_MSG_DELETE, f->id, &w);
}

static int serve_pool(ts_conn *c, const ts_frame *f) {
  if (f->len != 0) return reply_error(c, f->id, TS_EPROTO, "malformed 'P' message: payload must be empty");
  ts_worker_info *wi = malloc(sizeof(*wi) * TS_POOL_MAX_REPORT);
  if (wi == NULL) return reply_error(c, f->id, TS_ENOMEM, "out of memory");
  uint32_t n = ts_cluster_info(g_server.cluster, wi, TS_POOL_MAX_REPORT);
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_pool_write(&w, wi, n);
  free(wi);
  return reply(c, TS_MSG_POOL, f->id, &w);
}

/* Answers one client request; a negative return closes the connection. */
static int serve_request(ts_conn *c, const ts_frame *f, const principal *who) {
  switch (f->type) {
  case TS_MSG_SUBMIT: return serve_submit(c, f, who);
  case TS_MSG_STATUS: return serve_status(c, f, who);
  case TS_MSG_FETCH: return serve_fetch(c, f, who);
  case TS_MSG_RANGE: return serve_range(c, f, who);
  case TS_MSG_CANCEL: return serve_cancel(c, f, who);
  case TS_MSG_DELETE: return serve_delete(c, f, who);
  case TS_MSG_POOL: return serve_pool(c, f);
  case TS_MSG_HEARTBEAT: {
    ts_wr w;
    ts_wr_init(&w);
    return reply(c, TS_MSG_HEARTBEAT, f->id, &w);
  }
  default: {
    char msg[64];
    snprintf(msg, sizeof(msg), "unknown message type 0x%02x", f->type);
    reply_error(c, f->id, TS_EPROTO, msg);
    return TS_EPROTO;
  }
  }
}

/* A client that went away: logged when it left a message unfinished (an
 * upload cut off), which is then dropped whole - nothing of it is queued. */
static void note_client_gone(const ts_conn *c, const char *client) {
  uint64_t held = c->rd.len - c->rd.consumed + (c->pieces.active ? c->pieces.got : 0);
  if (held > 0)
    ts_log("client %s (%s) went away in the middle of a message (%" PRIu64 " bytes of it received): dropped, "
           "nothing of it was accepted", c->peer, client, held);
}

/* A client key's jobs are owned by its name; an admin key, or a client in
 * protected mode, is who it says it is (USER@HOST), as before keys had
 * names. */
static void serve_client(ts_conn *c, const ts_msg_ident *ident, const ts_principal *key) {
  principal who = {"", key->kind != TS_KEY_CLIENT};
  snprintf(who.owner, sizeof(who.owner), "%s", key->kind == TS_KEY_CLIENT ? key->name : ident->name);
  const char *client = who.owner;
  while (!atomic_load(&g_stop)) {
    ts_frame f;
    char err[TS_ERR_LEN];
    int rc = ts_conn_recv(c, &f, 1000, err);
    if (rc == TS_ETIMEDOUT) continue;
    if (rc == TS_ECONN) {
      note_client_gone(c, client);
      return;
    }
    if (rc < 0) {
      ts_log("protocol error from client %s: %s; closing", c->peer, err);
      reply_error(c, 0, rc, err);
      return;
    }
    if (serve_request(c, &f, &who) != 0) {
      ts_log("client %s: request '%c' failed; closing", c->peer, f.type >= 32 && f.type < 127 ? f.type : '?');
      return;
    }
  }
}

typedef struct {
  int fd;
  char peer[TS_NET_ADDR_LEN];
  struct sockaddr_storage addr;
} accepted;

static void serve_connection(const accepted *a);

static void *connection_thread(void *arg) {
  accepted a = *(accepted *)arg;
  free(arg);
  serve_connection(&a);
  return NULL;
}

/* Ends a connection that failed to start: a refused peer (protected
 * mode, wrong or missing secret) or one that broke the protocol is told
 * why in an 'E' and logged. */
static void end_start(ts_conn *c, int rc, const char *err) {
  static ts_log_limit timeouts = TS_LOG_LIMIT_INIT; /* slow or silent strangers, by the thousand */
  if (rc == TS_EAUTH) ts_log("refused %s: %s", c->peer, err);
  else if (rc == TS_ETIMEDOUT) ts_log_limited(&timeouts, "closed %s: %s", c->peer, err);
  else if (rc != TS_ECONN) ts_log("protocol error from %s: %s; closing", c->peer, err);
  if (rc != TS_ECONN) reply_error(c, 0, rc, err);
  ts_connset_remove(&g_conns, c->fd);
  /* Counted as pending while it lingers: refused strangers cannot pile
   * up threads outside the gate's limits. */
  if (rc == TS_EAUTH) ts_conn_linger(c, REFUSE_LINGER_MS);
  ts_gate_leave(&g_gate, c->fd);
  ts_conn_close(c);
}

/* Takes the connection: closes it, or hands it to the cluster. */
static void serve_connection(const accepted *ap) {
  accepted a = *ap;
  ts_conn c;
  ts_conn_init(&c, a.fd, g_server.max_frame, a.peer);
  ts_msg_ident ident;
  ts_principal key;
  char err[TS_ERR_LEN];
  int rc = ts_auth_peer_allowed(&g_server.auth, (const struct sockaddr *)&a.addr, err);
  if (rc == 0) rc = ts_auth_accept(&c, &g_server.auth, &kSelf, &ident, &key, TS_GATE_HANDSHAKE_MS, err);
  if (rc < 0) {
    end_start(&c, rc, err);
    return;
  }
  ts_gate_leave(&g_gate, a.fd);
  if (ident.role == TS_ROLE_WORKER) {
    ts_log("worker joining from %s (%s)%s%s%s%s", a.peer, ident.name, key.kind ? ", " : "",
           key.kind ? ts_auth_kind_name(key.kind) : "", key.kind ? " key " : "", key.name);
    /* The cluster owns the connection from here; it stays in the set while
     * it is calibrated, so a shutdown meanwhile does not wait for that. */
    int fd = c.fd;
    if (ts_cluster_adopt(g_server.cluster, &c, &ident, err) != 0) ts_log("worker %s refused: %s", a.peer, err);
    ts_connset_remove(&g_conns, fd);
    return;
  }
  serve_client(&c, &ident, &key);
  ts_connset_remove(&g_conns, c.fd);
  ts_conn_close(&c);
}

/* ---- options ------------------------------------------------------------ */

static void usage(FILE *f) {
  fprintf(f,
          "usage: texsyn-server [options]\n"
          "\n"
          "The texsyn coordinator: accepts synthesis jobs from clients (texsyn synth --server),\n"
          "runs them against a pool of texsyn-worker processes that scan slices of the\n"
          "reference, and keeps jobs and results in a spool directory.\n"
          "\n"
          "  --listen ADDR:PORT        clients and joining workers (default 127.0.0.1:7070;\n"
          "                            port 0 picks a free port)\n"
          "  --workers LIST            comma-separated HOST:PORT of workers started with\n"
          "                            --listen; reconnected when they come back\n"
          "  --spool DIR               job inputs, state and results (default ./texsyn-spool)\n"
          "  --jobs N                  jobs run at once, 1..64 (default 2)\n"
          "  --threads N               scan threads used when no worker is ready (default 2)\n"
          "  --calibrate-ms MS         calibration scan per worker, 1..10000 (default 200)\n"
          "  --rebalance-tolerance F   rate deviation that counts, 0.01..10 (default 0.25)\n"
          "  --rebalance-after S       seconds a deviation must persist before slices are\n"
          "                            resized, 0..3600 (default 3); shorter spikes are ignored\n"
          "  --batch-timeout S         floor of a batch's deadline, 0.01..3600 (default 2);\n"
          "                            the deadline is 8x the batch's expected scan time\n"
          "  --max-redispatch N        a batch that loses workers N times in a row fails\n"
          "                            its job instead of the pool, 1..1000 (default 5)\n"
          "  --max-workers N           pool size, 1..4096 (default 256); a worker past it is\n"
          "                            refused before it is calibrated\n"
          "  --pipeline-queries N      queries per batch frame, 1..1048576 (default 256)\n"
          "  --heartbeat S             ping a worker silent this long; no answer within\n"
          "                            2S+1 s drops it, 0..3600 (default 2; 0 = off)\n"
          "  --max-frame BYTES         largest accepted frame payload (default %u)\n"
          "  --max-pixels N            largest reference or output image (default %llu)\n"
          "  --max-client-jobs N       unfinished jobs one client may have, 0..1000000\n"
          "                            (default 100; 0 = no limit)\n"
          "  --max-spool BYTES         disk the spool's jobs may use, e.g. 500M, 20G\n"
          "                            (default 16G; 0 = no limit); texsyn delete frees it;\n"
          "                            one job may reserve at most half of it\n"
          "  --max-input-memory BYTES  what one job's input images may decode to, checked\n"
          "                            from their headers before decoding (default 4G;\n"
          "                            0 = no limit)\n"
          "  --keep-ended TIME         remove a finished job (done, failed or canceled) and\n"
          "                            its files this long after it ended: seconds, or with\n"
          "                            a unit: 90s, 30m, 12h, 7d (default: keep forever;\n"
          "                            texsyn delete ID or delete --ended removes them)\n"
          "  --checkpoint-interval S   checkpoint a running job inside a level every S\n"
          "                            seconds of work, 0..86400 (default 5; 0 = after\n"
          "                            whole levels only): a restart redoes at most that\n"
          "                            much of a job\n"
          "  --stop-grace S            on SIGTERM, wait up to S seconds, 0..3600 (default\n"
          "                            10), for each running job to finish its step and\n"
          "                            save a checkpoint there; a job still busy then is\n"
          "                            stopped and resumes from its last checkpoint\n"
          "  --secret-file PATH        an admin key, or the one secret every client and\n"
          "                            worker shares (owner-only file, 32 bytes or more);\n"
          "                            without keys only loopback peers are accepted\n"
          "                            (protected mode)\n"
          "  --keys DIR                keys peers prove, one per DIR/*.key file made with\n"
          "                            --gen-secret: admin, worker, client (its name owns\n"
          "                            its jobs), page (the --http page only); SIGHUP\n"
          "                            reads them again (SECURITY.md)\n"
          "  --gen-secret KIND[:NAME] PATH\n"
          "                            write a fresh key (admin, worker, client or page;\n"
          "                            NAME defaults to PATH's file name less .key) to\n"
          "                            PATH, mode 0600, never over a file; then exit\n"
          "  --modbus [ADDR:]PORT      serve the monitoring register map over Modbus TCP\n"
          "                            (off by default; PORT or :PORT listens on loopback,\n"
          "                            *:PORT on every interface)\n"
          "  --modbus-allow CIDR,...   peers besides loopback that may connect to the Modbus\n"
          "                            plane (others are closed at accept), e.g.\n"
          "                            10.1.0.0/16,192.168.1.7\n"
          "  --modbus-control          accept coil writes (pause) on the Modbus plane; needs\n"
          "                            --modbus-allow (give 127.0.0.1 for loopback only)\n"
          "  --modbus-poll S           read each worker's Modbus registers this often:\n"
          "                            drain, liveness, load, 0..3600 (default 1; 0 = off)\n"
          "  --rebalance-from WHAT     what may resize slices: batches (rates timed on the\n"
          "                            data plane), modbus (changes of the workers' CPU\n"
          "                            shares) or both (default both)\n"
          "  --http [ADDR:]PORT        serve the read-only operations page (jobs, pool,\n"
          "                            /metrics for Prometheus); off by default; PORT or\n"
          "                            :PORT listens on loopback; with keys it needs a\n"
          "                            page or admin key; beyond loopback only with HTTPS\n"
          "  --http-cert FILE          HTTPS for --http: the certificate chain (PEM)\n"
          "  --http-key FILE           HTTPS for --http: its private key (PEM)\n"
          "  --quiet                   no startup line\n"
          "  --version                 the texsyn release and wire protocol version\n",
          TS_FRAME_DEFAULT_MAX, (unsigned long long)TS_IMAGE_DEFAULT_MAX_PIXELS);
}

typedef struct {
  const char *listen, *workers, *spool, *secret_file, *keys, *gen_secret, *modbus, *http, *http_cert, *http_key;
  int jobs, quiet, modbus_control;
  ts_mb_allow modbus_allow; /* n == 0: loopback only */
  uint64_t max_pixels, max_spool, max_input;
  uint32_t max_client_jobs;
  double checkpoint_interval, stop_grace, keep_ended;
  ts_cluster_opts co;
} server_opts;

static int num(const char *opt, const char *s, double lo, double hi, double *out) {
  double v;
  if (ts_parse_double(s, &v) != 0 || !(v >= lo && v <= hi)) {
    fprintf(stderr, "texsyn-server: %s %s: need a number in %g..%g\n", opt, s, lo, hi);
    return -1;
  }
  *out = v;
  return 0;
}

/* A byte count with an optional binary suffix: 512, 64K, 100M, 16G, 2T. */
static int bytes_opt(const char *opt, const char *s, uint64_t *out) {
  if (ts_parse_bytes(s, out) == 0) return 0;
  fprintf(stderr, "texsyn-server: %s %s: need a byte count such as 500M or 20G\n", opt, s);
  return -1;
}

/* A duration: seconds, or a number with a unit s, m, h or d; more than 0
 * and at most 100 years. */
static int duration_opt(const char *opt, const char *s, double *out) {
  static const struct {
    char unit;
    double seconds;
  } units[] = {{'s', 1}, {'m', 60}, {'h', 3600}, {'d', 86400}};
  char *end;
  errno = 0;
  double v = strtod(s, &end);
  int ok = errno == 0 && end != s && (*end == '\0' || end[1] == '\0');
  if (ok && *end != '\0') {
    size_t i = 0;
    while (i < sizeof(units) / sizeof(units[0]) && units[i].unit != *end) i++;
    ok = i < sizeof(units) / sizeof(units[0]);
    if (ok) v *= units[i].seconds;
  }
  if (!ok || !(v > 0 && v <= 100 * 365 * 86400.0)) {
    fprintf(stderr, "texsyn-server: %s %s: need a duration above 0 such as 3600, 90s, 30m, 12h or 7d\n", opt, s);
    return -1;
  }
  *out = v;
  return 0;
}

static int modbus_allow(const char *s, ts_mb_allow *a) {
  char err[TS_ERR_LEN];
  if (ts_mb_allow_parse(s, a, err) == 0) return 0;
  fprintf(stderr, "texsyn-server: %s\n", err);
  return -1;
}

static int rebalance_from(const char *s, int *out) {
  if (strcmp(s, "both") == 0) *out = TS_REBALANCE_BATCHES | TS_REBALANCE_MODBUS;
  else if (strcmp(s, "batches") == 0) *out = TS_REBALANCE_BATCHES;
  else if (strcmp(s, "modbus") == 0) *out = TS_REBALANCE_MODBUS;
  else {
    fprintf(stderr, "texsyn-server: --rebalance-from %s: need both, batches or modbus\n", s);
    return -1;
  }
  return 0;
}

static int parse_opts(int argc, char **argv, server_opts *o) {
  enum { O_LISTEN = 256, O_WORKERS, O_SPOOL, O_JOBS, O_THREADS, O_CAL, O_TOL, O_AFTER, O_BT, O_REDISPATCH, O_MAX_WORKERS, O_PIPE, O_HB, O_FRAME, O_PIX, O_CLIENT_JOBS, O_SPOOL_MAX, O_MAX_INPUT, O_KEEP, O_CKPT, O_GRACE, O_SECRET, O_KEYS, O_GEN_SECRET, O_HTTP_CERT, O_HTTP_KEY, O_MODBUS, O_MB_ALLOW, O_MB_CONTROL, O_MB_POLL, O_REBAL_FROM, O_HTTP, O_QUIET, O_HELP, O_VERSION };
  static const struct option longopts[] = {
      {"listen", required_argument, 0, O_LISTEN}, {"workers", required_argument, 0, O_WORKERS},
      {"spool", required_argument, 0, O_SPOOL}, {"jobs", required_argument, 0, O_JOBS},
      {"threads", required_argument, 0, O_THREADS}, {"calibrate-ms", required_argument, 0, O_CAL},
      {"rebalance-tolerance", required_argument, 0, O_TOL}, {"rebalance-after", required_argument, 0, O_AFTER},
      {"batch-timeout", required_argument, 0, O_BT}, {"pipeline-queries", required_argument, 0, O_PIPE},
      {"heartbeat", required_argument, 0, O_HB},
      {"max-redispatch", required_argument, 0, O_REDISPATCH},
      {"max-workers", required_argument, 0, O_MAX_WORKERS},
      {"max-frame", required_argument, 0, O_FRAME}, {"max-pixels", required_argument, 0, O_PIX},
      {"max-client-jobs", required_argument, 0, O_CLIENT_JOBS}, {"max-spool", required_argument, 0, O_SPOOL_MAX},
      {"max-input-memory", required_argument, 0, O_MAX_INPUT},
      {"keep-ended", required_argument, 0, O_KEEP},
      {"checkpoint-interval", required_argument, 0, O_CKPT}, {"stop-grace", required_argument, 0, O_GRACE},
      {"secret-file", required_argument, 0, O_SECRET}, {"keys", required_argument, 0, O_KEYS},
      {"gen-secret", required_argument, 0, O_GEN_SECRET}, {"http-cert", required_argument, 0, O_HTTP_CERT},
      {"http-key", required_argument, 0, O_HTTP_KEY},
      {"modbus", required_argument, 0, O_MODBUS}, {"modbus-control", no_argument, 0, O_MB_CONTROL},
      {"modbus-allow", required_argument, 0, O_MB_ALLOW}, {"modbus-poll", required_argument, 0, O_MB_POLL}, {"rebalance-from", required_argument, 0, O_REBAL_FROM},
      {"http", required_argument, 0, O_HTTP},
      {"quiet", no_argument, 0, O_QUIET}, {"help", no_argument, 0, O_HELP},
      {"version", no_argument, 0, O_VERSION}, {0, 0, 0, 0}};
  memset(o, 0, sizeof(*o));
  o->listen = "127.0.0.1:7070";
  o->spool = "texsyn-spool";
  o->jobs = 2;
  o->max_pixels = TS_IMAGE_DEFAULT_MAX_PIXELS;
  o->max_client_jobs = 100;
  o->max_spool = 16ull << 30;
  o->max_input = 4ull << 30;
  o->checkpoint_interval = 5;
  o->stop_grace = 10;
  ts_cluster_opts_default(&o->co);
  opterr = 0;
  int c;
  double v;
  while ((c = getopt_long(argc, argv, "h", longopts, NULL)) != -1) {
    int rc = 0;
    switch (c) {
    case O_LISTEN: o->listen = optarg; break;
    case O_WORKERS: o->workers = optarg; break;
    case O_SPOOL: o->spool = optarg; break;
    case O_JOBS: rc = num("--jobs", optarg, 1, 64, &v); o->jobs = (int)v; break;
    case O_THREADS: rc = num("--threads", optarg, 1, 1024, &v); o->co.local_threads = (int)v; break;
    case O_CAL: rc = num("--calibrate-ms", optarg, 1, 10000, &v); o->co.calib_millis = (uint32_t)v; break;
    case O_TOL: rc = num("--rebalance-tolerance", optarg, 0.01, 10, &o->co.tolerance); break;
    case O_AFTER: rc = num("--rebalance-after", optarg, 0, 3600, &o->co.persist); break;
    case O_BT: rc = num("--batch-timeout", optarg, 0.01, 3600, &o->co.batch_timeout); break;
    case O_REDISPATCH: rc = num("--max-redispatch", optarg, 1, 1000, &v); o->co.max_redispatch = (uint32_t)v; break;
    case O_MAX_WORKERS:
      rc = num("--max-workers", optarg, 1, TS_CLUSTER_MAX_WORKERS, &v);
      o->co.max_workers = (uint32_t)v;
      break;
    case O_PIPE: rc = num("--pipeline-queries", optarg, 1, 1 << 20, &v); o->co.pipeline_queries = (uint32_t)v; break;
    case O_HB: rc = num("--heartbeat", optarg, 0, 3600, &o->co.heartbeat); break;
    case O_FRAME: rc = num("--max-frame", optarg, 1024, 4294967295.0, &v); o->co.max_frame = (uint32_t)v; break;
    case O_PIX: rc = num("--max-pixels", optarg, 1, 1e15, &v); o->max_pixels = (uint64_t)v; break;
    case O_CLIENT_JOBS: rc = num("--max-client-jobs", optarg, 0, 1e6, &v); o->max_client_jobs = (uint32_t)v; break;
    case O_SPOOL_MAX: rc = bytes_opt("--max-spool", optarg, &o->max_spool); break;
    case O_MAX_INPUT: rc = bytes_opt("--max-input-memory", optarg, &o->max_input); break;
    case O_KEEP: rc = duration_opt("--keep-ended", optarg, &o->keep_ended); break;
    case O_CKPT: rc = num("--checkpoint-interval", optarg, 0, 86400, &o->checkpoint_interval); break;
    case O_GRACE: rc = num("--stop-grace", optarg, 0, 3600, &o->stop_grace); break;
    case O_SECRET: o->secret_file = optarg; break;
    case O_KEYS: o->keys = optarg; break;
    case O_GEN_SECRET: o->gen_secret = optarg; break;
    case O_HTTP_CERT: o->http_cert = optarg; break;
    case O_HTTP_KEY: o->http_key = optarg; break;
    case O_MODBUS: o->modbus = optarg; break;
    case O_MB_CONTROL: o->modbus_control = 1; break;
    case O_MB_ALLOW: rc = modbus_allow(optarg, &o->modbus_allow); break;
    case O_MB_POLL: rc = num("--modbus-poll", optarg, 0, 3600, &o->co.modbus_poll); break;
    case O_REBAL_FROM: rc = rebalance_from(optarg, &o->co.rebalance_from); break;
    case O_HTTP: o->http = optarg; break;
    case O_QUIET: o->quiet = 1; break;
    case O_HELP: case 'h': usage(stdout); exit(0);
    case O_VERSION: ts_version_print("texsyn-server"); exit(0);
    default:
      fprintf(stderr, "texsyn-server: %s: unknown option or missing value (see --help)\n", argv[optind - 1]);
      return -1;
    }
    if (rc != 0) return -1;
  }
  if (o->gen_secret != NULL && optind != argc - 1) {
    fprintf(stderr, "texsyn-server: --gen-secret %s: give the key file's PATH after it, and nothing else\n",
            o->gen_secret);
    return -1;
  }
  if (o->gen_secret == NULL && optind < argc) {
    fprintf(stderr, "texsyn-server: unexpected argument '%s'\n", argv[optind]);
    return -1;
  }
  if ((o->http_cert != NULL) != (o->http_key != NULL) || (o->http_cert != NULL && o->http == NULL)) {
    fprintf(stderr, "texsyn-server: --http-cert and --http-key go together, with --http\n");
    return -1;
  }
  if (o->modbus_control && o->modbus_allow.n == 0) {
    fprintf(stderr, "texsyn-server: --modbus-control needs --modbus-allow CIDR,... naming who may write coils "
                    "(--modbus-allow 127.0.0.1 for loopback only): Modbus TCP carries no password\n");
    return -1;
  }
  return 0;
}

/* --gen-secret KIND[:NAME] PATH: writes the key and says what it is. */
static int gen_secret(const char *spec, const char *path) {
  char err[TS_ERR_LEN];
  ts_principal who;
  if (ts_auth_init(err) != 0 || ts_auth_generate(spec, path, &who, err) != 0) {
    fprintf(stderr, "texsyn-server: %s\n", err);
    return 1;
  }
  printf("wrote %s key '%s' to %s\n", ts_auth_kind_name(who.kind), who.name, path);
  return 0;
}

/* The coordinator's keys: --secret-file and --keys DIR, read again on
 * SIGHUP by a thread of its own (the signal is blocked everywhere else),
 * so a key is added or retired without a restart and without a job lost. */
static ts_keyring *g_ring;

static void *reload_thread(void *arg) {
  sigset_t *set = arg;
  for (;;) {
    int sig;
    if (sigwait(set, &sig) != 0) continue;
    char err[TS_ERR_LEN];
    uint32_t n[5];
    if (ts_keyring_reload(g_ring, err) != 0) {
      ts_log("SIGHUP: keys not reloaded, the ones in use stay: %s", err);
      continue;
    }
    ts_keyring_counts(g_ring, n);
    ts_log("SIGHUP: keys reloaded: %u admin, %u worker, %u client, %u page", n[TS_KEY_ADMIN], n[TS_KEY_WORKER],
           n[TS_KEY_CLIENT], n[TS_KEY_PAGE]);
  }
  return NULL;
}

static int load_keys(const server_opts *o, char *err) {
  if (o->secret_file == NULL && o->keys == NULL) return 0;
  int rc = ts_keyring_create(&g_ring, o->secret_file, o->keys, err);
  if (rc != 0) return rc;
  g_server.auth.enabled = 1;
  g_server.auth.ring = g_ring;
  static sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGHUP);
  pthread_sigmask(SIG_BLOCK, &set, NULL); /* before any other thread starts */
  pthread_t t;
  if (pthread_create(&t, NULL, reload_thread, &set) != 0) return ts_error(err, TS_ENOMEM, "cannot start a thread");
  pthread_detach(t);
  return 0;
}

static int add_workers(ts_cluster *c, const char *list) {
  char buf[4096], err[TS_ERR_LEN];
  snprintf(buf, sizeof(buf), "%s", list);
  char *save = NULL;
  for (char *a = strtok_r(buf, ",", &save); a != NULL; a = strtok_r(NULL, ",", &save))
    if (ts_cluster_add_address(c, a, err) != 0) {
      fprintf(stderr, "texsyn-server: --workers: %s\n", err);
      return -1;
    }
  return 0;
}

/* Starts the Modbus plane; at gets HOST:PORT for the ready line. */
static int start_modbus(const server_opts *o, char *at, char *err) {
  char addr[TS_NET_ADDR_LEN], host[TS_NET_ADDR_LEN - 8];
  int port;
  int rc = ts_mb_listen_addr(o->modbus, addr, sizeof(addr), host, sizeof(host), err);
  if (rc == 0)
    rc = ts_smon_start(addr, o->modbus_control, o->modbus_allow.n > 0 ? &o->modbus_allow : NULL, g_server.jobs, g_server.cluster, o->co.local_threads, ts_warn_msg,
                       &port, err);
  if (rc != 0) return rc;
  snprintf(at, TS_NET_ADDR_LEN, "%s:%d", host, port);
  ts_log("modbus plane on %s%s", at, o->modbus_control ? ", coil writes accepted" : "");
  return 0;
}

/* Starts the operations page; at gets HOST:PORT for the ready line. */
static int start_http(const server_opts *o, char *at, char *err) {
  char addr[TS_NET_ADDR_LEN], host[TS_NET_ADDR_LEN - 8];
  int port;
  int rc = ts_http_listen_addr(o->http, addr, sizeof(addr), host, sizeof(host), err);
  if (rc == 0)
    rc = ts_http_start(addr, &g_server.auth, o->http_cert, o->http_key, g_server.jobs, g_server.cluster,
                       o->co.local_threads, &port, err);
  if (rc != 0) return rc;
  /* An IPv6 host in brackets: the address is a URL's authority. */
  snprintf(at, TS_NET_ADDR_LEN, strchr(host, ':') ? "[%s]:%d" : "%s:%d", host, port);
  ts_log("http page on %s%s%s", at, o->http_cert ? " over HTTPS" : "",
         g_server.auth.enabled ? ", pages need a page or admin key" : ", loopback peers only");
  return 0;
}

int main(int argc, char **argv) {
  ts_log_init("texsyn-server", stderr, 0); /* --quiet drops the ready line only */
  /* The spool holds users' images and results: directories 0700, files
   * 0600, whatever umask the daemon was started with. */
  umask(077);
  server_opts o;
  if (parse_opts(argc, argv, &o) != 0) return 2;
  ts_connset_init(&g_conns);
  ts_gate_init(&g_gate, "job port", ts_warn_msg);
  char err[TS_ERR_LEN];
  if (o.gen_secret != NULL) return gen_secret(o.gen_secret, argv[argc - 1]);
  if (ts_auth_init(err) != 0 || load_keys(&o, err) != 0) {
    fprintf(stderr, "texsyn-server: %s\n", err);
    return 2;
  }
  o.co.auth = &g_server.auth;
  /* The image library is loaded now rather than at the first submit: a
   * coordinator that cannot read images must say so at start, not accept
   * jobs and fail each one, and resuming the spool reads references
   * anyway. The 0.2 s it costs is paid once, before the ready line. */
  if (ts_image_lib_load(err) != 0) {
    fprintf(stderr, "texsyn-server: %s\n", err);
    return 1;
  }
  ts_stop_on_signals(&g_stop);
  signal(SIGPIPE, SIG_IGN);
  int lfd, port;
  if (ts_net_listen(o.listen, &lfd, &port, err) != 0) {
    fprintf(stderr, "texsyn-server: %s\n", err);
    return 1;
  }
  ts_stop_listener(lfd);
  g_server.max_frame = o.co.max_frame;
  if (ts_cluster_create(&g_server.cluster, &o.co, err) != 0) {
    fprintf(stderr, "texsyn-server: %s\n", err);
    return 1;
  }
  if (o.workers != NULL && add_workers(g_server.cluster, o.workers) != 0) return 2;
  ts_jobs_opts jo = {o.spool, o.jobs, o.max_pixels, o.max_client_jobs, o.max_spool, g_server.cluster,
                     o.checkpoint_interval, o.stop_grace, o.keep_ended, o.max_input};
  if (ts_jobs_create(&g_server.jobs, &jo, err) != 0) {
    fprintf(stderr, "texsyn-server: %s\n", err);
    return 1;
  }
  char modbus_at[TS_NET_ADDR_LEN] = "";
  if (o.modbus != NULL && start_modbus(&o, modbus_at, err) != 0) {
    fprintf(stderr, "texsyn-server: --modbus %s: %s\n", o.modbus, err);
    return 1;
  }
  char http_at[TS_NET_ADDR_LEN] = "";
  if (o.http != NULL && start_http(&o, http_at, err) != 0) {
    fprintf(stderr, "texsyn-server: --http %s: %s\n", o.http, err);
    return 1;
  }
  char host[TS_NET_ADDR_LEN];
  int p0;
  ts_net_split(o.listen, host, sizeof(host), &p0, err);
  ts_log("listening on %s:%d, spool %s, %s", host, port, o.spool,
        g_server.auth.enabled ? "peers must prove the shared secret" : "no secret: loopback peers only");
  if (ts_auth_listen_warning(&g_server.auth, lfd, err)) ts_log("%s", err);
  if (!o.quiet) { /* last: whoever waits for this line finds the log written */
    printf("texsyn-server listening on %s:%d%s%s%s%s%s%s\n", host, port, modbus_at[0] ? " (modbus " : "", modbus_at,
           modbus_at[0] ? ")" : "", http_at[0] ? " (http " : "", http_at, http_at[0] ? ")" : "");
    fflush(stdout);
  }
  while (!atomic_load(&g_stop)) {
    accepted *a = malloc(sizeof(*a));
    if (a == NULL) break;
    if (ts_gate_accept(&g_gate, lfd, &a->fd, a->peer, sizeof(a->peer), &a->addr) != 0) {
      free(a);
      continue;
    }
    pthread_t t;
    if (ts_connset_add(&g_conns, a->fd) != 0) {
      ts_log("refused %s: %d connections open", a->peer, TS_CONNSET_MAX);
      close(a->fd);
      free(a);
      continue;
    }
    ts_gate_enter(&g_gate, a->fd, (const struct sockaddr *)&a->addr);
    if (pthread_create(&t, NULL, connection_thread, a) != 0) {
      ts_gate_leave(&g_gate, a->fd);
      ts_connset_remove(&g_conns, a->fd);
      close(a->fd);
      free(a);
      continue;
    }
    pthread_detach(t);
  }
  ts_log("shutting down");
  ts_stop_listener(-1); /* a second signal must not shut a reused fd number */
  close(lfd);
  ts_connset_close_all(&g_conns);
  if (o.modbus != NULL) ts_smon_stop();
  ts_http_stop(); /* before the jobs and the pool its threads read */
  ts_jobs_destroy(g_server.jobs);
  ts_cluster_destroy(g_server.cluster);
  ts_auth_clear(&g_server.auth);
  return 0; /* g_ring stays: the reload thread may be reading it */
}
