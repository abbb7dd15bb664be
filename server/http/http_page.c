/* http_page.c - see http_page.h. */
#include "http_page.h"

#include <inttypes.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "http_seq.h"
#include "l1.h"
#include "net.h"

/* ---- text buffer ----------------------------------------------------------- */

void ts_text_init(ts_text *t) { memset(t, 0, sizeof(*t)); }

void ts_text_free(ts_text *t) {
  free(t->buf);
  ts_text_init(t);
}

void ts_text_add(ts_text *t, const char *fmt, ...) {
  if (t->failed) return;
  for (;;) {
    va_list ap;
    va_start(ap, fmt);
    size_t room = t->cap - t->len;
    int n = vsnprintf(t->buf != NULL ? t->buf + t->len : NULL, room, fmt, ap);
    va_end(ap);
    if (n < 0) {
      t->failed = 1;
      return;
    }
    if ((size_t)n < room) {
      t->len += (size_t)n;
      return;
    }
    size_t cap = t->cap ? t->cap : 4096;
    while (cap - t->len <= (size_t)n) cap *= 2;
    char *b = realloc(t->buf, cap);
    if (b == NULL) {
      t->failed = 1;
      return;
    }
    t->buf = b;
    t->cap = cap;
  }
}

/* ---- escaping ---------------------------------------------------------------- */

/* Text inside HTML elements and double-quoted attributes. */
void ts_text_html(ts_text *t, const char *s) {
  for (; *s; s++) {
    switch (*s) {
    case '&': ts_text_add(t, "&amp;"); break;
    case '<': ts_text_add(t, "&lt;"); break;
    case '>': ts_text_add(t, "&gt;"); break;
    case '"': ts_text_add(t, "&quot;"); break;
    default: ts_text_add(t, "%c", *s);
    }
  }
}

/* A JSON string, quotes included; control characters as \u escapes. */
void ts_text_json(ts_text *t, const char *s) {
  ts_text_add(t, "\"");
  for (; *s; s++) {
    unsigned char c = (unsigned char)*s;
    if (c == '"' || c == '\\') ts_text_add(t, "\\%c", c);
    else if (c < 0x20) ts_text_add(t, "\\u%04x", c);
    else ts_text_add(t, "%c", c);
  }
  ts_text_add(t, "\"");
}

/* A Prometheus label value: backslash, double quote and newline escaped
 * (exposition format 0.0.4). */
static void add_label(ts_text *t, const char *s) {
  for (; *s; s++) {
    if (*s == '\\' || *s == '"') ts_text_add(t, "\\%c", *s);
    else if (*s == '\n') ts_text_add(t, "\\n");
    else ts_text_add(t, "%c", *s);
  }
}

/* ---- shared formatting ------------------------------------------------------- */

static const char *simd_name(int id) {
  const ts_l1_impl *impl = id >= 0 && id < TS_SIMD_COUNT ? ts_l1_impl_get((ts_simd)id) : NULL;
  return impl != NULL ? impl->name : "?";
}

/* Bytes per second for people: 812.4 MB/s, 1.92 GB/s. */
static void add_rate(ts_text *t, uint64_t bytes_per_s) {
  double v = (double)bytes_per_s;
  if (v >= 1e9) ts_text_add(t, "%.2f GB/s", v / 1e9);
  else ts_text_add(t, "%.1f MB/s", v / 1e6);
}

static void add_duration(ts_text *t, uint64_t s) {
  if (s >= 3600) ts_text_add(t, "%" PRIu64 " h %" PRIu64 " min", s / 3600, s / 60 % 60);
  else if (s >= 60) ts_text_add(t, "%" PRIu64 " min %" PRIu64 " s", s / 60, s % 60);
  else ts_text_add(t, "%" PRIu64 " s", s);
}

/* A job's ETA: only a running job has one, and it may not be known yet. */
static void add_eta(ts_text *t, const ts_job_status *j) {
  if (j->state != TS_JOB_RUNNING) ts_text_add(t, "-");
  else if (j->eta_ms == UINT32_MAX) ts_text_add(t, "unknown");
  else add_duration(t, (j->eta_ms + 999) / 1000);
}

/* The newest job first: the order people read a queue in. */
static const ts_job_status *nth_newest(const ts_http_snapshot *s, uint32_t i) {
  return &s->jobs[s->njobs - 1 - i];
}

