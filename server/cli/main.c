/* main.c - the `texsyn` command line: the command table (kCommands, at
 * the end: each command's name, entry and line of `texsyn --help`), the
 * job commands that manage jobs on a coordinator (status, watch, fetch,
 * cancel, delete, workers), quality, shuffle and simd. The job-running
 * commands live in rooms of their own (synth.c, stylize.c, segment.c,
 * aerial.c; their shared part in jobcmd.c), as does modbus (mbclient.c).
 */
#include <errno.h>
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "client.h"
#include "jobcmd.h"
#include "error.h"
#include "util.h"
#include "image.h"
#include "jobspec.h"
#include "l1.h"
#include "mbclient.h"
#include "aerial.h"
#include "engine.h"
#include "fillcmd.h"
#include "catalogue_cmd.h"
#include "flicker.h"
#include "mrf.h"
#include "paramopt.h"
#include "quality.h"
#include "segment.h"
#include "stylize.h"
#include "synth.h"
#include "video.h"
#include "search.h"


/* ---- quality and shuffle ---------------------------------------------- */

static int read_luma(const char *path, ts_plane *pl, char *err) {
  ts_image img = {0};
  int rc = ts_image_read(path, &img, NULL, err);
  if (rc != 0) return rc;
  rc = ts_plane_alloc(pl, img.width, img.height);
  if (rc == 0) ts_image_luma8(&img, pl->px);
  else ts_error(err, rc, "out of memory");
  ts_image_free(&img);
  return rc;
}

static const struct option eval_longopts[] = {
    {"ref", required_argument, 0, OPT_REF},       {"image", required_argument, 0, OPT_IMAGE},
    {"output", required_argument, 0, 'o'},        {"size", required_argument, 0, OPT_SIZE},
    {"wn", required_argument, 0, OPT_WN},         {"block", required_argument, 0, OPT_BLOCK},
    {"samples", required_argument, 0, OPT_SAMPLES}, {"seed", required_argument, 0, OPT_SEED},
    {"threads", required_argument, 0, TS_OPT_THREADS}, {"help", no_argument, 0, TS_OPT_HELP},
    {0, 0, 0, 0}};

typedef struct {
  const char *ref, *image, *out;
  int w, h, wn, block, threads;
  long samples;
  uint64_t seed;
} eval_opts;

static int eval_parse(int argc, char **argv, eval_opts *o, const char *usage, char *err) {
  *o = (eval_opts){NULL, NULL, NULL, 0, 0, 7, 16, ts_default_threads(), 2000, 1};
  optind = 1;
  opterr = 0;
  int c, rc = 0;
  long v;
  while (rc == 0 && (c = getopt_long(argc, argv, "o:h", eval_longopts, NULL)) != -1) {
    switch (c) {
    case OPT_REF: o->ref = optarg; break;
    case OPT_IMAGE: o->image = optarg; break;
    case 'o': o->out = optarg; break;
    case OPT_SIZE: rc = ts_arg_size("--size", optarg, &o->w, &o->h, err); break;
    case OPT_WN: rc = ts_arg_long("--wn", optarg, 3, TS_MAX_WN, &v, err); o->wn = (int)(v | 1); break;
    case OPT_BLOCK: rc = ts_arg_long("--block", optarg, 1, 4096, &v, err); o->block = (int)v; break;
    case OPT_SAMPLES: rc = ts_arg_long("--samples", optarg, 1, 10000000, &o->samples, err); break;
    case OPT_SEED: rc = ts_arg_u64("--seed", optarg, &o->seed, err); break;
    case TS_OPT_THREADS: rc = ts_arg_long("--threads", optarg, 1, 1024, &v, err); o->threads = (int)v; break;
    case TS_OPT_HELP: case 'h': printf("%s", usage); exit(0);
    default: rc = ts_arg_unknown(argv[0], argv[optind - 1], eval_longopts, err);
    }
  }
  return rc;
}

static const char *kQualityUsage =
    "usage: texsyn quality --ref REF --image IMG [--wn 7] [--samples 2000] [--seed 1] [--threads T]\n"
    "Prints the mean exact best-match error (grey levels per pixel) of WNxWN windows of IMG\n"
    "(read on the torus) against REF, for inner windows and for windows across the tiling seam.\n";

