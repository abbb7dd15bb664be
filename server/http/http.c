/* http.c - see http.h. Rendering is in http_page.c, the secret check in
 * http_auth.c, thumbnails in thumb.c; this file is the libmicrohttpd
 * glue: who asks, for what, and the response. */
#include "http.h"

#include <microhttpd.h>
#include <sodium.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "error.h"
#include "http_auth.h"
#include "http_deadline.h"
#include "http_page.h"
#include "l1.h"
#include "log.h"
#include "net.h"
#include "thumb.h"
#include "util.h"

#define HTTP_MAX_JOBS 100    /* the newest jobs listed; the spool may hold thousands */
#define HTTP_MAX_FRAMES 2048 /* the newest jobs that are video frames, grouped as sequences */
#define HTTP_REFRESH_S 2     /* the page reloads itself this often */
#define HTTP_CONNECTIONS 512 /* at once: each costs a socket, not a thread */
#define HTTP_PER_ADDRESS 16  /* at once from one address; a page load takes a few */
#define HTTP_THREADS 4       /* poll every connection; a thumbnail being made holds up one */
#define HTTP_TIMEOUT_S 10    /* a connection silent this long is closed */
#define HTTP_REQUEST_S 10    /* and one whose request is not in this long after it opened */
#define HTTP_PEM_MAX (1 << 20)

static struct {
  struct MHD_Daemon *daemon;
  const ts_auth *auth;
  ts_jobs *jobs;
  ts_cluster *cluster;
  int threads, simd;
  double started;
  char *cert_pem, *key_pem;
} g_http;

/* The private key is wiped before it goes back to the allocator. */
static void free_pems_of(char *cert, char *key) {
  free(cert);
  if (key != NULL) sodium_memzero(key, strlen(key));
  free(key);
}

static void free_pems(void) {
  free_pems_of(g_http.cert_pem, g_http.key_pem);
  g_http.cert_pem = g_http.key_pem = NULL;
}

/* ---- responses ----------------------------------------------------------------- */

/* How long a browser may keep a thumbnail: a finished job's result never
 * changes and its id is never given to another job, so the page, which
 * reloads every HTTP_REFRESH_S seconds with a strip of thumbnails per video
 * sequence, does not fetch them again each time. Everything else is
 * fetched afresh. */
#define HTTP_THUMB_CACHE "private, max-age=3600"
#define HTTP_NO_CACHE "no-store"

/* Queues body (malloc'ed; libmicrohttpd frees it) with status, type and
 * Cache-Control value. */
static enum MHD_Result respond_cached(struct MHD_Connection *c, unsigned status, const char *type, const char *cache,
                                      void *body, size_t len) {
  struct MHD_Response *r = MHD_create_response_from_buffer(len, body, MHD_RESPMEM_MUST_FREE);
  if (r == NULL) {
    free(body);
    return MHD_NO;
  }
  MHD_add_response_header(r, MHD_HTTP_HEADER_CONTENT_TYPE, type);
  MHD_add_response_header(r, MHD_HTTP_HEADER_CACHE_CONTROL, cache);
  if (status == MHD_HTTP_UNAUTHORIZED)
    MHD_add_response_header(r, MHD_HTTP_HEADER_WWW_AUTHENTICATE, "Basic realm=\"texsyn\", charset=\"UTF-8\"");
  if (status == MHD_HTTP_METHOD_NOT_ALLOWED) MHD_add_response_header(r, MHD_HTTP_HEADER_ALLOW, "GET, HEAD");
  enum MHD_Result rc = MHD_queue_response(c, status, r);
  MHD_destroy_response(r);
  return rc;
}

static enum MHD_Result respond(struct MHD_Connection *c, unsigned status, const char *type, void *body, size_t len) {
  return respond_cached(c, status, type, HTTP_NO_CACHE, body, len);
}