/* ---- HTML ---------------------------------------------------------------------- */

static const char kStyle[] =
    "body{font:14px/1.4 system-ui,sans-serif;margin:1.5em;color:#222}"
    "table{border-collapse:collapse;margin-bottom:1.5em}"
    "th,td{padding:.25em .7em;border-bottom:1px solid #ddd;text-align:left;vertical-align:middle}"
    "th{background:#f3f3f3}td.n{text-align:right;font-variant-numeric:tabular-nums}"
    "progress{width:12em}img{max-width:160px;max-height:160px;image-rendering:pixelated}"
    ".failed td,.failed{color:#a00}.running{font-weight:600}"
    ".strip img{height:48px;width:auto;max-width:none;margin:1px;vertical-align:middle}"
    "span.frame{display:inline-block;min-width:2.5em;height:48px;line-height:48px;margin:1px;text-align:center;"
    "background:#eee;color:#666;font-size:11px;vertical-align:middle}span.frame.running{background:#dde8f6}";

static void html_summary(ts_text *t, const ts_http_snapshot *s) {
  ts_text_add(t, "<p id=\"summary\">up ");
  add_duration(t, (uint64_t)s->uptime);
  ts_text_add(t, " &middot; %u workers ready &middot; pool rate ", s->stats.ready);
  add_rate(t, s->stats.rate);
  ts_text_add(t,
              " &middot; %" PRIu64 " batches &middot; %" PRIu64 " queries &middot; jobs: %u queued, %u running, "
              "%u done, %u failed, %u canceled%s</p>\n",
              s->stats.batches, s->stats.queries, s->counts[TS_JOB_QUEUED], s->counts[TS_JOB_RUNNING],
              s->counts[TS_JOB_DONE], s->counts[TS_JOB_FAILED], s->counts[TS_JOB_CANCELED],
              s->paused ? " &middot; <b>queue paused</b>" : "");
}

static void html_job(ts_text *t, const ts_job_status *j) {
  const char *state = ts_job_state_name(j->state);
  ts_text_add(t, "<tr class=\"job %s\" id=\"job-%" PRIu64 "\"><td class=n>%" PRIu64 "</td><td>", state, j->id, j->id);
  ts_text_html(t, j->engine);
  ts_text_add(t,
              "</td><td class=state>%s</td><td><progress max=\"1000\" value=\"%u\">%.1f%%</progress> "
              "<span class=percent>%.1f</span>%%</td><td>",
              state, j->permille, j->permille / 10.0, j->permille / 10.0);
  /* Counted up, as `texsyn status` shows it: the status's level counts down to 0. */
  if (j->state == TS_JOB_RUNNING && j->levels > 0)
    ts_text_add(t, "level %d of %u", j->levels - j->level, j->levels);
  if (j->text[0] != '\0') {
    ts_text_add(t, j->state == TS_JOB_RUNNING && j->levels > 0 ? ": " : "");
    ts_text_html(t, j->text);
  }
  ts_text_add(t, "</td><td class=n>");
  add_eta(t, j);
  ts_text_add(t, "</td><td>");
  /* Engines without an image result have no thumbnail, nor running jobs
   * without a growing preview (preview.h): the 404 removes it. */
  if (j->state == TS_JOB_DONE || j->state == TS_JOB_RUNNING)
    ts_text_add(t, "<img src=\"/jobs/%" PRIu64 "/thumb.png\" alt=\"job %" PRIu64 " result\" onerror=\"this.remove()\">",
                j->id, j->id);
  ts_text_add(t, "</td></tr>\n");
}

static void html_worker(ts_text *t, const ts_worker_info *w) {
  const char *state = ts_worker_state_name(w->state);
  ts_text_add(t, "<tr class=\"worker %s\"><td>", state);
  ts_text_html(t, w->addr);
  ts_text_add(t, "</td><td class=state>%s</td><td class=n>%u</td><td>%s</td><td class=n>", state, w->threads,
              simd_name(w->simd));
  add_rate(t, w->calibrated);
  ts_text_add(t, "</td><td class=n>");
  add_rate(t, w->rate);
  ts_text_add(t, "</td><td class=n>%.1f%%</td><td class=n>%" PRIu64 "</td></tr>\n", w->share / 10.0, w->batches);
}