static int cmd_quality(int argc, char **argv) {
  char err[TS_ERR_LEN] = "";
  eval_opts o;
  int rc = eval_parse(argc, argv, &o, kQualityUsage, err);
  if (rc == 0 && (o.ref == NULL || o.image == NULL))
    rc = ts_error(err, TS_EINVAL, "--ref and --image are required\n%s", kQualityUsage);
  if (rc != 0) {
    fprintf(stderr, "texsyn quality: %s\n", err);
    return 2; /* a usage error, as in every command */
  }
  ts_plane ref = {0}, img = {0};
  ts_search *search = NULL;
  ts_quality q;
  rc = read_luma(o.ref, &ref, err);
  if (rc == 0) rc = read_luma(o.image, &img, err);
  if (rc == 0) rc = ts_search_local_create(&search, o.threads, NULL, err);
  if (rc == 0) rc = ts_quality_measure(search, &ref, &img, o.wn, (uint32_t)o.samples, o.seed, &q, err);
  if (rc == 0)
    printf("{\"wn\": %d, \"inner_mean\": %.4f, \"inner_n\": %u, \"seam_mean\": %.4f, \"seam_n\": %u}\n",
           o.wn, q.mean_inner, q.n_inner, q.mean_seam, q.n_seam);
  else
    fprintf(stderr, "texsyn quality: %s\n", err);
  ts_search_destroy(search);
  ts_plane_free(&ref);
  ts_plane_free(&img);
  return rc == 0 ? 0 : 1;
}

static const char *kShuffleUsage =
    "usage: texsyn shuffle --ref REF -o OUT --size WxH [--block 16] [--seed 1]\n"
    "Tiles OUT with BLOCKxBLOCK blocks of REF taken at random positions (a baseline).\n";

static int cmd_shuffle(int argc, char **argv) {
  char err[TS_ERR_LEN] = "";
  eval_opts o;
  int rc = eval_parse(argc, argv, &o, kShuffleUsage, err);
  if (rc == 0 && (o.ref == NULL || o.out == NULL || o.w == 0))
    rc = ts_error(err, TS_EINVAL, "--ref, -o and --size are required\n%s", kShuffleUsage);
  if (rc != 0) {
    fprintf(stderr, "texsyn shuffle: %s\n", err);
    return 2; /* a usage error, as in every command */
  }
  ts_image ref = {0}, out = {0};
  uint32_t *map = NULL;
  rc = ts_image_read(o.ref, &ref, NULL, err);
  if (rc == 0 && (map = malloc(sizeof(uint32_t) * 2 * (size_t)o.w * o.h)) == NULL)
    rc = ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0) {
    ts_plane shape = {ref.width, ref.height, NULL};
    rc = ts_shuffle_blocks(&shape, o.w, o.h, o.block, o.seed, map);
    if (rc != 0) ts_error(err, rc, "--block %d does not fit the %dx%d reference", o.block, ref.width, ref.height);
  }
  if (rc == 0) rc = ts_image_alloc(&out, o.w, o.h, ref.channels, ref.type, err);
  if (rc == 0) {
    for (long i = 0; i < (long)o.w * o.h; i++)
      ts_image_copy_pixel(&out, (int)(i % o.w), (int)(i / o.w), &ref, (int)map[2 * i], (int)map[2 * i + 1]);
    rc = ts_image_write(o.out, &out, ref.meta, err);
  }
  if (rc != 0) fprintf(stderr, "texsyn shuffle: %s\n", err);
  free(map);
  ts_image_free(&out);
  ts_image_free(&ref);
  return rc == 0 ? 0 : 1;
}

static int cmd_simd(void) {
  const ts_l1_impl *sel = NULL;
  char err[TS_ERR_LEN];
  int rc = ts_l1_select(&sel, err);
  for (int i = 0; i < TS_SIMD_COUNT; i++) {
    const ts_l1_impl *impl = ts_l1_impl_get((ts_simd)i);
    if (impl) printf("%s%s\n", impl->name, impl == sel ? " (selected)" : "");
  }
  if (rc != 0) fprintf(stderr, "texsyn simd: %s\n", err);
  return rc == 0 ? 0 : 1;
}

/* ---- job commands --------------------------------------------------------- */

enum { OPT_ENDED = OPT_NNF + 1 }; /* delete --ended */

