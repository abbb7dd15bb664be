/* jobcmd.c - see jobcmd.h. */
#include "jobcmd.h"

#include <errno.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <unistd.h>

#include "error.h"
#include "image.h"
#include "search.h"
#include "util.h"

const char *const ts_job_options_help =
    "  -o, --output OUT     output image; format from the extension\n"
    "  --report F           JSON report: parameters, timings, statistics\n" TS_JOB_RUN_HELP;

/* ---- arguments --------------------------------------------------------- */

int ts_arg_long(const char *opt, const char *s, long lo, long hi, long *out, char *err) {
  if (ts_parse_long(s, lo, hi, out) != 0)
    return ts_error(err, TS_EINVAL, "%s %s: need a whole number in %ld..%ld", opt, s, lo, hi);
  return 0;
}

int ts_arg_u64(const char *opt, const char *s, uint64_t *out, char *err) {
  if (ts_parse_u64(s, out) != 0) return ts_error(err, TS_EINVAL, "%s %s: need a whole number >= 0", opt, s);
  return 0;
}

int ts_arg_double(const char *opt, const char *s, double *out, char *err) {
  if (ts_parse_double(s, out) != 0) return ts_error(err, TS_EINVAL, "%s %s: need a number", opt, s);
  return 0;
}

int ts_arg_size(const char *opt, const char *s, int *w, int *h, char *err) {
  int rc = ts_parse_size(s, TS_OUTPUT_SIDE_MAX, w, h);
  if (rc == TS_EFORMAT) return ts_error(err, TS_EINVAL, "%s %s: expected WxH, e.g. 1024x1024", opt, s);
  if (rc != 0) return ts_error(err, TS_EINVAL, "%s %s: expected WxH with 1..%d each", opt, s, TS_OUTPUT_SIDE_MAX);
  return 0;
}

int ts_default_threads(void) {
  long n = sysconf(_SC_NPROCESSORS_ONLN);
  return n < 1 ? 1 : n > 1024 ? 1024 : (int)n;
}

const char *ts_env_server(void) {
  const char *s = getenv("TEXSYN_SERVER");
  return s != NULL && s[0] != '\0' ? s : NULL;
}

const char *ts_output_path(const ts_output_paths *t, const char *key) {
  for (int i = 0; i < t->n; i++)
    if (strcmp(t->key[i], key) == 0) return t->path[i];
  return NULL;
}

void ts_output_set(ts_output_paths *t, const char *key, const char *path) {
  int i = 0;
  while (i < t->n && strcmp(t->key[i], key) != 0) i++;
  if (i == (int)(sizeof(t->key) / sizeof(t->key[0]))) return; /* more keys than any engine has outputs */
  t->key[i] = key;
  t->path[i] = path;
  if (i == t->n) t->n++;
}

void ts_job_cmd_init(ts_job_cmd *o, const char *cmd, const ts_engine *e) {
  memset(o, 0, sizeof(*o));
  o->cmd = cmd;
  ts_jobspec_default(&o->spec, e);
  o->threads = ts_default_threads();
  o->max_pixels = TS_IMAGE_DEFAULT_MAX_PIXELS;
}

int ts_job_option(ts_job_cmd *o, int c, const char *arg, char *err) {
  long v;
  int rc = 0;
  switch (c) {
  case 'o': ts_output_set(&o->out, "output", arg); break;
  case TS_OPT_REPORT: ts_output_set(&o->out, "report", arg); break;
  case TS_OPT_THREADS: rc = ts_arg_long("--threads", arg, 1, 1024, &v, err); o->threads = (int)v; break;
  case TS_OPT_MAXPIX: rc = ts_arg_u64("--max-pixels", arg, &o->max_pixels, err); break;
  case TS_OPT_QUIET: o->quiet = 1; break;
  case TS_OPT_SERVER: o->server = arg; break;
  case TS_OPT_DETACH: o->detach = 1; break;
  case TS_OPT_EMBEDDED: o->embedded = 1; break;
  case TS_OPT_SECRET: o->secret_file = arg; break;
  default: rc = TS_ENOENT;
  }
  return rc;
}

/* The option that sets output key: -o, else --KEY with '-' for '_'. */
static void output_option(const char *key, char *out, size_t cap) {
  if (strcmp(key, "output") == 0) {
    snprintf(out, cap, "-o");
    return;
  }
  int n = snprintf(out, cap, "--%s", key);
  for (int i = 2; i < n && (size_t)i < cap; i++)
    if (out[i] == '_') out[i] = '-';
}