void ts_http_render_html(ts_text *t, const ts_http_snapshot *s, int refresh_s) {
  ts_text_add(t,
              "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
              "<meta http-equiv=\"refresh\" content=\"%d\"><title>texsyn-server</title><style>%s</style></head>\n"
              "<body><h1>texsyn-server</h1>\n",
              refresh_s, kStyle);
  html_summary(t, s);
  ts_http_seqs seqs;
  if (ts_http_seqs_make(s->frames, s->nframes, &seqs) == 0) ts_http_seqs_html(t, &seqs);
  else t->failed = 1;
  ts_http_seqs_free(&seqs);
  ts_text_add(t, "<h2>Jobs</h2>\n<table id=\"jobs\"><tr><th>job</th><th>engine</th><th>state</th><th>progress</th>"
                 "<th>stage</th><th>ETA</th><th>result</th></tr>\n");
  for (uint32_t i = 0; i < s->njobs; i++) {
    html_job(t, nth_newest(s, i));
  }
  if (s->njobs == 0) ts_text_add(t, "<tr><td colspan=7>no jobs</td></tr>\n");
  ts_text_add(t, "</table>\n<h2>Pool</h2>\n<table id=\"pool\"><tr><th>worker</th><th>state</th><th>threads</th>"
                 "<th>SIMD</th><th>calibrated</th><th>rate</th><th>slice share</th><th>batches</th></tr>\n");
  for (uint32_t i = 0; i < s->nworkers; i++) html_worker(t, &s->workers[i]);
  if (s->nworkers == 0)
    ts_text_add(t, "<tr><td colspan=8>no workers: the coordinator scans with its %d local threads</td></tr>\n",
                s->threads);
  ts_text_add(t, "</table>\n</body></html>\n");
}

/* ---- JSON ----------------------------------------------------------------------- */

static void json_job(ts_text *t, const ts_job_status *j) {
  ts_text_add(t, "{\"id\":%" PRIu64 ",\"engine\":", j->id);
  ts_text_json(t, j->engine);
  ts_text_add(t, ",\"state\":\"%s\",\"permille\":%u,\"level\":%u,\"levels\":%u,\"workers\":%u,\"text\":",
              ts_job_state_name(j->state), j->permille, j->level, j->levels, j->workers);
  ts_text_json(t, j->text);
  if (j->state == TS_JOB_RUNNING && j->eta_ms != UINT32_MAX) ts_text_add(t, ",\"eta_s\":%.1f}", j->eta_ms / 1000.0);
  else ts_text_add(t, ",\"eta_s\":null}");
}

static void json_worker(ts_text *t, const ts_worker_info *w) {
  ts_text_add(t, "{\"worker\":");
  ts_text_json(t, w->addr);
  ts_text_add(t,
              ",\"state\":\"%s\",\"threads\":%u,\"simd\":\"%s\",\"calibrated\":%" PRIu64 ",\"rate\":%" PRIu64
              ",\"share_permille\":%u,\"batches\":%" PRIu64 "}",
              ts_worker_state_name(w->state), w->threads, simd_name(w->simd), w->calibrated, w->rate, w->share,
              w->batches);
}

void ts_http_render_json(ts_text *t, const ts_http_snapshot *s) {
  ts_text_add(t,
              "{\"uptime_s\":%.0f,\"threads\":%d,\"simd\":\"%s\",\"paused\":%s,\"workers_ready\":%u,\"rate\":%" PRIu64
              ",\"batches\":%" PRIu64 ",\"queries\":%" PRIu64 ",\"counts\":{",
              s->uptime, s->threads, simd_name(s->simd), s->paused ? "true" : "false", s->stats.ready, s->stats.rate,
              s->stats.batches, s->stats.queries);
  for (int i = 0; i < TS_JOB_STATE_COUNT; i++)
    ts_text_add(t, "%s\"%s\":%u", i ? "," : "", ts_job_state_name(i), s->counts[i]);
  ts_text_add(t, "},\"jobs\":[");
  for (uint32_t i = 0; i < s->njobs; i++) {
    ts_text_add(t, i ? "," : "");
    json_job(t, nth_newest(s, i));
  }
  ts_text_add(t, "],\"sequences\":");
  ts_http_seqs seqs;
  if (ts_http_seqs_make(s->frames, s->nframes, &seqs) == 0) ts_http_seqs_json(t, &seqs);
  else t->failed = 1;
  ts_http_seqs_free(&seqs);
  ts_text_add(t, ",\"pool\":[");
  for (uint32_t i = 0; i < s->nworkers; i++) {
    ts_text_add(t, i ? "," : "");
    json_worker(t, &s->workers[i]);
  }
  ts_text_add(t, "]}\n");
}