static const char *kJobUsage =
    "usage: texsyn status [ID] | watch ID | fetch ID -o OUT | cancel ID | delete ID|--ended\n"
    "              | workers [--server HOST:PORT]\n"
    "\n"
    "  status [ID]   every job the coordinator knows, a line each under a header: id,\n"
    "                state (queued, held: queued while the queue is paused, running,\n"
    "                done, failed, canceled), engine, owner (its client key's name,\n"
    "                else the client's USER@HOST), when it was submitted, started\n"
    "                and ended (local time today, else the date), progress, output\n"
    "                (the -o name it was submitted with; - for another owner's job\n"
    "                seen with a client key), then what it does or why it ended;\n"
    "                with ID that job's line and every field in full\n"
    "  watch ID      follow a job (level, % of blocks, ETA, workers) until it ends\n"
    "  fetch ID      write a finished job's results: -o OUT (the image, or an energy\n"
    "                job's JSON) and those of the side outputs asked for when it\n"
    "                was submitted: --report F, --copy-map F, --copy-map-raw F,\n"
    "                --usage-map F (synth), --nnf F (stylize); one the job did not\n"
    "                make is an error, and then nothing is written; an image is\n"
    "                converted to the format its path names (-o x.tif of a PNG)\n"
    "  cancel ID     stop a queued or running job\n"
    "  delete ID     remove a finished, failed or canceled job and its files from the\n"
    "                coordinator's spool (frees space under its --max-spool limit)\n"
    "  delete --ended  every job that has ended (texsyn-server --keep-ended does it\n"
    "                after a time); prints how many and which\n"
    "  workers       the worker pool under a header: name (--name), address, threads,\n"
    "                kernel, calibrated rate and the rate slices are sized with (bytes\n"
    "                scanned/s; measured on batches once a lasting deviation rebalanced\n"
    "                them), slice share (0 while draining or dead), state (calibrating,\n"
    "                active, draining, dead: dropped, shown with when for an hour or\n"
    "                until it rejoins), batches\n"
    "\n"
    "  --server HOST:PORT   the coordinator (default: $TEXSYN_SERVER, else 127.0.0.1:7070)\n"
    "  --secret-file PATH   your client key, an admin key or the shared secret\n"
    "                       (default: $TEXSYN_SECRET_FILE if set)\n"
    "  --quiet              no progress (watch): without it a bar on a terminal, else\n"
    "                       a line as each level starts and every 10 s\n";

typedef struct {
  const char *server, *secret_file;
  uint64_t id;
  int have_id, quiet, ended;
  ts_output_paths t;
} job_opts;

static int job_parse(int argc, char **argv, job_opts *o, char *err) {
  static const struct option longopts[] = {
      {"server", required_argument, 0, TS_OPT_SERVER},    {"output", required_argument, 0, 'o'},
      {"copy-map", required_argument, 0, OPT_COPY},       {"copy-map-raw", required_argument, 0, OPT_COPY_RAW},
      {"usage-map", required_argument, 0, OPT_USAGE_MAP}, {"report", required_argument, 0, TS_OPT_REPORT},
      {"nnf", required_argument, 0, OPT_NNF},             {"quiet", no_argument, 0, TS_OPT_QUIET},
      {"help", no_argument, 0, TS_OPT_HELP},              {"secret-file", required_argument, 0, TS_OPT_SECRET},
      {"ended", no_argument, 0, OPT_ENDED},               {0, 0, 0, 0}};
  memset(o, 0, sizeof(*o));
  o->server = ts_env_server() ? ts_env_server() : ts_default_server;
  optind = 1;
  opterr = 0;
  int c;
  while ((c = getopt_long(argc, argv, "o:h", longopts, NULL)) != -1) {
    switch (c) {
    case TS_OPT_SERVER: o->server = optarg; break;
    case TS_OPT_SECRET: o->secret_file = optarg; break;
    case TS_OPT_QUIET: o->quiet = 1; break;
    case OPT_ENDED: o->ended = 1; break;
    case TS_OPT_HELP: case 'h': printf("%s", kJobUsage); exit(0);
    case 'o': ts_output_set(&o->t, "output", optarg); break;
    case TS_OPT_REPORT: ts_output_set(&o->t, "report", optarg); break;
    default:
      if (!ts_synth_output_option(&o->t, c, optarg)) return ts_arg_unknown(argv[0], argv[optind - 1], longopts, err);
    }
  }
  if (optind < argc) {
    int rc = ts_arg_u64("job id", argv[optind], &o->id, err);
    if (rc != 0) return rc;
    if (o->id == 0) return ts_error(err, TS_EINVAL, "job ids start at 1");
    o->have_id = 1;
    optind++;
  }
  if (optind < argc) return ts_error(err, TS_EINVAL, "unexpected argument '%s'", argv[optind]);
  return 0;
}

