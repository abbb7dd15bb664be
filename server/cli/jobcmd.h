/* jobcmd.h - what the CLI's job commands (texsyn synth, stylize, energy)
 * share: the options every job takes, the output paths by spec key, the
 * checks made before any work (outputs writable, inputs readable, the
 * engine's verdict on them), and running the job in-process or on a
 * coordinator (same options, same bytes). A command parses its own
 * options into a ts_job_cmd and hands it to ts_job_run. */
#ifndef TS_JOBCMD_H
#define TS_JOBCMD_H

#include <getopt.h>
#include <stdint.h>

#include "client.h"
#include "engine.h"
#include "jobspec.h"
#include "suggest.h"

/* The scan threads a job takes without --threads: the online CPUs, as a
 * worker does (1..1024). The bytes do not depend on it. */
int ts_default_threads(void);

/* Local paths of a job's outputs, by spec key ("output" is -o). */
typedef struct {
  int n;
  const char *key[TS_ENGINE_MAX_OUTPUTS * 2];
  const char *path[TS_ENGINE_MAX_OUTPUTS * 2];
} ts_output_paths;

/* The path given for output key, or NULL. */
const char *ts_output_path(const ts_output_paths *t, const char *key);
/* Records (or replaces) the path of output key. */
void ts_output_set(ts_output_paths *t, const char *key, const char *path);

typedef struct {
  const char *cmd;                       /* "synth": messages say "texsyn synth: ..." */
  const char *result_name;               /* what the closing line names: NULL, the -o path */
  ts_jobspec spec;                       /* engine and parameters (wants follow from out) */
  const char *in[TS_ENGINE_MAX_INPUTS];  /* input paths, in the engine's order */
  ts_output_paths out;
  const char *server, *secret_file;
  int threads, quiet, detach, embedded;
  uint64_t max_pixels;
} ts_job_cmd;

/* Option codes of the options every job takes; a command numbers its own
 * from TS_OPT_OWN. */
enum {
  TS_OPT_THREADS = 256, TS_OPT_QUIET, TS_OPT_SERVER, TS_OPT_EMBEDDED, TS_OPT_DETACH, TS_OPT_SECRET,
  TS_OPT_REPORT, TS_OPT_MAXPIX, TS_OPT_HELP, TS_OPT_OWN
};

/* The options every job takes, for a command's getopt_long table: where
 * and how it runs, then (TS_JOB_LONGOPTS) the result image and report of
 * a job whose result is an image. */
#define TS_JOB_RUN_LONGOPTS                                                                           \
  {"threads", required_argument, 0, TS_OPT_THREADS}, {"quiet", no_argument, 0, TS_OPT_QUIET},        \
      {"server", required_argument, 0, TS_OPT_SERVER}, {"embedded", no_argument, 0, TS_OPT_EMBEDDED}, \
      {"detach", no_argument, 0, TS_OPT_DETACH}, {"secret-file", required_argument, 0, TS_OPT_SECRET}, \
      {"max-pixels", required_argument, 0, TS_OPT_MAXPIX}, {"help", no_argument, 0, TS_OPT_HELP}
#define TS_JOB_LONGOPTS                                                                               \
  {"output", required_argument, 0, 'o'}, {"report", required_argument, 0, TS_OPT_REPORT}, TS_JOB_RUN_LONGOPTS

/* Their lines of a command's --help: TS_JOB_RUN_HELP those of
 * TS_JOB_RUN_LONGOPTS, ts_job_options_help all of them. */
#define TS_JOB_RUN_HELP                                                                      \
  "  --threads T          scan threads, 1..1024 (default: the online CPUs)\n"                               \
  "  --max-pixels N       refuse inputs and outputs above N pixels (default 268435456)\n"    \
  "  --quiet              nothing on stderr but errors: no progress (else a bar on a\n"    \
  "                       terminal, or a line as each level starts and every 10 s),\n"   \
  "                       no job id, no closing line\n"                                    \
  "  --server HOST:PORT   run the job on a texsyn-server (and its workers) instead\n"        \
  "                       of in-process; same options, same output bytes\n"                 \
  "                       (default: $TEXSYN_SERVER if set, else in-process)\n"              \
  "  --embedded           run in-process even if $TEXSYN_SERVER is set\n"                    \
  "  --detach             with --server: print the job id and return at once\n"             \
  "                       (then texsyn watch/fetch ID)\n"                                    \
  "  --secret-file PATH   with --server: your client key, an admin key or the shared\n"     \
  "                       secret (default: $TEXSYN_SECRET_FILE if set)\n"
