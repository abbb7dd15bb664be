/* http_page.h - what the operations page (http.c) says, as text: the HTML
 * status page, the same data as JSON, the Prometheus metrics, and the
 * small parsers the server needs (listen address, request path). All pure:
 * they render a snapshot taken by the caller, so they are unit-tested
 * without a daemon. */
#ifndef TS_HTTP_PAGE_H
#define TS_HTTP_PAGE_H

#include <stddef.h>
#include <stdint.h>

#include "cluster.h"
#include "jobs.h"
#include "msg.h"

/* A growing text buffer. After a failed allocation it stays as it was and
 * `failed` is set; the caller checks once at the end. */
typedef struct {
  char *buf;
  size_t len, cap;
  int failed;
} ts_text;

void ts_text_init(ts_text *t);
void ts_text_add(ts_text *t, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
void ts_text_free(ts_text *t);
/* s as text inside HTML elements and double-quoted attributes. */
void ts_text_html(ts_text *t, const char *s);
/* s as a JSON string, quotes included. */
void ts_text_json(ts_text *t, const char *s);

/* Everything the pages show, read through the thread-safe snapshots of
 * jobs.h and cluster.h at one moment. */
typedef struct {
  double uptime;                            /* seconds since the coordinator started */
  int threads, simd;                        /* local scan threads, SIMD level (l1.h ts_simd) */
  ts_cluster_stats stats;                   /* pool totals */
  uint32_t counts[TS_JOB_STATE_COUNT];      /* jobs in the spool by state */
  int have_current;                         /* cur is valid */
  ts_job_status cur;                        /* ts_jobs_current */
  int paused;                               /* the queue is held */
  const ts_job_status *jobs;                /* the newest jobs, oldest first */
  uint32_t njobs;
  const ts_worker_info *workers;            /* the pool */
  uint32_t nworkers;
  const ts_job_frame *frames;               /* the newest jobs that are video frames, oldest first */
  uint32_t nframes;
} ts_http_snapshot;

/* The HTML status page (no external resources; it reloads itself every
 * refresh_s seconds). */
void ts_http_render_html(ts_text *t, const ts_http_snapshot *s, int refresh_s);
/* The same data as one JSON object. */
void ts_http_render_json(ts_text *t, const ts_http_snapshot *s);
/* Prometheus text exposition format 0.0.4. */
void ts_http_render_metrics(ts_text *t, const ts_http_snapshot *s);

/* What a request path asks for. Query strings are not part of url
 * (libmicrohttpd splits them off). */
typedef enum {
  TS_HTTP_NOT_FOUND = 0,
  TS_HTTP_INDEX,   /* / */
  TS_HTTP_STATUS,  /* /status.json */
  TS_HTTP_METRICS, /* /metrics */
  TS_HTTP_THUMB,   /* /jobs/ID/thumb.png: *job gets ID */
  TS_HTTP_SMALL,   /* /jobs/ID/small.png: *job gets ID */
} ts_http_route_kind;

ts_http_route_kind ts_http_route(const char *url, uint64_t *job);

/* The address an --http argument means: PORT or :PORT is loopback
 * (127.0.0.1), ADDR:PORT is that. Writes HOST:PORT to out and the host
 * alone to host (for display). 0 or TS_EINVAL naming the problem. */
int ts_http_listen_addr(const char *arg, char *out, size_t cap, char *host, size_t hostcap, char *err);

#endif