/* ---- what status and workers show ---------------------------------------- */

/* A job's state as an operator reads it: a queued job behind a paused
 * queue is held. */
static const char *state_shown(const ts_job_status *s) {
  return s->flags & TS_JOB_HELD ? "held" : ts_job_state_name(s->state);
}

/* A time in a listing: the clock time for today, the date before (local
 * time); "-" for none. */
static void time_compact(uint64_t ms, char *out, size_t cap) {
  if (ms == 0) {
    snprintf(out, cap, "-");
    return;
  }
  time_t t = (time_t)(ms / 1000), now = time(NULL);
  struct tm at, today;
  localtime_r(&t, &at);
  localtime_r(&now, &today);
  int same_day = at.tm_year == today.tm_year && at.tm_yday == today.tm_yday;
  strftime(out, cap, same_day ? "%H:%M:%S" : "%Y-%m-%d", &at);
}

/* A span of seconds as people say it: 0.4s, 12s, 3m05s, 2h10m, 3d04h. */
static void span_of(double s, char *out, size_t cap) {
  long v = (long)s;
  if (s < 10) snprintf(out, cap, "%.1fs", s < 0 ? 0.0 : s);
  else if (v < 60) snprintf(out, cap, "%lds", v);
  else if (v < 3600) snprintf(out, cap, "%ldm%02lds", v / 60, v % 60);
  else if (v < 86400) snprintf(out, cap, "%ldh%02ldm", v / 3600, v % 3600 / 60);
  else snprintf(out, cap, "%ldd%02ldh", v / 86400, v % 86400 / 3600);
}

/* A time in detail: local date and time, how long ago. */
static void time_full(uint64_t ms, char *out, size_t cap) {
  if (ms == 0) {
    snprintf(out, cap, "-");
    return;
  }
  time_t t = (time_t)(ms / 1000);
  struct tm at;
  localtime_r(&t, &at);
  char when[64], ago[32];
  strftime(when, sizeof(when), "%Y-%m-%d %H:%M:%S %Z", &at);
  span_of((double)time(NULL) - (double)t, ago, sizeof(ago));
  snprintf(out, cap, "%s (%s ago)", when, ago);
}

/* How far a job got: "42.0%", or "-" before it ran. */
static void progress_compact(const ts_job_status *s, char *out, size_t cap) {
  if (s->state == TS_JOB_RUNNING || s->state == TS_JOB_DONE || s->permille > 0)
    snprintf(out, cap, "%.1f%%", s->permille / 10.0);
  else snprintf(out, cap, "-");
}

/* What a job is doing or why it ended, one line: the level, ETA and
 * workers of a running job, then its text. */
static void note_of(const ts_job_status *s, char *out, size_t cap) {
  int n = 0;
  if (s->state == TS_JOB_RUNNING) {
    char eta[32] = "ETA ?";
    if (s->eta_ms != UINT32_MAX) snprintf(eta, sizeof(eta), "ETA %.1fs", s->eta_ms / 1000.0);
    n = snprintf(out, cap, "level %d of %d, %s, %u worker%s", s->levels - s->level, s->levels, eta, s->workers,
                 s->workers == 1 ? "" : "s");
  } else if (s->flags & TS_JOB_HELD) {
    n = snprintf(out, cap, "the queue is paused; it starts once resumed (texsyn modbus ... --set pause=0)");
  } else {
    out[0] = '\0';
  }
  if (s->text[0] && n >= 0 && (size_t)n < cap) snprintf(out + n, cap - (size_t)n, "%s%s", n ? ": " : "", s->text);
}

/* One line per job: the summary `texsyn watch` ends with. */
static void print_status(const ts_job_status *s) {
  char note[TS_ERR_LEN + 128];
  note_of(s, note, sizeof(note));
  if (note[0]) printf("%-6llu %-9s %s\n", (unsigned long long)s->id, state_shown(s), note);
  else printf("%-6llu %s\n", (unsigned long long)s->id, state_shown(s));
}