/* A plain-text error naming the problem. */
static enum MHD_Result respond_error(struct MHD_Connection *c, unsigned status, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static enum MHD_Result respond_error(struct MHD_Connection *c, unsigned status, const char *fmt, ...) {
  char msg[TS_ERR_LEN + 64];
  va_list ap;
  va_start(ap, fmt);
  int n = vsnprintf(msg, sizeof(msg), fmt, ap);
  va_end(ap);
  size_t len = n < 0 ? 0 : (size_t)n < sizeof(msg) - 1 ? (size_t)n : sizeof(msg) - 2;
  msg[len++] = '\n';
  char *body = malloc(len);
  if (body == NULL) return MHD_NO;
  memcpy(body, msg, len);
  return respond(c, status, "text/plain; charset=utf-8", body, len);
}

static enum MHD_Result respond_text(struct MHD_Connection *c, ts_text *t, const char *type) {
  if (t->failed) {
    ts_text_free(t);
    return respond_error(c, MHD_HTTP_INTERNAL_SERVER_ERROR, "out of memory");
  }
  return respond(c, MHD_HTTP_OK, type, t->buf, t->len); /* the buffer goes to the response */
}

/* ---- pages ------------------------------------------------------------------------ */

/* Fills s from the snapshots; its arrays are malloc'ed (snapshot_free). */
static int snapshot_take(ts_http_snapshot *s) {
  memset(s, 0, sizeof(*s));
  ts_job_status *jobs = malloc(sizeof(*jobs) * HTTP_MAX_JOBS);
  ts_worker_info *workers = malloc(sizeof(*workers) * TS_POOL_MAX_REPORT);
  ts_job_frame *frames = malloc(sizeof(*frames) * HTTP_MAX_FRAMES);
  if (jobs == NULL || workers == NULL || frames == NULL) {
    free(jobs);
    free(workers);
    free(frames);
    return TS_ENOMEM;
  }
  s->uptime = ts_now() - g_http.started;
  s->threads = g_http.threads;
  s->simd = g_http.simd;
  ts_cluster_stats_get(g_http.cluster, &s->stats);
  ts_jobs_counts(g_http.jobs, s->counts);
  s->have_current = ts_jobs_current(g_http.jobs, &s->cur) == 0;
  s->paused = ts_jobs_paused(g_http.jobs);
  s->njobs = ts_jobs_list_recent(g_http.jobs, jobs, HTTP_MAX_JOBS);
  s->nworkers = ts_cluster_info(g_http.cluster, workers, TS_POOL_MAX_REPORT);
  s->nframes = ts_jobs_list_frames(g_http.jobs, frames, HTTP_MAX_FRAMES);
  s->jobs = jobs;
  s->workers = workers;
  s->frames = frames;
  return 0;
}

static void snapshot_free(ts_http_snapshot *s) {
  free((void *)s->jobs);
  free((void *)s->workers);
  free((void *)s->frames);
}

static enum MHD_Result serve_page(struct MHD_Connection *c, ts_http_route_kind page) {
  ts_http_snapshot s;
  if (snapshot_take(&s) != 0) return respond_error(c, MHD_HTTP_INTERNAL_SERVER_ERROR, "out of memory");
  ts_text t;
  ts_text_init(&t);
  const char *type;
  if (page == TS_HTTP_INDEX) {
    ts_http_render_html(&t, &s, HTTP_REFRESH_S);
    type = "text/html; charset=utf-8";
  } else if (page == TS_HTTP_STATUS) {
    ts_http_render_json(&t, &s);
    type = "application/json";
  } else {
    ts_http_render_metrics(&t, &s);
    type = "text/plain; version=0.0.4; charset=utf-8";
  }
  snapshot_free(&s);
  return respond_text(c, &t, type);
}

static enum MHD_Result serve_thumb(struct MHD_Connection *c, uint64_t id, const char *name, int side) {
  uint8_t *png;
  size_t len;
  char err[TS_ERR_LEN];
  int growing = 0;
  int rc = ts_thumb_get(g_http.jobs, id, name, side, &png, &len, &growing, err);
  if (rc == TS_ENOENT || rc == TS_EINVAL) return respond_error(c, MHD_HTTP_NOT_FOUND, "%s", err);
  if (rc != 0) {
    ts_log("http: thumbnail of job %llu: %s", (unsigned long long)id, err);
    return respond_error(c, MHD_HTTP_INTERNAL_SERVER_ERROR, "%s", err);
  }
  return respond_cached(c, MHD_HTTP_OK, "image/png", growing ? "no-store" : HTTP_THUMB_CACHE, png, len);
}

/* ---- requests ----------------------------------------------------------------------- */

/* 0 if the peer may see pages: protected mode (no secret) lets loopback
 * peers in; with a secret, anyone who proves it. *status and err say why
 * not. */
static int allowed(struct MHD_Connection *c, unsigned *status, char *err) {
  const union MHD_ConnectionInfo *ci = MHD_get_connection_info(c, MHD_CONNECTION_INFO_CLIENT_ADDRESS);
  *status = MHD_HTTP_FORBIDDEN;
  if (ci == NULL || ci->client_addr == NULL) return ts_error(err, TS_EAUTH, "peer address unknown");
  int rc = ts_auth_peer_allowed(g_http.auth, ci->client_addr, err);
  if (rc != 0 || !g_http.auth->enabled) return rc;
  /* Only a page or an admin key: a client's or worker's key is for the data plane. */
  *status = MHD_HTTP_UNAUTHORIZED;
  const char *h = MHD_lookup_connection_value(c, MHD_HEADER_KIND, MHD_HTTP_HEADER_AUTHORIZATION);
  return ts_http_auth_check(g_http.auth, h, err);
}

static enum MHD_Result on_request(void *cls, struct MHD_Connection *c, const char *url, const char *method,
                                  const char *version, const char *upload, size_t *upload_len, void **state) {
  (void)cls, (void)version, (void)upload, (void)upload_len, (void)state;
  ts_http_deadline_request_in(c);
  if (strcmp(method, MHD_HTTP_METHOD_GET) != 0 && strcmp(method, MHD_HTTP_METHOD_HEAD) != 0)
    return respond_error(c, MHD_HTTP_METHOD_NOT_ALLOWED, "%s: this server is read-only (GET and HEAD)", method);
  char err[TS_ERR_LEN];
  unsigned status;
  if (allowed(c, &status, err) != 0) return respond_error(c, status, "%s", err);
  uint64_t job = 0;
  ts_http_route_kind page = ts_http_route(url, &job);
  switch (page) {
  case TS_HTTP_NOT_FOUND:
    return respond_error(c, MHD_HTTP_NOT_FOUND, "no page %s (there are /, /status.json, /metrics and "
                                                "/jobs/ID/thumb.png, /jobs/ID/small.png)", url);
  case TS_HTTP_THUMB: return serve_thumb(c, job, "thumb.png", TS_THUMB_SIDE);
  case TS_HTTP_SMALL: return serve_thumb(c, job, "small.png", TS_THUMB_SMALL_SIDE);
  default: return serve_page(c, page);
  }
}

static void on_mhd_log(void *cls, const char *fmt, va_list ap) {
  (void)cls;
  char msg[TS_ERR_LEN];
  vsnprintf(msg, sizeof(msg), fmt, ap);
  size_t n = strlen(msg);
  if (n > 0 && msg[n - 1] == '\n') msg[n - 1] = '\0';
  /* One per refused connection, at a flood: "Server reached connection
   * limit" by the thousand. */
  static ts_log_limit limit = TS_LOG_LIMIT_INIT;
  ts_log_limited(&limit, "http: %s", msg);
}

/* A PEM file read whole, NUL-terminated (what libmicrohttpd takes). */
static int read_pem(const char *opt, const char *path, char **out, char *err) {
  uint8_t *buf;
  size_t len;
  char why[TS_ERR_LEN];
  if (ts_file_read(path, HTTP_PEM_MAX, &buf, &len, why) != 0) return ts_error(err, TS_EIO, "%s %s: %s", opt, path, why);
  char *s = realloc(buf, len + 1);
  if (s == NULL) {
    free(buf);
    return ts_error(err, TS_ENOMEM, "out of memory");
  }
  s[len] = '\0';
  *out = s;
  return 0;
}

/* With keys, a page beyond loopback needs HTTPS: a page key or an admin
 * key sent in the clear would be anyone's who watches the network. */
static int check_exposure(const ts_auth *auth, int lfd, int tls, char *err) {
  struct sockaddr_storage ss;
  socklen_t sl = sizeof(ss);
  if (!auth->enabled || tls || getsockname(lfd, (struct sockaddr *)&ss, &sl) != 0 ||
      ts_auth_is_loopback((struct sockaddr *)&ss))
    return 0;
  return ts_error(err, TS_EINVAL,
                  "the page would send its keys in the clear beyond loopback: give --http-cert and --http-key "
                  "(HTTPS), or keep --http on loopback behind a TLS reverse proxy (deploy/README.md, \"Who may look\")");
}

int ts_http_start(const char *listen, const ts_auth *auth, const char *cert, const char *key, ts_jobs *jobs,
                  ts_cluster *cluster, int threads, int *port, char *err) {
  const ts_l1_impl *simd;
  int rc = ts_l1_select(&simd, err);
  if (rc != 0) return rc;
  if (cert != NULL && MHD_is_feature_supported(MHD_FEATURE_TLS) != MHD_YES)
    return ts_error(err, TS_ENOTSUP, "this libmicrohttpd has no TLS: use a TLS reverse proxy in front of a loopback "
                    "--http (deploy/README.md, \"Who may look\")");
  char *cert_pem = NULL, *key_pem = NULL;
  if (cert != NULL && (rc = read_pem("--http-cert", cert, &cert_pem, err)) == 0)
    rc = read_pem("--http-key", key, &key_pem, err);
  int lfd = -1;
  if (rc == 0) rc = ts_net_listen(listen, &lfd, port, err);
  if (rc == 0) rc = check_exposure(auth, lfd, cert != NULL, err);
  if (rc != 0) {
    if (lfd >= 0) close(lfd);
    free_pems_of(cert_pem, key_pem);
    return rc;
  }
  char warning[TS_ERR_LEN];
  if (ts_auth_listen_warning(auth, lfd, warning)) ts_log("http: %s", warning);
  g_http.auth = auth;
  g_http.jobs = jobs;
  g_http.cluster = cluster;
  g_http.threads = threads;
  g_http.simd = simd->id;
  g_http.started = ts_now();
  if ((rc = ts_http_deadline_start(HTTP_REQUEST_S, err)) != 0) {
    close(lfd);
    free_pems_of(cert_pem, key_pem);
    return rc;
  }
  unsigned flags = MHD_USE_INTERNAL_POLLING_THREAD | MHD_USE_AUTO | MHD_USE_ERROR_LOG | (cert ? MHD_USE_TLS : 0);
  struct MHD_OptionItem tls[] = {{MHD_OPTION_HTTPS_MEM_CERT, 0, cert_pem},
                                 {MHD_OPTION_HTTPS_MEM_KEY, 0, key_pem},
                                 {MHD_OPTION_END, 0, NULL}};
  g_http.daemon = MHD_start_daemon(
      flags, 0, NULL, NULL, on_request, NULL, MHD_OPTION_EXTERNAL_LOGGER, on_mhd_log, NULL, MHD_OPTION_LISTEN_SOCKET,
      lfd, MHD_OPTION_THREAD_POOL_SIZE, (unsigned)HTTP_THREADS, MHD_OPTION_CONNECTION_LIMIT,
      (unsigned)HTTP_CONNECTIONS, MHD_OPTION_PER_IP_CONNECTION_LIMIT, (unsigned)HTTP_PER_ADDRESS,
      MHD_OPTION_CONNECTION_TIMEOUT, (unsigned)HTTP_TIMEOUT_S, MHD_OPTION_NOTIFY_CONNECTION,
      ts_http_deadline_notify, NULL, MHD_OPTION_NOTIFY_COMPLETED, ts_http_deadline_completed, NULL,
      MHD_OPTION_ARRAY, cert ? tls : tls + 2,
      MHD_OPTION_END);
  /* libmicrohttpd reads them at start; they stay until it stops. */
  g_http.cert_pem = cert_pem;
  g_http.key_pem = key_pem;
  if (g_http.daemon == NULL) {
    ts_http_deadline_stop();
    free_pems();
    close(lfd);
    return ts_error(err, TS_EIO, "libmicrohttpd could not start on %s%s (see the log above)", listen,
                    cert ? " with that certificate and key" : "");
  }
  return 0;
}

void ts_http_stop(void) {
  if (g_http.daemon == NULL) return;
  MHD_stop_daemon(g_http.daemon); /* joins its threads, closes the socket */
  g_http.daemon = NULL;
  ts_http_deadline_stop();
  free_pems();
}