/* Every image output's extension names a format texsyn writes: checked
 * on the client, before any work, wherever the job is to run (a
 * coordinator would find out only after the job ran). */
static int check_formats(const ts_job_cmd *o, char *err) {
  const ts_engine *e = o->spec.engine;
  for (int k = 0; k < e->noutputs; k++) {
    const char *path = ts_output_path(&o->out, e->outputs[k].key);
    if (path == NULL || e->outputs[k].kind != TS_OUTPUT_IMAGE) continue;
    const char *ext = ts_path_ext(path);
    struct stat st; /* a directory is check_writable's to name */
    if (ts_output_ext_ok(&e->outputs[k], ext) || (stat(path, &st) == 0 && S_ISDIR(st.st_mode))) continue;
    char opt[64], own[32] = "";
    output_option(e->outputs[k].key, opt, sizeof(opt));
    if (e->outputs[k].own_ext != NULL) snprintf(own, sizeof(own), " (or .%s)", e->outputs[k].own_ext);
    if (ext[0] == '\0')
      return ts_error(err, TS_EINVAL, "%s %s: the extension names the image format: use " TS_IMAGE_EXTS_HELP "%s",
                      opt, path, own);
    return ts_error(err, TS_EINVAL, "%s %s: texsyn does not write .%s images; use " TS_IMAGE_EXTS_HELP "%s", opt,
                    path, ext, own);
  }
  return 0;
}

int ts_job_parse_end(ts_job_cmd *o, char *err) {
  if (o->server != NULL && o->embedded) return ts_error(err, TS_EINVAL, "--server and --embedded exclude each other");
  if (o->server == NULL && !o->embedded) o->server = ts_env_server();
  if (ts_output_path(&o->out, "output") == NULL)
    return ts_error(err, TS_EINVAL, "-o OUT is required (see texsyn %s --help)", o->cmd);
  int rc = check_formats(o, err);
  if (rc != 0) return rc;
  if (o->detach && o->server == NULL) return ts_error(err, TS_EINVAL, "--detach needs --server");
  o->spec.engine->set_max_pixels(&o->spec.params, o->max_pixels);
  return 0;
}

/* ---- before the work --------------------------------------------------- */

/* Whether the file path names can be written: a probe file made beside it
 * and removed at once (permissions alone do not tell: root, read-only
 * mounts). Checked before the job runs, so a wrong -o costs no work. */
static int check_writable(const char *path, char *err) {
  struct stat st;
  if (stat(path, &st) == 0 && S_ISDIR(st.st_mode))
    return ts_error(err, TS_EINVAL, "cannot write %s: it is a directory; name a file in it", path);
  char probe[4096];
  int n = snprintf(probe, sizeof(probe), "%s.probe-XXXXXX", path);
  if (n < 0 || (size_t)n >= sizeof(probe)) return ts_error(err, TS_EINVAL, "%s: path too long", path);
  int fd = mkstemp(probe);
  if (fd < 0)
    return ts_error(err, TS_EIO, "cannot write %s: %s (found before the job ran; nothing was done)", path,
                    strerror(errno));
  close(fd);
  unlink(probe);
  return 0;
}

int ts_job_check_outputs(const ts_job_cmd *o, char *err) {
  for (int i = 0; i < o->out.n; i++)
    if (check_writable(o->out.path[i], err) != 0) return TS_EIO;
  return 0;
}

/* The spec's wants, for a coordinator (an embedded run writes to the
 * paths): for every output given a path, the format its extension names
 * ("1" for a flag output). */
static void set_wants(const ts_job_cmd *o, ts_jobspec *spec) {
  const ts_engine *e = spec->engine;
  for (int k = 0; k < e->noutputs; k++) {
    const char *path = ts_output_path(&o->out, e->outputs[k].key);
    char *want = spec->wants.want[k];
    if (path == NULL) want[0] = '\0';
    else if (e->outputs[k].kind == TS_OUTPUT_FLAG) snprintf(want, TS_EXT_LEN, "1");
    else snprintf(want, TS_EXT_LEN, "%s", ts_path_ext(path)); /* a format ts_job_parse_end took */
  }
}

/* Reads the first n inputs (within --max-pixels); on failure the ones
 * read are freed. */
static int read_inputs(const ts_job_cmd *o, int n, ts_engine_file *in, char *err) {
  ts_image_limits limits = {o->max_pixels, NULL};
  for (int k = 0; k < n; k++) {
    int rc = ts_engine_input_read(o->spec.engine, &o->spec.params, k, o->in[k], &limits, &in[k], err);
    if (rc != 0) {
      for (int i = 0; i <= k; i++) ts_image_free(&in[i].img);
      return rc;
    }
  }
  return 0;
}