/* `texsyn status ID`: the summary, then every field. */
static void print_detail(const ts_job_status *s) {
  char buf[128], span[32];
  print_status(s);
  printf("  engine     %s\n  owner      %s\n  output     %s\n", s->engine, s->owner, s->output[0] ? s->output : "-");
  time_full(s->submitted_ms, buf, sizeof(buf));
  printf("  submitted  %s\n", buf);
  time_full(s->started_ms, buf, sizeof(buf));
  printf("  started    %s", buf);
  if (s->started_ms >= s->submitted_ms && s->started_ms != 0 && s->submitted_ms != 0) {
    span_of((double)(s->started_ms - s->submitted_ms) / 1000.0, span, sizeof(span));
    printf(", %s after it was submitted", span);
  }
  time_full(s->ended_ms, buf, sizeof(buf));
  printf("\n  ended      %s", buf);
  if (s->ended_ms >= s->started_ms && s->started_ms != 0 && s->ended_ms != 0) {
    span_of((double)(s->ended_ms - s->started_ms) / 1000.0, span, sizeof(span));
    printf(", ran %s", span);
  }
  progress_compact(s, buf, sizeof(buf));
  printf("\n  progress   %s", buf);
  if (s->levels > 0 && s->state == TS_JOB_RUNNING) printf(" (level %d of %d)", s->levels - s->level, s->levels);
  printf("\n");
}

/* Column widths of the listing: the widest of the header and the values. */
typedef struct {
  int state, engine, owner;
} list_widths;

static int widest(int w, const char *s) {
  int n = (int)strlen(s);
  return n > w ? n : w;
}

/* `texsyn status`: a header, then a line per job, oldest first. */
static void print_list(const ts_job_status *s, uint32_t n) {
  list_widths w = {5, 6, 5};
  for (uint32_t i = 0; i < n; i++) {
    w.state = widest(w.state, state_shown(&s[i]));
    w.engine = widest(w.engine, s[i].engine);
    w.owner = widest(w.owner, s[i].owner);
  }
  printf("%-6s %-*s %-*s %-*s %-10s %-10s %-10s %-8s %s\n", "ID", w.state, "STATE", w.engine, "ENGINE", w.owner,
         "OWNER", "SUBMITTED", "STARTED", "ENDED", "PROGRESS", "OUTPUT");
  for (uint32_t i = 0; i < n; i++) {
    char sub[32], start[32], end[32], prog[32], note[TS_ERR_LEN + 128];
    time_compact(s[i].submitted_ms, sub, sizeof(sub));
    time_compact(s[i].started_ms, start, sizeof(start));
    time_compact(s[i].ended_ms, end, sizeof(end));
    progress_compact(&s[i], prog, sizeof(prog));
    note_of(&s[i], note, sizeof(note));
    printf("%-6llu %-*s %-*s %-*s %-10s %-10s %-10s %-8s %s%s%s\n", (unsigned long long)s[i].id, w.state,
           state_shown(&s[i]), w.engine, s[i].engine, w.owner, s[i].owner, sub, start, end, prog,
           s[i].output[0] ? s[i].output : "-", note[0] ? "  " : "", note);
  }
  if (n == 0) printf("(no jobs)\n");
}