extern const char *const ts_job_options_help;

/* A job command for engine e with its defaults. */
void ts_job_cmd_init(ts_job_cmd *o, const char *cmd, const ts_engine *e);
/* Takes option c if it is one of every job's: 0, TS_EINVAL with a message,
 * or TS_ENOENT when c is the command's own. */
int ts_job_option(ts_job_cmd *o, int c, const char *arg, char *err);
/* After the options: where the job runs, and what every job needs. */
int ts_job_parse_end(ts_job_cmd *o, char *err);
/* Runs the job: checks, reads, runs embedded or remotely, writes. The
 * process exit status: 0, 1 (I/O, a failed job), 2 (bad parameters). */
int ts_job_run(ts_job_cmd *o);

/* The steps of ts_job_run, for commands that run several jobs (frames.h):
 * whether every output path can be written; a checked job run on the
 * inputs in-process on `search`, its outputs written; a job submitted to
 * a coordinator (its id in *id). */
int ts_job_check_outputs(const ts_job_cmd *o, char *err);
int ts_job_embedded(const ts_job_cmd *o, const ts_image *const *in, ts_search *search, char *err);
int ts_job_submit(ts_conn *c, const ts_job_cmd *o, uint64_t *id, char *err);
/* Connects to o's coordinator; a failure's message says that nothing was
 * submitted and how to run in-process. */
int ts_job_open(ts_conn *c, const ts_job_cmd *o, char *err);
/* Follows a submitted job to its end (a progress bar unless quiet) and
 * writes its files to o's output paths: 0, or TS_EIO when it failed or
 * was canceled (its reason in the message), or the connection's error. */
int ts_job_finish(ts_conn *c, const ts_job_cmd *o, uint64_t id, char *err);

/* Sets spec key `key` of o's engine to value; a value the engine refuses
 * is TS_EINVAL naming `what` (the option) and o's --help. */
int ts_job_set_key(ts_job_cmd *o, const char *key, const char *value, const char *what, char *err);

/* An option that sets one spec key to its value as given. */
typedef struct {
  int opt;
  const char *key, *name;
} ts_key_option;
/* Takes option c if the table (n entries) has it: 0 or TS_EINVAL as
 * ts_job_set_key; TS_ENOENT when c is not in the table. */
int ts_job_key_option(ts_job_cmd *o, const ts_key_option *t, size_t n, int c, const char *arg, char *err);

/* The shared parsers (util.h), with the option named in the message. */
int ts_arg_long(const char *opt, const char *s, long lo, long hi, long *out, char *err);
int ts_arg_u64(const char *opt, const char *s, uint64_t *out, char *err);
int ts_arg_double(const char *opt, const char *s, double *out, char *err);
/* WxH, each side 1..TS_OUTPUT_SIDE_MAX. */
int ts_arg_size(const char *opt, const char *s, int *w, int *h, char *err);

/* The coordinator from $TEXSYN_SERVER, or NULL when unset or empty. */
const char *ts_env_server(void);
/* The job commands' coordinator without --server and $TEXSYN_SERVER
 * (passed as this pointer, messages call it the default). */
extern const char ts_default_server[];
/* Connects to a coordinator with the shared secret from path, else
 * $TEXSYN_SECRET_FILE, else none; a failure's message says what to check
 * (the address, the coordinator, the secret and where it came from). */
int ts_job_connect(ts_conn *c, const char *addr, const char *path, char *err);
/* How a client shows a job's progress on stderr: not at all (--quiet), a
 * bar redrawn in place (a terminal), or plain lines, one as each level
 * starts and every 10 s (a batch job's or Slurm's log). */
enum { TS_PROGRESS_NONE, TS_PROGRESS_BAR, TS_PROGRESS_LINES };
int ts_progress_mode(int quiet);
/* Follows a job until it ends, showing its progress in mode (lines say
 * "texsyn CMD: ..."); its final status in *last. */
int ts_job_watch(ts_conn *c, uint64_t id, const char *cmd, int mode, ts_job_status *last, char *err);
/* Writes a finished job's files to the paths given for their outputs. */
int ts_job_fetch(ts_conn *c, uint64_t id, const ts_output_paths *t, char *err);

#endif