/* ---- progress ---------------------------------------------------------- */

/* A plain line at least this often (seconds) inside a long level. */
#define PROGRESS_LINE_SECONDS 10.0

int ts_progress_mode(int quiet) {
  return quiet ? TS_PROGRESS_NONE : isatty(STDERR_FILENO) ? TS_PROGRESS_BAR : TS_PROGRESS_LINES;
}

/* What a client shows of a job under way: the bar redrawn at most every
 * 0.1 s, or a line when a level (or a level's stage) starts and every
 * PROGRESS_LINE_SECONDS. Levels are shown as people count them, 1 the
 * coarsest to L the finest; engines and the wire count down to 0. */
typedef struct {
  int mode;
  const char *cmd;
  double start, last_bar, last_line;
  int line_level; /* level of the last line: 0 queued, -1 no line yet */
  char line_stage[64];
} progress_view;

static void view_init(progress_view *v, int mode, const char *cmd) {
  *v = (progress_view){mode, cmd, ts_now(), 0, 0, -1, ""};
}

static int line_due(progress_view *v, int level, const char *stage, double t) {
  int n = (int)sizeof(v->line_stage) - 1;
  if (level == v->line_level && strncmp(stage, v->line_stage, (size_t)n) == 0 && t - v->last_line < PROGRESS_LINE_SECONDS)
    return 0;
  v->line_level = level;
  snprintf(v->line_stage, sizeof(v->line_stage), "%.*s", n, stage);
  v->last_line = t;
  return 1;
}

static void bar_of(double frac, char bar[31]) {
  int fill = (int)(frac * 30);
  for (int i = 0; i < 30; i++) bar[i] = i < fill ? '#' : '.';
  bar[30] = '\0';
}

/* "ETA 5.1s", or "ETA ?" before there is anything to go by. */
static void eta_of(double seconds, int known, char *out, size_t cap) {
  if (known) snprintf(out, cap, "ETA %.1fs", seconds);
  else snprintf(out, cap, "ETA ?");
}

static void progress_draw(void *ctx, const ts_progress *p) {
  progress_view *v = ctx;
  double t = ts_now();
  double frac = p->work_total > 0 ? p->work_done / p->work_total : 1.0;
  char eta[32];
  eta_of(frac > 0.001 ? (t - v->start) * (1.0 - frac) / frac : 0.0, frac > 0.001, eta, sizeof(eta));
  int level = p->levels - p->level;
  const char *sep = p->stage[0] ? ": " : "";
  if (v->mode == TS_PROGRESS_LINES && line_due(v, level, p->stage, t))
    fprintf(stderr, "texsyn %s: %s%slevel %d of %d, %.0f%% of the work, %s\n", v->cmd, p->stage, sep, level,
            p->levels, 100.0 * frac, eta);
  if (v->mode != TS_PROGRESS_BAR || (t - v->last_bar < 0.1 && p->done != p->total)) return;
  v->last_bar = t;
  int pct = p->total ? (int)(100 * p->done / p->total) : 100;
  char bar[31];
  bar_of(frac, bar);
  fprintf(stderr, "\r%s%slevel %d of %d %3d%% of blocks [%s] %s ", p->stage, sep, level, p->levels, pct, bar, eta);
  fflush(stderr);
}

static void remote_progress(progress_view *v, const ts_job_status *s) {
  double t = ts_now();
  unsigned long long id = (unsigned long long)s->id;
  if (s->state == TS_JOB_QUEUED) {
    /* Held: the coordinator's queue is paused; a change of that is a new line. */
    const char *what = s->flags & TS_JOB_HELD ? "held: the coordinator's queue is paused" : "queued";
    if (v->mode == TS_PROGRESS_LINES && line_due(v, 0, what, t))
      fprintf(stderr, "texsyn %s: job %llu %s\n", v->cmd, id, what);
    if (v->mode == TS_PROGRESS_BAR) fprintf(stderr, "\rjob %llu %s (%.0fs) ", id, what, t - v->start);
    fflush(stderr);
    return;
  }
  if (s->state != TS_JOB_RUNNING) return;
  char eta[32], bar[31];
  eta_of(s->eta_ms / 1000.0, s->eta_ms != UINT32_MAX, eta, sizeof(eta));
  int level = s->levels - s->level;
  const char *sep = s->text[0] ? ": " : "", *plural = s->workers == 1 ? "" : "s";
  if (v->mode == TS_PROGRESS_LINES && line_due(v, level, s->text, t))
    fprintf(stderr, "texsyn %s: job %llu %s%slevel %d of %d, %.1f%% of the work, %s, %u worker%s\n", v->cmd, id,
            s->text, sep, level, s->levels, s->permille / 10.0, eta, s->workers, plural);
  if (v->mode == TS_PROGRESS_BAR) {
    bar_of(s->permille / 1000.0, bar);
    fprintf(stderr, "\rjob %llu %s%slevel %d of %d %5.1f%% [%s] %s, %u worker%s ", id, s->text, sep, level, s->levels,
            s->permille / 10.0, bar, eta, s->workers, plural);
  }
  fflush(stderr);
}