/* The records of one job (id) or of every job (0): *out is malloc'd. */
static int fetch_records(ts_conn *c, uint64_t id, ts_job_status **out, uint32_t *n, char *err) {
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_status_req req = {id, 0};
  ts_msg_status_req_write(&w, &req);
  ts_frame f;
  int rc = ts_client_call(c, TS_MSG_STATUS, &w, 30000, &f, err);
  ts_wr_free(&w);
  /* As many records as the reply can hold: each takes at least 52 bytes. */
  uint32_t cap = rc == 0 ? f.len / 52 + 1 : 0;
  *out = rc == 0 ? malloc(sizeof(**out) * cap) : NULL;
  *n = 0;
  if (rc == 0 && *out == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory for %u job records", cap);
  if (rc == 0) rc = ts_msg_status_read(&f, *out, cap, n, err);
  return rc;
}

static int job_status(ts_conn *c, const job_opts *o, char *err) {
  ts_job_status *s;
  uint32_t n;
  int rc = fetch_records(c, o->have_id ? o->id : 0, &s, &n, err);
  if (rc == 0 && o->have_id && n != 1) rc = ts_error(err, TS_EPROTO, "%u records for one job", n);
  if (rc == 0 && o->have_id) print_detail(s);
  else if (rc == 0) print_list(s, n);
  free(s);
  return rc;
}

/* A worker's state as an operator reads it. */
static const char *worker_state_shown(int state) {
  return state == TS_WORKER_READY ? "active" : state == TS_WORKER_FAILED ? "dead" : ts_worker_state_name(state);
}

static int job_workers(ts_conn *c, const job_opts *o, char *err) {
  (void)o;
  ts_wr w;
  ts_wr_init(&w);
  ts_frame f;
  int rc = ts_client_call(c, TS_MSG_POOL, &w, 30000, &f, err);
  ts_worker_info *wi = rc == 0 ? malloc(sizeof(*wi) * TS_POOL_MAX_REPORT) : NULL;
  uint32_t n = 0;
  if (rc == 0 && wi == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0) rc = ts_msg_pool_read(&f, wi, TS_POOL_MAX_REPORT, &n, err);
  int wn = 4;
  for (uint32_t i = 0; rc == 0 && i < n; i++) wn = widest(wn, wi[i].name[0] ? wi[i].name : "-");
  if (rc == 0)
    printf("%-*s %-24s %7s %-7s %12s %12s %6s %-11s %9s\n", wn, "NAME", "ADDRESS", "THREADS", "SIMD", "CALIBRATED",
           "RATE", "SHARE", "STATE", "BATCHES");
  for (uint32_t i = 0; rc == 0 && i < n; i++) {
    const ts_l1_impl *impl = ts_l1_impl_get((ts_simd)wi[i].simd);
    printf("%-*s %-24s %7u %-7s %12.4g %12.4g %5.1f%% %-11s %9llu", wn, wi[i].name[0] ? wi[i].name : "-", wi[i].addr,
           wi[i].threads, impl ? impl->name : "?", (double)wi[i].calibrated, (double)wi[i].rate, wi[i].share / 10.0,
           worker_state_shown(wi[i].state), (unsigned long long)wi[i].batches);
    if (wi[i].died_ms != 0) {
      char when[128];
      time_full(wi[i].died_ms, when, sizeof(when));
      printf("  dropped %s", when);
    }
    printf("\n");
  }
  if (rc == 0 && n == 0) printf("(no workers: the coordinator scans by itself)\n");
  free(wi);
  return rc;
}

/* A running job stops at its next batch, not when the coordinator takes
 * the cancel: `cancel` returns once it has, so that what follows (status,
 * delete) finds it canceled. */
static int job_cancel_wait(ts_conn *c, uint64_t id, char *err) {
  ts_job_status st;
  int rc = ts_job_watch(c, id, NULL, TS_PROGRESS_NONE, &st, err);
  if (rc == 0 && st.state != TS_JOB_CANCELED)
    rc = ts_error(err, TS_EINVAL, "job %llu ended %s before the cancel reached it", (unsigned long long)id,
                  ts_job_state_name(st.state));
  if (rc == 0) printf("job %llu canceled\n", (unsigned long long)id);
  return rc;
}

/* ---- the job commands' actions: connected, their options parsed ---------- */

static int job_fetch(ts_conn *c, const job_opts *o, char *err) { return ts_job_fetch(c, o->id, &o->t, err); }

static int job_watch(ts_conn *c, const job_opts *o, char *err) {
  ts_job_status st;
  int rc = ts_job_watch(c, o->id, "watch", ts_progress_mode(o->quiet), &st, err);
  if (rc == 0) print_status(&st);
  if (rc == 0 && st.state != TS_JOB_DONE)
    rc = ts_error(err, TS_EINVAL, "job %llu %s", (unsigned long long)o->id, ts_job_state_name(st.state));
  return rc;
}

/* Sends a request about job o->id whose reply says only that it was done. */
static int job_request(ts_conn *c, uint8_t type, const job_opts *o, char *err) {
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_jobid_write(&w, o->id);
  ts_frame f;
  int rc = ts_client_call(c, type, &w, 30000, &f, err);
  ts_wr_free(&w);
  return rc;
}

static int job_cancel(ts_conn *c, const job_opts *o, char *err) {
  int rc = job_request(c, TS_MSG_CANCEL, o, err);
  return rc == 0 ? job_cancel_wait(c, o->id, err) : rc;
}

/* delete --ended: every job that has ended, each by its own request; one
 * gone meanwhile (deleted by another client, expired) is not missed. */
static int delete_ended(ts_conn *c, const job_opts *o, char *err) {
  ts_job_status *s;
  uint32_t n, deleted = 0;
  int rc = fetch_records(c, 0, &s, &n, err);
  char ids[1024] = "";
  size_t len = 0;
  for (uint32_t i = 0; rc == 0 && i < n; i++) {
    if (s[i].state < TS_JOB_DONE) continue;
    job_opts one = *o;
    one.id = s[i].id;
    rc = job_request(c, TS_MSG_DELETE, &one, err);
    if (rc == TS_ENOENT) {
      rc = 0;
      continue;
    }
    if (rc != 0) break;
    deleted++;
    int k = snprintf(ids + len, sizeof(ids) - len, "%s%llu (%s)", len ? ", " : "", (unsigned long long)s[i].id,
                     ts_job_state_name(s[i].state));
    if (k > 0 && (size_t)k < sizeof(ids) - len) len += (size_t)k;
    else if (len + 4 < sizeof(ids)) len += (size_t)snprintf(ids + len, sizeof(ids) - len, "...");
  }
  free(s);
  if (deleted > 0) printf("deleted %u ended job%s: %s\n", deleted, deleted == 1 ? "" : "s", ids);
  else if (rc == 0) printf("no ended jobs to delete\n");
  return rc;
}

static int job_delete(ts_conn *c, const job_opts *o, char *err) {
  if (o->ended) return delete_ended(c, o, err);
  int rc = job_request(c, TS_MSG_DELETE, o, err);
  if (rc == 0) printf("job %llu deleted\n", (unsigned long long)o->id);
  return rc;
}

/* ---- the command table ------------------------------------------------ */

typedef int job_action(ts_conn *c, const job_opts *o, char *err);

/* A command: its own main (argv[0] its name), or a job command's action
 * (with job_parse's options, a job id if needs_id, then connected). The
 * help line is texsyn --help's; NULL leaves an alias out. */
typedef struct {
  const char *name;
  int (*run)(int argc, char **argv);
  job_action *job;
  int needs_id;
  const char *help;
} command;

static int cmd_simd_main(int argc, char **argv) {
  static const char *usage = "usage: texsyn simd\n"
                             "Lists the L1 kernel variants this CPU supports; the one texsyn uses is marked\n"
                             "(selected). TEXSYN_SIMD=scalar|mmx|sse2|avx2|avx512 forces one.\n";
  if (argc == 2 && (strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0)) {
    printf("%s", usage);
    return 0;
  }
  if (argc > 1) {
    fprintf(stderr, "texsyn simd: unexpected argument '%s'\n%s", argv[1], usage);
    return 2;
  }
  return cmd_simd();
}

static int cmd_help(int argc, char **argv);
static int cmd_version(int argc, char **argv) {
  (void)argc;
  (void)argv;
  ts_version_print("texsyn");
  return 0;
}

static const command kCommands[] = {
    {"synth", ts_cmd_synth, NULL, 0, "synthesise a texture from a reference (alias: run), or fill a hole"},
    {"run", ts_cmd_synth, NULL, 0, NULL},
    {"aerial", ts_cmd_aerial, NULL, 0, "build an aerial image from a land-use class map and a catalogue"},
    {"catalogue", ts_cmd_catalogue, NULL, 0, "cut an aerial catalogue's references from an orthophoto and its class map"},
    {"stylize", ts_cmd_stylize, NULL, 0, "paint a target in the style of an exemplar, guided by image pairs"},
    {"energy", ts_cmd_energy, NULL, 0, "score a stylized image: mean exact best guided patch distance, coverage"},
    {"apply-nnf", ts_cmd_apply_nnf, NULL, 0, "vote a stylize --nnf field over another layer of the exemplar"},
    {"segment", ts_cmd_segment, NULL, 0, "label an image's pixels with the classes of training textures"},
    {"video", ts_cmd_video, NULL, 0, "stylize a sequence from painted keyframes along the optical flow"},
    {"flicker", ts_cmd_flicker, NULL, 0, "score a stylized sequence's temporal coherence: warp error along the flow"},
    {"quality", cmd_quality, NULL, 0, "neighbourhood error of an image against a reference"},
    {"shuffle", cmd_shuffle, NULL, 0, "random block shuffle of a reference (a baseline)"},
    {"simd", cmd_simd_main, NULL, 0, "list the L1 kernel variants this CPU supports"},
    {"params", ts_cmd_params, NULL, 0, "list the engines' parameters: job spec keys, options, defaults"},
    {"status", NULL, job_status, 0, "jobs on a coordinator (texsyn-server): one, or every job"},
    {"watch", NULL, job_watch, 1, "follow a job until it ends"},
    {"fetch", NULL, job_fetch, 1, "write a finished job's results"},
    {"cancel", NULL, job_cancel, 1, "stop a queued or running job"},
    {"delete", NULL, job_delete, 1, "remove an ended job and its files from the coordinator"},
    {"workers", NULL, job_workers, 0, "the coordinator's worker pool"},
    {"modbus", ts_mbclient_main, NULL, 0, "read a daemon's Modbus register map, or set its drain/pause coil"},
    {"help", cmd_help, NULL, 0, "this list (also --help, -h)"},
    {"--help", cmd_help, NULL, 0, NULL},
    {"-h", cmd_help, NULL, 0, NULL},
    {"--version", cmd_version, NULL, 0, "the texsyn release and wire protocol version"},
};
#define NCOMMANDS (sizeof(kCommands) / sizeof(kCommands[0]))

static void usage_main(FILE *f) {
  fprintf(f, "usage: texsyn COMMAND [options]   (texsyn COMMAND --help for details)\n");
  for (size_t i = 0; i < NCOMMANDS; i++)
    if (kCommands[i].help != NULL) fprintf(f, "  %-10s %s\n", kCommands[i].name, kCommands[i].help);
}

static int cmd_help(int argc, char **argv) {
  (void)argc;
  (void)argv;
  usage_main(stdout);
  return 0;
}

static int cmd_job(const command *cmd, int argc, char **argv) {
  char err[TS_ERR_LEN] = "";
  job_opts o;
  int rc = job_parse(argc, argv, &o, err);
  int by_state = cmd->job == job_delete && o.ended; /* delete --ended takes no id */
  if (rc == 0 && o.ended && cmd->job != job_delete)
    rc = ts_error(err, TS_EINVAL, "--ended is an option of texsyn delete only");
  else if (rc == 0 && by_state && o.have_id)
    rc = ts_error(err, TS_EINVAL, "delete takes a job id or --ended, not both");
  else if (rc == 0 && cmd->needs_id && !o.have_id && !by_state)
    rc = ts_error(err, TS_EINVAL, "%s needs a job id%s\n%s", cmd->name, cmd->job == job_delete ? " (or --ended)" : "",
                  kJobUsage);
  if (rc == 0 && cmd->job == job_fetch && ts_output_path(&o.t, "output") == NULL)
    rc = ts_error(err, TS_EINVAL, "fetch needs -o OUT");
  if (rc != 0) {
    fprintf(stderr, "texsyn %s: %s\n", cmd->name, err);
    return 2;
  }
  ts_conn c;
  rc = ts_job_connect(&c, o.server, o.secret_file, err);
  if (rc == 0) {
    rc = cmd->job(&c, &o, err);
    ts_conn_close(&c);
  }
  if (rc != 0) fprintf(stderr, "texsyn %s: %s\n", cmd->name, err);
  return rc == 0 ? 0 : 1;
}

/* texsyn COMMAND ...: the command's entry, or a hint at the closest one. */
int main(int argc, char **argv) {
  char err[TS_ERR_LEN];
  if (ts_auth_init(err) != 0) {
    fprintf(stderr, "texsyn: %s\n", err);
    return 1;
  }
  if (argc < 2) {
    usage_main(stderr);
    return 2;
  }
  const char *name = argv[1], *names[NCOMMANDS];
  size_t n = 0;
  for (size_t i = 0; i < NCOMMANDS; i++) {
    const command *cmd = &kCommands[i];
    if (strcmp(cmd->name, name) == 0) return cmd->run ? cmd->run(argc - 1, argv + 1) : cmd_job(cmd, argc - 1, argv + 1);
    if (cmd->help != NULL) names[n++] = cmd->name;
  }
  const char *best = ts_closest(name, strlen(name), names, n);
  if (best != NULL) fprintf(stderr, "texsyn: unknown command '%s'; did you mean '%s'?\n", name, best);
  else fprintf(stderr, "texsyn: unknown command '%s'\n", name);
  usage_main(stderr);
  return 2;
}