/* ---- Prometheus ------------------------------------------------------------------ */

static void metric_head(ts_text *t, const char *name, const char *type, const char *help) {
  ts_text_add(t, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type);
}

static void metric(ts_text *t, const char *name, const char *type, const char *help, double v) {
  metric_head(t, name, type, help);
  ts_text_add(t, "%s %.17g\n", name, v);
}

/* The coordinator's figures: those of its Modbus plane (proto/mbmap.h). */
static void metrics_coordinator(ts_text *t, const ts_http_snapshot *s) {
  metric(t, "texsyn_uptime_seconds", "gauge", "Seconds since the coordinator started.", s->uptime);
  metric(t, "texsyn_scan_threads", "gauge", "Local scan threads, used when no worker is ready.", s->threads);
  metric(t, "texsyn_simd_level", "gauge", "L1 kernel variant: 0 scalar, 1 mmx, 2 sse2, 3 avx2, 4 avx512.",
         s->simd);
  metric(t, "texsyn_pool_rate_bytes_per_second", "gauge", "Calibrated scan rates of the ready workers, summed.",
         (double)s->stats.rate);
  metric(t, "texsyn_batches_total", "counter", "Query batches answered for jobs, by workers or locally.",
         (double)s->stats.batches);
  metric(t, "texsyn_queries_total", "counter", "Queries answered for jobs, by workers or locally.",
         (double)s->stats.queries);
  metric(t, "texsyn_workers_ready", "gauge", "Workers ready.", s->stats.ready);
  /* Gauges, not counters: `texsyn delete` removes finished jobs. */
  metric_head(t, "texsyn_jobs", "gauge", "Jobs in the spool by state.");
  for (int i = 0; i < TS_JOB_STATE_COUNT; i++)
    ts_text_add(t, "texsyn_jobs{state=\"%s\"} %u\n", ts_job_state_name(i), s->counts[i]);
  int run = s->have_current;
  metric(t, "texsyn_current_job_id", "gauge",
         "The running job that started first, else the job that ended last (0: none).",
         run ? (double)s->cur.id : 0);
  metric(t, "texsyn_current_job_progress_ratio", "gauge", "That job's progress, 0..1.",
         run ? s->cur.permille / 1000.0 : 0);
  metric(t, "texsyn_current_job_level", "gauge",
         "The level that job synthesises, machine-numbered: L-1 the coarsest down to 0 the finest "
         "(texsyn status shows L-level of L).",
         run ? s->cur.level : 0);
  /* NaN: no estimate yet (Prometheus takes it as a value, not a gap). */
  int eta = run && s->cur.state == TS_JOB_RUNNING && s->cur.eta_ms != UINT32_MAX;
  metric_head(t, "texsyn_current_job_eta_seconds", "gauge", "That job's estimated time to finish (NaN: unknown).");
  if (eta) ts_text_add(t, "texsyn_current_job_eta_seconds %.3f\n", s->cur.eta_ms / 1000.0);
  else ts_text_add(t, "texsyn_current_job_eta_seconds NaN\n");
  metric(t, "texsyn_queue_paused", "gauge", "1 while the queue is paused.", s->paused);
}

typedef enum { W_CALIBRATED, W_RATE, W_SHARE, W_BATCHES, W_THREADS } worker_figure;

static double worker_value(const ts_worker_info *w, worker_figure f) {
  switch (f) {
  case W_CALIBRATED: return (double)w->calibrated;
  case W_RATE: return (double)w->rate;
  case W_SHARE: return w->share / 1000.0;
  case W_BATCHES: return (double)w->batches;
  case W_THREADS: return w->threads;
  }
  return 0;
}

/* A failed worker stays in the pool until no exchange holds it, and the
 * same worker may meanwhile join again from the same address: its series
 * would then appear twice, which Prometheus refuses. Failed workers are
 * left out of /metrics (the page and status.json show them). */
static int in_metrics(const ts_worker_info *w) { return w->state != TS_WORKER_FAILED; }