/* ---- in-process -------------------------------------------------------- */

static int write_outputs(const ts_job_cmd *o, const ts_engine_run *run, char *err) {
  const ts_engine *e = o->spec.engine;
  int rc = 0;
  for (int k = 0; rc == 0 && k < e->noutputs; k++) {
    const char *path = ts_output_path(&o->out, e->outputs[k].key);
    if (path != NULL && !e->outputs[k].streamed) rc = e->write_output(run, k, path, o->threads, err);
  }
  return rc;
}

/* What the closing line names. */
static const char *result_name(const ts_job_cmd *o) {
  return o->result_name != NULL ? o->result_name : ts_output_path(&o->out, "output");
}

int ts_job_embedded(const ts_job_cmd *o, const ts_image *const *in, ts_search *search, char *err) {
  const ts_engine *e = o->spec.engine;
  ts_engine_run *run = NULL;
  progress_view pv;
  view_init(&pv, ts_progress_mode(o->quiet), o->cmd);
  const char *out_paths[TS_ENGINE_MAX_OUTPUTS] = {0};
  for (int k = 0; k < e->noutputs; k++)
    if (e->outputs[k].streamed) out_paths[k] = ts_output_path(&o->out, e->outputs[k].key);
  ts_engine_hooks hooks = {.progress = progress_draw, .progress_ctx = &pv, .output_paths = out_paths};
  double t0 = ts_now();
  uint64_t pairs = search->stats.pairs;
  int rc = e->run(&o->spec.params, in, search, &hooks, &run, err);
  if (pv.mode == TS_PROGRESS_BAR) fputc('\n', stderr);
  if (rc == 0) rc = write_outputs(o, run, err);
  if (rc == 0 && !o->quiet)
    fprintf(stderr, "texsyn: %s in %.2fs (in-process with %d thread%s, %s, %.3g comparisons)\n", result_name(o),
            ts_now() - t0, o->threads, o->threads == 1 ? "" : "s", search->simd->name,
            (double)(search->stats.pairs - pairs));
  e->run_free(run);
  return rc;
}

static int run_embedded(const ts_job_cmd *o, const ts_image *const *in, char *err) {
  ts_search *search = NULL;
  int rc = ts_search_local_create(&search, o->threads, NULL, err);
  if (rc == 0) rc = ts_job_embedded(o, in, search, err);
  ts_search_destroy(search);
  return rc;
}

/* ---- on a coordinator -------------------------------------------------- */

const char ts_default_server[] = "127.0.0.1:7070";