static void metric_workers(ts_text *t, const ts_http_snapshot *s, const char *name, const char *type,
                           const char *help, worker_figure f) {
  metric_head(t, name, type, help);
  for (uint32_t i = 0; i < s->nworkers; i++) {
    if (!in_metrics(&s->workers[i])) continue;
    ts_text_add(t, "%s{worker=\"", name);
    add_label(t, s->workers[i].addr);
    ts_text_add(t, "\"} %.17g\n", worker_value(&s->workers[i], f));
  }
}

static void metrics_workers(ts_text *t, const ts_http_snapshot *s) {
  metric_workers(t, s, "texsyn_worker_calibrated_bytes_per_second", "gauge",
                 "A worker's scan rate measured at calibration.", W_CALIBRATED);
  metric_workers(t, s, "texsyn_worker_rate_bytes_per_second", "gauge",
                 "The rate a worker's slices are sized with (calibrated, then timed on batches).", W_RATE);
  metric_workers(t, s, "texsyn_worker_slice_share_ratio", "gauge", "A worker's share of each slicing, 0..1.",
                 W_SHARE);
  metric_workers(t, s, "texsyn_worker_batches_total", "counter",
                 "Batches a worker answered (from 0 when it joins again).", W_BATCHES);
  metric_workers(t, s, "texsyn_worker_threads", "gauge", "A worker's scan threads.", W_THREADS);
  metric_head(t, "texsyn_worker_state", "gauge", "1 for a worker's state (calibrating, ready, draining).");
  for (uint32_t i = 0; i < s->nworkers; i++) {
    if (!in_metrics(&s->workers[i])) continue;
    ts_text_add(t, "texsyn_worker_state{worker=\"");
    add_label(t, s->workers[i].addr);
    ts_text_add(t, "\",state=\"%s\"} 1\n", ts_worker_state_name(s->workers[i].state));
  }
}

void ts_http_render_metrics(ts_text *t, const ts_http_snapshot *s) {
  metrics_coordinator(t, s);
  metrics_workers(t, s);
}

/* ---- parsing -------------------------------------------------------------------- */

/* A job id: 1..UINT64_MAX in decimal, no sign, no leading zero. Sets *end
 * past it. */
static int parse_job_id(const char *s, const char **end, uint64_t *id) {
  uint64_t v = 0;
  const char *p = s;
  if (*p < '1' || *p > '9') return TS_EINVAL;
  for (; *p >= '0' && *p <= '9'; p++) {
    unsigned d = (unsigned)(*p - '0');
    if (v > (UINT64_MAX - d) / 10) return TS_EINVAL;
    v = v * 10 + d;
  }
  *end = p;
  *id = v;
  return 0;
}

ts_http_route_kind ts_http_route(const char *url, uint64_t *job) {
  if (strcmp(url, "/") == 0) return TS_HTTP_INDEX;
  if (strcmp(url, "/status.json") == 0) return TS_HTTP_STATUS;
  if (strcmp(url, "/metrics") == 0) return TS_HTTP_METRICS;
  static const char kJobs[] = "/jobs/";
  const char *end;
  if (strncmp(url, kJobs, sizeof(kJobs) - 1) != 0 || parse_job_id(url + sizeof(kJobs) - 1, &end, job) != 0)
    return TS_HTTP_NOT_FOUND;
  if (strcmp(end, "/thumb.png") == 0) return TS_HTTP_THUMB;
  return strcmp(end, "/small.png") == 0 ? TS_HTTP_SMALL : TS_HTTP_NOT_FOUND;
}

int ts_http_listen_addr(const char *arg, char *out, size_t cap, char *host, size_t hostcap, char *err) {
  const char *colon = strrchr(arg, ':');
  /* No host, or an empty one: loopback, as every texsyn plane defaults to. */
  const char *port = colon == NULL ? arg : colon == arg ? arg + 1 : NULL;
  int n = port != NULL ? snprintf(out, cap, "127.0.0.1:%s", port) : snprintf(out, cap, "%s", arg);
  if (n < 0 || (size_t)n >= cap) return ts_error(err, TS_EINVAL, "--http %s: address too long", arg);
  int p;
  char why[TS_ERR_LEN];
  if (ts_net_split(out, host, hostcap, &p, why) != 0)
    return ts_error(err, TS_EINVAL, "--http %s: %s (want PORT, :PORT or ADDR:PORT)", arg, why);
  return 0;
}