/* Appends text to the message in err, cut to fit. */
static void err_append(char *err, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void err_append(char *err, const char *fmt, ...) {
  size_t n = strlen(err);
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(err + n, TS_ERR_LEN - n, fmt, ap);
  va_end(ap);
}

/* The hint a failed connection gets, by what failed: the address, the
 * coordinator not there, or the secret (naming where it came from). */
static void connect_hint(int rc, const char *addr, const char *secret, const char *secret_from, char *err) {
  const char *from = addr == ts_env_server() ? ", from $TEXSYN_SERVER"
                     : addr == ts_default_server ? ", the default: no --server, no $TEXSYN_SERVER"
                                                 : "";
  if (rc == TS_ECONN || rc == TS_ETIMEDOUT) err_append(err, " (is texsyn-server running at %s%s?)", addr, from);
  else if (rc == TS_EAUTH && secret != NULL) err_append(err, "; this client's secret: %s, from %s", secret, secret_from);
}

int ts_job_connect(ts_conn *c, const char *addr, const char *path, char *err) {
  char host[256];
  int port;
  if (ts_net_split(addr, host, sizeof(host), &port, NULL) != 0 || port == 0)
    return ts_error(err, TS_EINVAL, "%s%s: need HOST:PORT, e.g. 127.0.0.1:7070",
                    addr == ts_env_server() ? "$TEXSYN_SERVER=" : "--server ", addr);
  const char *from = "--secret-file";
  if (path == NULL) {
    path = getenv("TEXSYN_SECRET_FILE");
    from = "$TEXSYN_SECRET_FILE";
  }
  if (path != NULL && path[0] == '\0') path = NULL;
  ts_auth auth = {0};
  int rc = path != NULL ? ts_auth_load(&auth, path, err) : 0;
  if (rc == 0 && auth.enabled && !ts_auth_kind_allows(auth.who.kind, TS_ROLE_CLIENT))
    rc = ts_error(err, TS_EAUTH, "%s (%s) is a %s key; a client needs a client key (texsyn-server --gen-secret "
                  "client PATH) or an admin key", path, from, ts_auth_kind_name(auth.who.kind));
  if (rc == 0) {
    rc = ts_client_connect(c, addr, &auth, err);
    if (rc != 0) connect_hint(rc, addr, path, from, err);
  }
  ts_auth_clear(&auth);
  return rc;
}

/* The fetched file that is output `key`, or -1. */
static int fetched_file(const ts_msg_files *m, const char *key) {
  for (uint32_t k = 0; k < m->n; k++) {
    const ts_engine_output *out = ts_engine_output_of_file(m->name[k]);
    if (out != NULL && strcmp(out->key, key) == 0) return (int)k;
  }
  return -1;
}

/* Every output given a path is among the job's files: a job makes only
 * what its submission asked for, and a fetch that quietly wrote less
 * would leave the caller with old or no files. Nothing is written then. */
static int check_fetched(uint64_t id, const ts_msg_files *m, const ts_output_paths *t, char *err) {
  char missing[512] = "";
  size_t len = 0;
  for (int i = 0; i < t->n; i++) {
    if (fetched_file(m, t->key[i]) >= 0) continue;
    char opt[64];
    output_option(t->key[i], opt, sizeof(opt));
    int n = snprintf(missing + len, sizeof(missing) - len, "%s%s %s", len ? ", " : "", opt, t->path[i]);
    if (n > 0 && (size_t)n < sizeof(missing) - len) len += (size_t)n;
  }
  if (len == 0) return 0;
  return ts_error(err, TS_ENOENT, "job %llu did not make %s: a job makes only the outputs asked for when it was "
                  "submitted; nothing was written", (unsigned long long)id, missing);
}

/* An image fetched in one format and asked for in another is converted
 * (as the job would have written it); a format of the output's own (the
 * NNF's .raw) has no conversion. Checked for every path before any is
 * written. */
static int check_conversions(uint64_t id, const ts_msg_files *m, const ts_output_paths *t, char *err) {
  for (int i = 0; i < t->n; i++) {
    int k = fetched_file(m, t->key[i]);
    const char *name = m->name[k], *want = ts_path_ext(t->path[i]);
    const ts_engine_output *out = ts_engine_output_of_file(name);
    if (out->kind != TS_OUTPUT_IMAGE || ts_ext_same_format(ts_path_ext(name), want)) continue;
    char opt[64];
    output_option(t->key[i], opt, sizeof(opt));
    if (m->data[k] == NULL) /* taken in ranges: never held whole, so never decoded whole */
      return ts_error(err, TS_EINVAL, "%s %s: job %llu made %s of %.1f GB, too large to convert here: fetch it as "
                      ".%s and convert it with gdal_translate or oiiotool (nothing was written)", opt, t->path[i],
                      (unsigned long long)id, name, (double)m->size[k] / 1e9, ts_path_ext(name));
    if (!ts_output_ext_ok(out, want))
      return ts_error(err, TS_EINVAL, "%s %s: texsyn does not write .%s images; use " TS_IMAGE_EXTS_HELP
                      " (nothing was written)", opt, t->path[i], want);
    if (out->own_ext != NULL && (strcasecmp(want, out->own_ext) == 0 ||
                                 strcasecmp(ts_path_ext(name), out->own_ext) == 0))
      return ts_error(err, TS_EINVAL, "%s %s: job %llu made %s, and .%s has no conversion to or from another "
                      "format: fetch it as .%s (nothing was written)", opt, t->path[i], (unsigned long long)id, name,
                      out->own_ext, ts_path_ext(name));
  }
  return 0;
}

/* One fetched file written to path: as it is, or converted to the format
 * the path names. */
static int write_fetched(const char *name, const uint8_t *data, size_t len, const char *path, char *err) {
  const ts_engine_output *out = ts_engine_output_of_file(name);
  if (out->kind != TS_OUTPUT_IMAGE || ts_ext_same_format(ts_path_ext(name), ts_path_ext(path)))
    return ts_file_write(path, data, len, err);
  ts_image img;
  ts_image_limits any = {UINT64_MAX, NULL}; /* the coordinator wrote it: no decoding surprise to fear */
  int rc = ts_image_read_mem(name, data, len, &img, &any, err);
  if (rc != 0) return rc;
  rc = ts_image_write(path, &img, img.meta, err);
  ts_image_free(&img);
  return rc;
}

/* A file too large for the 'F' reply, taken range by range ('B') into a
 * temporary file renamed to path at the end: neither side holds it. */
static int fetch_ranges(ts_conn *c, uint64_t id, const char *name, uint64_t size, const char *path, char *err) {
  char tmp[TS_FILE_TMP_LEN];
  FILE *out = ts_file_create(path, tmp, err);
  if (out == NULL) return TS_EIO;
  int rc = 0;
  for (uint64_t at = 0; rc == 0 && at < size;) {
    ts_msg_range r = {.id = id, .offset = at, .len = (uint32_t)(size - at < TS_RANGE_MAX ? size - at : TS_RANGE_MAX)};
    snprintf(r.name, sizeof(r.name), "%s", name);
    ts_wr w;
    ts_wr_init(&w);
    ts_msg_range_write(&w, &r);
    ts_frame f;
    rc = ts_client_call(c, TS_MSG_RANGE, &w, 600000, &f, err);
    ts_wr_free(&w);
    if (rc == 0 && f.len != r.len)
      rc = ts_error(err, TS_EPROTO, "job %llu's %s: %u bytes at %llu instead of %u", (unsigned long long)id, name,
                    f.len, (unsigned long long)at, r.len);
    if (rc == 0 && fwrite(f.payload, 1, f.len, out) != f.len) rc = ts_error(err, TS_EIO, "%s: %s", path, strerror(errno));
    at += r.len;
  }
  int crc = ts_file_commit(out, tmp, path, rc == 0, err);
  return rc != 0 ? rc : crc;
}

int ts_job_fetch(ts_conn *c, uint64_t id, const ts_output_paths *t, char *err) {
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_jobid_write(&w, id);
  ts_frame f;
  int rc = ts_client_call(c, TS_MSG_FETCH, &w, 600000, &f, err);
  ts_wr_free(&w);
  ts_msg_files m;
  if (rc == 0) rc = ts_msg_files_read(&f, &m, err);
  if (rc == 0) rc = check_fetched(id, &m, t, err);
  if (rc == 0) rc = check_conversions(id, &m, t, err);
  /* The inline files first: their bytes live in the reply's frame, which
   * the next call ('B') replaces. */
  for (int ranged = 0; ranged < 2; ranged++)
    for (uint32_t i = 0; rc == 0 && i < m.n; i++) {
      const ts_engine_output *out = ts_engine_output_of_file(m.name[i]);
      const char *path = out != NULL ? ts_output_path(t, out->key) : NULL;
      if (path == NULL || (m.data[i] == NULL) != ranged) continue;
      rc = ranged ? fetch_ranges(c, id, m.name[i], m.size[i], path, err)
                  : write_fetched(m.name[i], m.data[i], m.len[i], path, err);
    }
  return rc;
}

int ts_job_watch(ts_conn *c, uint64_t id, const char *cmd, int mode, ts_job_status *last, char *err) {
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_status_req req = {id, 1};
  ts_msg_status_req_write(&w, &req);
  int rc = ts_wr_status(&w) ? TS_ENOMEM : ts_conn_send(c, TS_MSG_STATUS, 1, w.buf, w.len, err);
  ts_wr_free(&w);
  progress_view pv;
  view_init(&pv, mode, cmd);
  while (rc == 0) {
    ts_frame f;
    uint32_t n;
    rc = ts_client_next(c, TS_MSG_STATUS, -1, &f, err);
    if (rc == 0) rc = ts_msg_status_read(&f, last, 1, &n, err);
    if (rc == 0 && n != 1) rc = ts_error(err, TS_EPROTO, "empty status update");
    if (rc != 0) break;
    remote_progress(&pv, last);
    if (last->state > TS_JOB_RUNNING) break;
  }
  if (mode == TS_PROGRESS_BAR) fputc('\n', stderr);
  return rc;
}

/* The file name of a path, as the coordinator is told it. */
static void base_name(const char *path, char *out, size_t cap) {
  const char *slash = strrchr(path, '/');
  snprintf(out, cap, "%s", slash ? slash + 1 : path);
}

/* Every input goes in the one submit frame: together they must fit it. */
#define SUBMIT_MAX (TS_FRAME_DEFAULT_MAX - 8192)

int ts_job_submit(ts_conn *c, const ts_job_cmd *o, uint64_t *id, char *err) {
  ts_jobspec js = o->spec;
  char spec[TS_SPEC_MAX];
  set_wants(o, &js);
  ts_jobspec_set_name(&js, result_name(o)); /* for texsyn status */
  int n = ts_jobspec_format(&js, spec, sizeof(spec));
  if (n < 0) return ts_error(err, TS_ETOOBIG, "job spec too long");
  ts_engine_inputs names;
  o->spec.engine->inputs(&o->spec.params, &names);
  uint8_t *data[TS_ENGINE_MAX_INPUTS] = {NULL};
  size_t len[TS_ENGINE_MAX_INPUTS], total = 0;
  int rc = 0;
  for (int k = 0; rc == 0 && k < names.n; k++) {
    rc = ts_file_read(o->in[k], SUBMIT_MAX, &data[k], &len[k], err);
    total += rc == 0 ? len[k] : 0;
  }
  if (rc == TS_ETOOBIG || (rc == 0 && total > SUBMIT_MAX))
    rc = ts_error(err, TS_ETOOBIG, "the inputs take more than the %u bytes a submission can carry",
                  (unsigned)SUBMIT_MAX);
  ts_msg_submit *m = rc == 0 ? calloc(1, sizeof(*m)) : NULL;
  if (rc == 0 && m == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory");
  ts_wr w;
  ts_wr_init(&w);
  if (rc == 0) {
    *m = (ts_msg_submit){.spec = spec, .spec_len = (uint32_t)n, .ref = data[0], .ref_len = (uint32_t)len[0],
                         .nmore = (uint32_t)names.n - 1};
    base_name(o->in[0], m->ref_name, sizeof(m->ref_name));
    for (int k = 1; k < names.n; k++) {
      ts_msg_input *in = &m->more[k - 1];
      snprintf(in->key, sizeof(in->key), "%s", names.name[k]);
      base_name(o->in[k], in->name, sizeof(in->name));
      in->data = data[k];
      in->len = (uint32_t)len[k];
    }
    ts_msg_submit_write(&w, m);
  }
  for (int k = 0; k < names.n; k++) free(data[k]);
  free(m);
  ts_frame f;
  if (rc == 0) rc = ts_client_call(c, TS_MSG_SUBMIT, &w, 60000, &f, err);
  ts_wr_free(&w);
  if (rc == 0) rc = ts_msg_jobid_read(&f, id, err);
  return rc;
}

int ts_job_open(ts_conn *c, const ts_job_cmd *o, char *err) {
  int rc = ts_job_connect(c, o->server, o->secret_file, err);
  if (rc != 0) err_append(err, "\n(no job was submitted; --embedded runs it here)");
  return rc;
}

/* What an interrupt of a client following its job says, made before the
 * handler is armed: the handler may only write(2) it and _exit. */
static char interrupt_msg[768];
static size_t interrupt_len;

static void on_interrupt(int sig) {
  (void)sig;
  ssize_t n = write(STDERR_FILENO, interrupt_msg, interrupt_len);
  (void)n;
  _exit(130);
}

/* Ctrl-C (or a SIGTERM) while a client follows job id: the job is the
 * coordinator's and goes on; the client says so, and how to follow or
 * stop it, rather than vanish with the id unsaid. `old` keeps the
 * handlers armed before, for interrupt_disarm. */
static void interrupt_arm(const ts_job_cmd *o, uint64_t id, int bar, struct sigaction *old) {
  char where[300] = "";
  if (o->server != ts_env_server()) snprintf(where, sizeof(where), " --server %s", o->server);
  int n = snprintf(interrupt_msg, sizeof(interrupt_msg),
                   "%stexsyn %s: interrupted; job %llu keeps running on %s: `texsyn watch %llu%s` follows it, "
                   "`texsyn cancel %llu%s` stops it\n",
                   bar ? "\n" : "", o->cmd, (unsigned long long)id, o->server, (unsigned long long)id, where,
                   (unsigned long long)id, where);
  interrupt_len = n < 0 ? 0 : (size_t)n < sizeof(interrupt_msg) ? (size_t)n : sizeof(interrupt_msg) - 1;
  struct sigaction sa;
  memset(&sa, 0, sizeof(sa));
  sa.sa_handler = on_interrupt;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, &old[0]);
  sigaction(SIGTERM, &sa, &old[1]);
}

static void interrupt_disarm(const struct sigaction *old) {
  sigaction(SIGINT, &old[0], NULL);
  sigaction(SIGTERM, &old[1], NULL);
}

int ts_job_finish(ts_conn *c, const ts_job_cmd *o, uint64_t id, char *err) {
  ts_job_status st = {0};
  double t0 = ts_now();
  int mode = ts_progress_mode(o->quiet);
  struct sigaction old[2];
  interrupt_arm(o, id, mode == TS_PROGRESS_BAR, old); /* before the id is out: an interrupt from then on says it */
  if (!o->quiet) fprintf(stderr, "texsyn %s: job %llu on %s\n", o->cmd, (unsigned long long)id, o->server);
  int rc = ts_job_watch(c, id, o->cmd, mode, &st, err);
  interrupt_disarm(old);
  if (rc == 0 && st.state != TS_JOB_DONE)
    rc = ts_error(err, TS_EIO, "job %llu %s%s%s", (unsigned long long)id, ts_job_state_name(st.state),
                  st.text[0] ? ": " : "", st.text);
  if (rc == 0) rc = ts_job_fetch(c, id, &o->out, err);
  if (rc == 0 && !o->quiet) {
    char pool[48] = "no workers: the coordinator scanned alone";
    if (st.workers > 0) snprintf(pool, sizeof(pool), "%u worker%s", st.workers, st.workers == 1 ? "" : "s");
    fprintf(stderr, "texsyn: %s in %.2fs (job %llu on %s with %s)\n", result_name(o), ts_now() - t0,
            (unsigned long long)id, o->server, pool);
  }
  return rc;
}

static int run_remote(const ts_job_cmd *o) {
  char err[TS_ERR_LEN] = "";
  ts_conn c;
  uint64_t id = 0;
  int rc = ts_job_open(&c, o, err);
  if (rc != 0) {
    fprintf(stderr, "texsyn %s: %s\n", o->cmd, err);
    return 1;
  }
  rc = ts_job_submit(&c, o, &id, err);
  if (rc == 0 && o->detach) printf("%llu\n", (unsigned long long)id);
  else if (rc == 0) rc = ts_job_finish(&c, o, id, err);
  if (rc != 0) fprintf(stderr, "texsyn %s: %s\n", o->cmd, err);
  ts_conn_close(&c);
  return rc == 0 ? 0 : 1;
}

/* ---- the job ----------------------------------------------------------- */

/* The inputs are read here in either case: a job the engine refuses is
 * refused before anything travels or runs. */
int ts_job_run(ts_job_cmd *o) {
  char err[TS_ERR_LEN] = "", msg[4096];
  const ts_engine *e = o->spec.engine;
  if (!o->detach && ts_job_check_outputs(o, err) != 0) {
    fprintf(stderr, "texsyn %s: %s\n", o->cmd, err);
    return 1;
  }
  ts_engine_inputs names;
  e->inputs(&o->spec.params, &names);
  ts_engine_file *in = calloc(TS_ENGINE_MAX_INPUTS, sizeof(*in)); /* 4 KB of path each */
  const ts_image *inp[TS_ENGINE_MAX_INPUTS];
  if (in == NULL || read_inputs(o, names.n, in, err) != 0) {
    fprintf(stderr, "texsyn %s: %s\n", o->cmd, in == NULL ? "out of memory" : err);
    free(in);
    return 1;
  }
  for (int k = 0; k < names.n; k++) inp[k] = &in[k].img;
  int status = 0;
  if (e->check(&o->spec.params, inp, msg, sizeof(msg)) != 0) {
    fprintf(stderr, "texsyn %s: invalid parameters for %s (%dx%d):\n%s\n", o->cmd, o->in[0], in[0].img.width,
            in[0].img.height, msg);
    status = 2;
  } else if (o->server == NULL) {
    int rc = run_embedded(o, inp, err);
    if (rc != 0) fprintf(stderr, "texsyn %s: %s\n", o->cmd, err);
    status = rc == 0 ? 0 : 1;
  }
  for (int k = 0; k < names.n; k++) ts_image_free(&in[k].img);
  free(in);
  return status != 0 || o->server == NULL ? status : run_remote(o);
}

int ts_job_set_key(ts_job_cmd *o, const char *key, const char *value, const char *what, char *err) {
  int rc = o->spec.engine->spec_set(o->spec.params.bytes, key, value);
  return rc != 0 ? ts_error(err, TS_EINVAL, "%s %s: not a valid value (see texsyn %s --help)", what, value, o->cmd) : 0;
}

int ts_job_key_option(ts_job_cmd *o, const ts_key_option *t, size_t n, int c, const char *arg, char *err) {
  for (size_t i = 0; i < n; i++)
    if (t[i].opt == c) return ts_job_set_key(o, t[i].key, arg, t[i].name, err);
  return TS_ENOENT;
}
