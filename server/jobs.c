/* jobs.c - see jobs.h. */
#include "jobs.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "checkpoint.h"
#include "error.h"
#include "image.h"
#include "jobspec.h"
#include "log.h"
#include "spool.h"
#include "util.h"

#define JOBS_PATH 4096
#define JOBS_SPOOL_LEN 1024 /* longer spool paths are refused */
#define JOBS_CLIENT_LEN 128
#define JOBS_MAX_PIXELS_OPTION "texsyn-server --max-pixels" /* named in limit errors */

_Static_assert(TS_ENGINE_MAX_INPUTS <= TS_MSG_MAX_INPUTS && TS_ENGINE_KEY_LEN == TS_MSG_KEY_MAX,
               "an engine's inputs must fit a submission");

typedef struct job {
  uint64_t id;
  char client[JOBS_CLIENT_LEN];
  char dir[JOBS_SPOOL_LEN + 32];
  char ref_ext[TS_EXT_LEN]; /* input 0: ref.EXT */
  char more_ext[TS_ENGINE_MAX_INPUTS - 1][TS_EXT_LEN]; /* input k > 0: NAME.EXT, more_ext[k - 1] */
  ts_jobspec spec;
  ts_job_status st;
  uint64_t version;
  atomic_int cancel; /* set by a client's thread or the stop path, read by the job's */
  double started;
  uint64_t bytes; /* on disk, or reserved for results not written yet */
  struct job *next; /* all jobs, oldest first */
} job;

typedef struct client_share {
  char client[JOBS_CLIENT_LEN];
  uint64_t started;    /* jobs started: the fairness count */
  uint32_t unfinished; /* jobs accepted and not final: the limit's count */
  struct client_share *next;
} client_share;

struct ts_jobs {
  ts_jobs_opts o;
  char spool[JOBS_SPOOL_LEN];
  pthread_mutex_t lock;
  pthread_cond_t changed; /* any job's status changed, or a job queued */
  job *head, *tail;
  client_share *shares;
  uint64_t next_id;
  uint64_t spool_bytes; /* sum of the jobs' bytes */
  int stop;
  atomic_int stopping; /* read by the engines (and runners, unlocked): stop at a checkpoint */
  int running; /* jobs in run_job */
  int paused; /* no queued job starts */
  uint64_t last_ended; /* id of the job that ended last */
  int nrunners;
  pthread_t runners[64];
  int lock_fd; /* SPOOL/lock, flocked: this coordinator's spool */
};

/* The queue's lines go to the daemon's log (log.h). */
#define jobs_log(j, ...) ((void)(j), ts_log(__VA_ARGS__))

/* ---- files ------------------------------------------------------------- */

/* Writes data to path atomically and durably: a temporary file, fsync,
 * rename, then the directory's fsync (ts_file_commit says why in that
 * order). A kill at any moment leaves the old file or the new one; once
 * this returns, a power loss leaves the new one. */
static int write_atomic(const char *path, const void *data, size_t len, char *err) {
  char tmp[JOBS_PATH + 32];
  snprintf(tmp, sizeof(tmp), "%s.tmp", path);
  int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return ts_error(err, TS_EIO, "cannot write %s: %s", path, strerror(errno));
  const uint8_t *p = data;
  size_t left = len;
  while (left > 0) {
    ssize_t k = write(fd, p, left);
    if (k < 0 && errno == EINTR) continue;
    if (k <= 0) {
      int e = k < 0 ? errno : ENOSPC; /* a regular file that takes no byte is full */
      close(fd);
      unlink(tmp);
      return ts_error(err, TS_EIO, "cannot write %s: %s", path, strerror(e));
    }
    p += k;
    left -= (size_t)k;
  }
  int ok = fsync(fd) == 0, e = errno;
  if (close(fd) != 0 && ok) {
    ok = 0;
    e = errno;
  }
  if (ok && rename(tmp, path) != 0) {
    ok = 0;
    e = errno;
  }
  if (!ok) {
    unlink(tmp);
    return ts_error(err, TS_EIO, "cannot write %s: %s", path, strerror(e));
  }
  if (ts_parent_sync(path) != 0)
    return ts_error(err, TS_EIO, "cannot write %s: syncing its directory: %s", path, strerror(errno));
  return 0;
}

/* Makes directory dir, durably: once this returns, its parent's entry for
 * it survives a power loss. */
static int make_dir(const char *dir, char *err) {
  if (mkdir(dir, 0755) != 0) return ts_error(err, TS_EIO, "cannot create %s: %s", dir, strerror(errno));
  if (ts_parent_sync(dir) != 0)
    return ts_error(err, TS_EIO, "cannot create %s: syncing its parent: %s", dir, strerror(errno));
  return 0;
}

/* Reads a small file of the spool for spool.h's judges: its bytes into
 * *buf (the caller frees it), or why it could not (f->why, pointing into
 * why, stays NULL when the file is missing). */
static void read_spool_file(const char *path, size_t cap, ts_spool_file *f, uint8_t **buf, char why[TS_ERR_LEN]) {
  size_t len;
  *f = (ts_spool_file){NULL, 0, NULL};
  if (ts_file_read(path, cap, buf, &len, why) == 0) {
    f->data = (const char *)*buf;
    f->len = len;
    return;
  }
  struct stat st;
  if (lstat(path, &st) == 0 || errno != ENOENT) f->why = why;
}

static void job_path(const job *jb, const char *name, char *out, size_t cap) {
  snprintf(out, cap, "%s/%s", jb->dir, name);
}

/* Bytes of the files in a job's directory (it holds no subdirectories). */
static uint64_t dir_bytes(const char *dir) {
  DIR *d = opendir(dir);
  if (d == NULL) return 0;
  uint64_t total = 0;
  struct dirent *e;
  struct stat st;
  while ((e = readdir(d)) != NULL)
    if (fstatat(dirfd(d), e->d_name, &st, AT_SYMLINK_NOFOLLOW) == 0 && S_ISREG(st.st_mode))
      total += (uint64_t)st.st_size;
  closedir(d);
  return total;
}

/* Whether a file name is a temporary one of write_atomic ("NAME.tmp") or
 * of the image library ("NAME.tmp-PID-N"). */
static int temporary_name(const char *name) {
  const char *t = strstr(name, ".tmp");
  return t != NULL && (t[4] == '\0' || t[4] == '-');
}

/* Removes the temporary files a coordinator killed while writing left in
 * a job's directory, before the job runs again. */
static void remove_temporaries(const char *dir) {
  DIR *d = opendir(dir);
  if (d == NULL) return;
  struct dirent *e;
  while ((e = readdir(d)) != NULL)
    if (temporary_name(e->d_name)) unlinkat(dirfd(d), e->d_name, 0);
  closedir(d);
}

/* Removes a job's directory and the files in it: 0, or -1 with errno
 * telling the first failure (the other files are removed all the same). */
static int remove_dir(const char *dir) {
  DIR *d = opendir(dir);
  if (d == NULL) return errno == ENOENT ? 0 : -1;
  int first = 0;
  struct dirent *e;
  while ((e = readdir(d)) != NULL)
    if (strcmp(e->d_name, ".") != 0 && strcmp(e->d_name, "..") != 0 && unlinkat(dirfd(d), e->d_name, 0) != 0 &&
        first == 0)
      first = errno;
  closedir(d);
  if (rmdir(dir) != 0 && first == 0) first = errno;
  errno = first;
  return first != 0 ? -1 : 0;
}

/* The state after a job's last checkpoint (see on_checkpoint). */
#define JOBS_CHECKPOINT "checkpoint"

/* A checkpoint left behind only takes room: the job is final. */
static void drop_job_checkpoint(ts_jobs *j, job *jb) {
  char path[JOBS_PATH + 32];
  job_path(jb, JOBS_CHECKPOINT, path, sizeof(path));
  if (unlink(path) != 0 && errno != ENOENT)
    jobs_log(j, "job %" PRIu64 ": cannot remove its checkpoint %s: %s; it stays until the job is deleted", jb->id,
             path, strerror(errno));
}

/* ---- status ------------------------------------------------------------ */

static void job_changed(ts_jobs *j, job *jb) {
  jb->version++;
  pthread_cond_broadcast(&j->changed);
}

static job *job_find(ts_jobs *j, uint64_t id) {
  for (job *jb = j->head; jb != NULL; jb = jb->next)
    if (jb->id == id) return jb;
  return NULL;
}

static void job_append(ts_jobs *j, job *jb) {
  if (j->tail) j->tail->next = jb;
  else j->head = jb;
  j->tail = jb;
}

/* A client's record (lock held); NULL only when out of memory. */
static client_share *share_of(ts_jobs *j, const char *client) {
  for (client_share *s = j->shares; s != NULL; s = s->next)
    if (strcmp(s->client, client) == 0) return s;
  client_share *s = calloc(1, sizeof(*s));
  if (s == NULL) return NULL;
  snprintf(s->client, sizeof(s->client), "%s", client);
  s->next = j->shares;
  j->shares = s;
  return s;
}

static int job_final(const job *jb) { return jb->st.state >= TS_JOB_DONE; }

/* Records a final state on disk, then in memory. A "done" that cannot be
 * recorded is not told to clients: the job fails with the reason, and a
 * restart, finding no state, runs it again (the same bytes). */
static void job_finish(ts_jobs *j, job *jb, int state, const char *text) {
  char path[JOBS_PATH + 16], buf[TS_ERR_LEN + 32], err[TS_ERR_LEN], why[TS_ERR_LEN];
  job_path(jb, "state", path, sizeof(path));
  int n = state == TS_JOB_DONE ? snprintf(buf, sizeof(buf), "done\n")
          : state == TS_JOB_CANCELED ? snprintf(buf, sizeof(buf), "canceled\n")
                                     : snprintf(buf, sizeof(buf), "failed: %s\n", text);
  if (write_atomic(path, buf, (size_t)n, err) != 0) {
    jobs_log(j, "job %" PRIu64 ": %s", jb->id, err);
    if (state == TS_JOB_DONE) {
      snprintf(why, sizeof(why), "%.400s; its results are written: a restart of the coordinator brings it back", err);
      state = TS_JOB_FAILED;
      text = why;
    }
  }
  if (state == TS_JOB_DONE) jobs_log(j, "job %" PRIu64 " done in %.2fs", jb->id, ts_now() - jb->started);
  else jobs_log(j, "job %" PRIu64 " %s%s%s", jb->id, ts_job_state_name((uint8_t)state), text[0] ? ": " : "", text);
  drop_job_checkpoint(j, jb);
  uint64_t bytes = dir_bytes(jb->dir); /* the reserve becomes what was written */
  pthread_mutex_lock(&j->lock);
  j->spool_bytes = j->spool_bytes - jb->bytes + bytes;
  jb->bytes = bytes;
  client_share *cs = share_of(j, jb->client);
  if (cs && cs->unfinished > 0) cs->unfinished--;
  jb->st.state = (uint8_t)state;
  j->last_ended = jb->id;
  if (state == TS_JOB_DONE) jb->st.permille = 1000;
  jb->st.eta_ms = 0;
  snprintf(jb->st.text, sizeof(jb->st.text), "%s", text);
  job_changed(j, jb);
  pthread_mutex_unlock(&j->lock);
}

/* ---- running ----------------------------------------------------------- */

typedef struct {
  ts_jobs *j;
  job *jb;
  double last;
} progress_ctx;

static void on_progress(void *arg, const ts_progress *p) {
  progress_ctx *pc = arg;
  double now = ts_now();
  if (now - pc->last < 0.1 && p->done != p->total) return;
  pc->last = now;
  double frac = p->work_total > 0 ? p->work_done / p->work_total : 0;
  pthread_mutex_lock(&pc->j->lock);
  ts_job_status *st = &pc->jb->st;
  st->level = (uint8_t)p->level;
  st->levels = (uint8_t)p->levels;
  st->permille = (uint16_t)(frac >= 1.0 ? 999 : frac * 1000); /* 1000 = written */
  double elapsed = now - pc->jb->started;
  st->eta_ms = frac > 0.001 ? (uint32_t)(elapsed * (1 - frac) / frac * 1000) : UINT32_MAX;
  st->workers = (uint16_t)ts_cluster_ready(pc->j->o.cluster);
  snprintf(st->text, sizeof(st->text), "%s", p->stage);
  job_changed(pc->j, pc->jb);
  pthread_mutex_unlock(&pc->j->lock);
}

/* Every output the job asked for, into its directory. */
static int write_results(job *jb, const ts_engine_run *run, char *err) {
  const ts_jobspec *s = &jb->spec;
  int rc = 0;
  for (int k = 0; rc == 0 && k < s->engine->noutputs; k++) {
    if (s->wants.want[k][0] == '\0') continue;
    char name[64], path[JOBS_PATH + 64];
    ts_engine_output_file(s->engine, k, &s->wants, name, sizeof(name));
    job_path(jb, name, path, sizeof(path));
    rc = s->engine->write_output(run, k, path, 0, err);
  }
  /* Their names durable before job_finish records "done" (which a restart
   * trusts without looking at the results): the image library fsyncs an
   * image before its rename but leaves the directory to its caller. */
  if (rc == 0 && ts_dir_sync(jb->dir) != 0)
    rc = ts_error(err, TS_EIO, "cannot write the results in %s: syncing the directory: %s", jb->dir, strerror(errno));
  return rc;
}

/* ---- checkpoints ------------------------------------------------------- */

typedef struct {
  ts_jobs *j;
  job *jb;
  uint64_t tag;
} checkpoint_ctx;

/* The tag that ties a checkpoint to this job's parameters. */
static uint64_t job_tag(const job *jb) {
  char text[TS_SPEC_MAX];
  int n = ts_jobspec_format(&jb->spec, text, sizeof(text));
  return ts_checkpoint_tag(text, n > 0 ? (size_t)n : 0);
}

/* Writes a checkpoint atomically: a kill at any moment leaves either the
 * previous checkpoint or this one. One that cannot be written (a full
 * disk) does not fail the job: it goes on, and a restart would redo more. */
static int on_checkpoint(void *arg, const uint8_t *buf, size_t len, const char *what, char *err) {
  checkpoint_ctx *cc = arg;
  char path[JOBS_PATH + 32], why[TS_ERR_LEN];
  (void)err;
  job_path(cc->jb, JOBS_CHECKPOINT, path, sizeof(path));
  if (write_atomic(path, buf, len, why) == 0)
    jobs_log(cc->j, "job %" PRIu64 ": checkpoint %s (%zu bytes)", cc->jb->id, what, len);
  else
    jobs_log(cc->j, "job %" PRIu64 ": no checkpoint %s: %s; the job goes on without it", cc->jb->id, what, why);
  return 0;
}

/* A damaged or foreign checkpoint: the job starts over, which gives the
 * same bytes, only later. */
static void on_checkpoint_refused(void *arg, const char *why) {
  checkpoint_ctx *cc = arg;
  char path[JOBS_PATH + 32];
  job_path(cc->jb, JOBS_CHECKPOINT, path, sizeof(path));
  jobs_log(cc->j, "job %" PRIu64 ": ignoring its checkpoint (%s); starting over", cc->jb->id, why);
  unlink(path);
}

/* The work redone is a bound, not a measurement (the process that did it
 * is gone): the checkpoint's age, or the interval after which the crashed
 * run would have written its next one. */
static void on_resumed(void *arg, const char *where, double redone) {
  checkpoint_ctx *cc = arg;
  jobs_log(cc->j, "job %" PRIu64 ": resuming %s from its checkpoint; work since the checkpoint (at most %.1f s) "
           "is redone", cc->jb->id, where, redone);
}

/* Runs the job's engine, from its last checkpoint if it has one. */
static int run_engine(ts_jobs *j, job *jb, const ts_image *const *in, ts_search *search, ts_engine_run **run,
                      char *err) {
  progress_ctx pc = {j, jb, 0};
  checkpoint_ctx cc = {j, jb, job_tag(jb)};
  char path[JOBS_PATH + 32];
  job_path(jb, JOBS_CHECKPOINT, path, sizeof(path));
  uint8_t *resume = NULL;
  size_t resume_len = 0;
  if (ts_file_read(path, SIZE_MAX, &resume, &resume_len, NULL) != 0) resume = NULL;
  ts_engine_hooks hooks = {.progress = on_progress,
                           .progress_ctx = &pc,
                           .save = on_checkpoint,
                           .save_ctx = &cc,
                           .checkpoint_interval = j->o.checkpoint_interval,
                           .resume = resume,
                           .resume_len = resume_len,
                           .tag = cc.tag,
                           .resume_refused = on_checkpoint_refused,
                           .resumed = on_resumed,
                           .stop = &j->stopping};
  int rc = jb->spec.engine->run(&jb->spec.params, in, search, &hooks, run, err);
  free(resume);
  return rc;
}

/* Where input k of a job lives: ref.EXT for the first, NAME.EXT after. */
static void input_path(const job *jb, const ts_engine_inputs *names, int k, char *out, size_t cap) {
  if (k == 0) snprintf(out, cap, "%s/ref.%s", jb->dir, jb->ref_ext);
  else snprintf(out, cap, "%s/%s.%s", jb->dir, names->name[k], jb->more_ext[k - 1]);
}

/* Reads every input of a job; on failure the ones read are freed. */
static int read_inputs(ts_jobs *j, const job *jb, ts_image *in, int *n, char *err) {
  ts_engine_inputs names;
  jb->spec.engine->inputs(&jb->spec.params, &names);
  ts_image_limits limits = {j->o.max_pixels, JOBS_MAX_PIXELS_OPTION};
  char path[JOBS_PATH + 64];
  for (int k = 0; k < names.n; k++) {
    input_path(jb, &names, k, path, sizeof(path));
    int rc = ts_image_read(path, &in[k], &limits, err);
    if (rc != 0) {
      while (k-- > 0) ts_image_free(&in[k]);
      return rc;
    }
  }
  *n = names.n;
  return 0;
}

static int run_job(ts_jobs *j, job *jb, char *err) {
  remove_temporaries(jb->dir);
  ts_image in[TS_ENGINE_MAX_INPUTS] = {0};
  const ts_image *inp[TS_ENGINE_MAX_INPUTS];
  int n;
  int rc = read_inputs(j, jb, in, &n, err);
  if (rc != 0) return rc;
  for (int k = 0; k < n; k++) inp[k] = &in[k];
  const ts_engine *e = jb->spec.engine;
  char msg[2048];
  e->set_max_pixels(&jb->spec.params, j->o.max_pixels);
  if (e->check(&jb->spec.params, inp, msg, sizeof(msg)) != 0)
    rc = ts_error(err, TS_EINVAL, "invalid parameters for the %dx%d %s: %s", in[0].width, in[0].height,
                  n == 1 ? "reference" : "inputs", msg);
  ts_search *search = NULL;
  ts_engine_run *run = NULL;
  if (rc == 0) rc = ts_search_cluster_create(&search, j->o.cluster, &jb->cancel, err);
  if (rc == 0) rc = run_engine(j, jb, inp, search, &run, err);
  if (rc == 0) rc = write_results(jb, run, err);
  e->run_free(run);
  ts_search_destroy(search);
  for (int k = 0; k < n; k++) ts_image_free(&in[k]);
  return rc;
}

/* The next job to start (lock held): fewest started jobs per client, then
 * the oldest. */
static job *pick_job(ts_jobs *j) {
  job *best = NULL;
  uint64_t best_started = UINT64_MAX;
  for (job *jb = j->head; jb != NULL; jb = jb->next) {
    if (jb->st.state != TS_JOB_QUEUED || jb->cancel) continue;
    client_share *cs = share_of(j, jb->client);
    uint64_t n = cs ? cs->started : 0;
    if (n < best_started) {
      best = jb;
      best_started = n;
    }
  }
  return best;
}

static void *runner(void *arg) {
  ts_jobs *j = arg;
  pthread_mutex_lock(&j->lock);
  for (;;) {
    job *jb = NULL;
    while (!j->stop && (j->paused || (jb = pick_job(j)) == NULL)) pthread_cond_wait(&j->changed, &j->lock);
    if (j->stop) break;
    client_share *cs = share_of(j, jb->client);
    if (cs) cs->started++;
    jb->st.state = TS_JOB_RUNNING;
    jb->st.workers = (uint16_t)ts_cluster_ready(j->o.cluster); /* for jobs that report no progress (energy) */
    jb->st.level = jb->st.levels > 0 ? jb->st.levels - 1 : 0;    /* the coarsest, until progress says more */
    jb->started = ts_now();
    j->running++;
    job_changed(j, jb);
    pthread_mutex_unlock(&j->lock);
    char err[TS_ERR_LEN] = "";
    int rc = run_job(j, jb, err);
    if (rc == TS_ESTOPPED)
      jobs_log(j, "job %" PRIu64 ": %s, checkpoint saved; a restart resumes it there", jb->id, err);
    else if (rc != 0 && atomic_load(&j->stopping)) /* j->stop needs the lock; stopping is set with it */
      jobs_log(j, "job %" PRIu64 ": stopped before its step ended (%s); a restart resumes it from its last "
               "checkpoint", jb->id, err);
    else if (rc == TS_ECANCELED) job_finish(j, jb, TS_JOB_CANCELED, "canceled by a client");
    else job_finish(j, jb, rc == 0 ? TS_JOB_DONE : TS_JOB_FAILED, rc == 0 ? "" : err);
    pthread_mutex_lock(&j->lock);
    j->running--;
    pthread_cond_broadcast(&j->changed);
  }
  pthread_mutex_unlock(&j->lock);
  return NULL;
}

/* ---- spool ------------------------------------------------------------- */

/* Makes path and the directories above it that are missing, each one
 * made durably (make_dir). */
static int mkdir_p(const char *path, char *err) {
  char buf[JOBS_PATH + 16];
  snprintf(buf, sizeof(buf), "%s", path);
  size_t n = strlen(buf);
  for (size_t i = 1; i <= n; i++) {
    if (buf[i] != '/' && buf[i] != '\0') continue;
    char c = buf[i];
    buf[i] = '\0';
    struct stat st;
    if (stat(buf, &st) != 0 && make_dir(buf, err) != 0) return TS_EIO;
    buf[i] = c;
  }
  return 0;
}

/* Judges job directory dir by its files (spool.h). */
static int judge_job_dir(const char *dir, ts_spool_job *rec, char *err) {
  enum { NFILES = 5 };
  static const struct {
    const char *name;
    size_t cap; /* more than the file's writer ever puts there */
  } files[NFILES] = {{"job.spec", TS_SPEC_MAX}, {"client", TS_SPOOL_CLIENT_LEN}, {"ref.ext", TS_EXT_LEN},
                     {"inputs", TS_ENGINE_MAX_INPUTS * (TS_ENGINE_KEY_LEN + TS_EXT_LEN + 2)},
                     {"state", TS_ERR_LEN + 32}};
  ts_spool_files f = {0};
  ts_spool_file *slot[NFILES] = {&f.spec, &f.client, &f.ref_ext, &f.inputs, &f.state};
  uint8_t *buf[NFILES] = {NULL};
  char why[NFILES][TS_ERR_LEN], path[JOBS_PATH + 32];
  for (int i = 0; i < NFILES; i++) {
    snprintf(path, sizeof(path), "%s/%s", dir, files[i].name);
    read_spool_file(path, files[i].cap, slot[i], &buf[i], why[i]);
  }
  struct stat st;
  snprintf(path, sizeof(path), "%s/%s", dir, JOBS_CHECKPOINT);
  f.checkpoint = lstat(path, &st) == 0;
  int rc = ts_spool_read_job(dir, &f, rec, err);
  for (int i = 0; i < NFILES; i++) free(buf[i]);
  return rc;
}

/* Reloads one job directory; unfinished jobs queue again, damaged ones
 * are kept as spool.h says, with a log line. */
static void load_job(ts_jobs *j, uint64_t id) {
  /* Ids are never reused, not even an unacknowledged submission's: its
   * directory is still there and a new job could not be created in it. */
  if (id >= j->next_id) j->next_id = id + 1;
  job *jb = calloc(1, sizeof(*jb));
  ts_spool_job *rec = malloc(sizeof(*rec));
  char err[TS_ERR_LEN];
  if (jb == NULL || rec == NULL) {
    jobs_log(j, "out of memory loading job %" PRIu64 " from the spool: it is left out until a restart", id);
    free(jb);
    free(rec);
    return;
  }
  jb->id = id;
  snprintf(jb->dir, sizeof(jb->dir), "%s/jobs/%" PRIu64, j->spool, id);
  if (judge_job_dir(jb->dir, rec, err) != 0) {
    /* Never acknowledged: its files go, its id stays taken (last-id). */
    jobs_log(j, "%s; removing it", err);
    remove_dir(jb->dir);
    free(jb);
    free(rec);
    return;
  }
  if (rec->note[0] != '\0') jobs_log(j, "job %" PRIu64 ": %s", id, rec->note);
  if (rec->has_spec) jb->spec = rec->spec;
  snprintf(jb->client, sizeof(jb->client), "%s", rec->client);
  snprintf(jb->ref_ext, sizeof(jb->ref_ext), "%s", rec->ref_ext);
  memcpy(jb->more_ext, rec->more_ext, sizeof(jb->more_ext));
  jb->st.id = id;
  jb->st.state = (uint8_t)rec->state;
  jb->st.levels = rec->has_spec ? (uint8_t)jb->spec.engine->levels(&jb->spec.params) : 0;
  jb->st.permille = rec->state == TS_JOB_DONE ? 1000 : 0;
  jb->st.eta_ms = UINT32_MAX;
  snprintf(jb->st.text, sizeof(jb->st.text), "%s", rec->text);
  free(rec);
  jb->bytes = dir_bytes(jb->dir);
  j->spool_bytes += jb->bytes;
  client_share *cs = share_of(j, jb->client);
  if (cs && !job_final(jb)) cs->unfinished++;
  job_append(j, jb);
}

/* The highest id ever given out, kept apart from the job directories so a
 * deleted job's id is not given out again after a restart. */
#define JOBS_LAST_ID "last-id"

/* Records id as given out, before the job that has it is acknowledged. */
static int note_last_id(ts_jobs *j, uint64_t id, char *err) {
  char path[JOBS_PATH + 16], text[32];
  snprintf(path, sizeof(path), "%s/%s", j->spool, JOBS_LAST_ID);
  int n = snprintf(text, sizeof(text), "%" PRIu64 "\n", id);
  return write_atomic(path, text, (size_t)n, err);
}

/* Numbers new jobs after last-id (next_id is already past every job
 * directory). Without a usable last-id the job directories are all there
 * is: the ids of deleted jobs above them could come again, which the log
 * line says, with what to do about it. */
static void read_last_id(ts_jobs *j, size_t njobs) {
  char path[JOBS_PATH + 16], why[TS_ERR_LEN], err[TS_ERR_LEN];
  snprintf(path, sizeof(path), "%s/%s", j->spool, JOBS_LAST_ID);
  ts_spool_file f;
  uint8_t *buf = NULL;
  read_spool_file(path, 32, &f, &buf, why);
  uint64_t last;
  int rc = ts_spool_read_last_id(path, &f, &last, err);
  free(buf);
  if (rc == 0 && j->next_id <= last) j->next_id = last + 1;
  if (j->next_id == 0) j->next_id = 1;
  if (rc == 0 || (rc == TS_ENOENT && njobs == 0)) return; /* a new spool has none */
  jobs_log(j,
           "%s: new jobs are numbered from %" PRIu64 ", after the jobs in the spool; ids of jobs deleted "
           "above %" PRIu64 " would be given out again: if there were any, write the highest id ever given to %s",
           err, j->next_id, j->next_id - 1, path);
}

static int cmp_u64(const void *a, const void *b) {
  uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
  return x < y ? -1 : x > y;
}

/* Removes what is left of a deleted job (TS_SPOOL_DELETED). */
static void finish_deletion(ts_jobs *j, const char *jobs, const char *name) {
  char path[JOBS_PATH + 16 + 256];
  snprintf(path, sizeof(path), "%s/%s", jobs, name);
  if (remove_dir(path) == 0) jobs_log(j, "removed %s, what a deletion cut short by a crash left", path);
  else jobs_log(j, "cannot remove %s, a deleted job's files: %s; remove it by hand", path, strerror(errno));
}

static int load_spool(ts_jobs *j, char *err) {
  char path[JOBS_PATH + 16];
  snprintf(path, sizeof(path), "%s/jobs", j->spool);
  DIR *d = opendir(path);
  if (d == NULL) return ts_error(err, TS_EIO, "cannot read the spool %s: %s", path, strerror(errno));
  uint64_t *ids = NULL;
  size_t n = 0, cap = 0;
  struct dirent *e;
  while ((e = readdir(d)) != NULL) {
    uint64_t id;
    ts_spool_entry kind = ts_spool_entry_of(e->d_name, &id);
    if (kind == TS_SPOOL_DELETED) {
      if (id >= j->next_id) j->next_id = id + 1;
      finish_deletion(j, path, e->d_name);
    }
    if (kind != TS_SPOOL_JOB) continue;
    if (n == cap) {
      cap = cap ? 2 * cap : 64;
      uint64_t *p = realloc(ids, cap * sizeof(*ids));
      if (p == NULL) break;
      ids = p;
    }
    ids[n++] = id;
  }
  closedir(d);
  if (n > 0) qsort(ids, n, sizeof(*ids), cmp_u64);
  for (size_t i = 0; i < n; i++) load_job(j, ids[i]);
  free(ids);
  read_last_id(j, n);
  return 0;
}

/* ---- the lock ---------------------------------------------------------- */

/* One coordinator per spool: two would both run its queued jobs, write
 * the same files and give out the same ids. The lock is flock's, on
 * SPOOL/lock: the kernel drops it when its holder dies, however it dies,
 * so the file a killed coordinator leaves never blocks the next one. The
 * holder writes its pid there, for the message that refuses a second. */
#define JOBS_LOCK "lock"

/* The pid in the lock file open as fd; 0 while there is none (its holder
 * is between its flock and its write). */
static long lock_holder(int fd) {
  char text[32], *end;
  ssize_t n = pread(fd, text, sizeof(text) - 1, 0);
  if (n <= 0) return 0;
  text[n] = '\0';
  long pid = strtol(text, &end, 10);
  return pid > 0 && *end == '\n' ? pid : 0;
}

/* Why the lock at path, open as fd, of spool is not ours: its holder,
 * named. */
static int lock_refused(int fd, const char *spool, const char *path, char *err) {
  long pid = 0;
  const struct timespec tick = {0, 10 * 1000 * 1000};
  for (int i = 0; i < 100 && (pid = lock_holder(fd)) == 0; i++) nanosleep(&tick, NULL);
  char holder[64] = "its pid not written yet";
  if (pid > 0) snprintf(holder, sizeof(holder), "pid %ld", pid);
  return ts_error(err, TS_EINVAL,
                  "the spool %s is in use by another texsyn-server (%s, holding %s): stop that one first, or "
                  "give this one another --spool", spool, holder, path);
}

static int lock_spool(ts_jobs *j, char *err) {
  char path[JOBS_PATH + 16], text[32];
  snprintf(path, sizeof(path), "%s/%s", j->spool, JOBS_LOCK);
  j->lock_fd = open(path, O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (j->lock_fd < 0) return ts_error(err, TS_EIO, "cannot lock the spool: cannot open %s: %s", path, strerror(errno));
  if (flock(j->lock_fd, LOCK_EX | LOCK_NB) != 0)
    return errno == EWOULDBLOCK ? lock_refused(j->lock_fd, j->spool, path, err)
                                : ts_error(err, TS_EIO, "cannot lock the spool: %s: %s", path, strerror(errno));
  int n = snprintf(text, sizeof(text), "%ld\n", (long)getpid());
  if (ftruncate(j->lock_fd, 0) != 0 || write(j->lock_fd, text, (size_t)n) != n)
    return ts_error(err, TS_EIO, "cannot lock the spool: cannot write %s: %s", path, strerror(errno));
  return 0;
}

/* The spool's directories, made if missing, and its lock. */
static int open_spool(ts_jobs *j, char *err) {
  char path[JOBS_PATH + 16];
  snprintf(path, sizeof(path), "%s/jobs", j->spool);
  char why[TS_ERR_LEN];
  if (mkdir_p(path, why) != 0) return ts_error(err, TS_EIO, "cannot create the spool %s: %s", path, why);
  return lock_spool(j, err);
}

int ts_jobs_create(ts_jobs **out, const ts_jobs_opts *o, char *err) {
  *out = NULL;
  if (o->runners < 1 || o->runners > 64) return ts_error(err, TS_EINVAL, "--jobs %d: need 1..64", o->runners);
  ts_jobs *j = calloc(1, sizeof(*j));
  if (j == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  j->o = *o;
  if (strlen(o->spool) >= sizeof(j->spool)) {
    free(j);
    return ts_error(err, TS_EINVAL, "--spool: path longer than %d bytes", JOBS_SPOOL_LEN - 1);
  }
  snprintf(j->spool, sizeof(j->spool), "%s", o->spool);
  j->lock_fd = -1;
  pthread_mutex_init(&j->lock, NULL);
  pthread_cond_init(&j->changed, NULL);
  int rc = open_spool(j, err);
  if (rc == 0) rc = load_spool(j, err);
  for (int i = 0; rc == 0 && i < o->runners; i++) {
    if (pthread_create(&j->runners[i], NULL, runner, j) != 0) rc = ts_error(err, TS_ENOMEM, "cannot start job runners");
    else j->nrunners++;
  }
  if (rc != 0) {
    ts_jobs_destroy(j);
    return rc;
  }
  *out = j;
  return 0;
}

/* Asks the running jobs to stop at a checkpoint and waits up to
 * o.stop_grace seconds for them (lock held); then cancels what still runs,
 * which ends its search at once. */
static void stop_running_jobs(ts_jobs *j) {
  j->stop = 1;
  atomic_store(&j->stopping, 1);
  pthread_cond_broadcast(&j->changed);
  if (j->running > 0)
    jobs_log(j, "stopping: %d running job%s to checkpoint (--stop-grace %g s)", j->running,
             j->running == 1 ? "" : "s", j->o.stop_grace);
  struct timespec until = ts_wait_until(j->o.stop_grace);
  while (j->running > 0 && pthread_cond_timedwait(&j->changed, &j->lock, &until) == 0) {
  }
  if (j->running > 0)
    jobs_log(j, "%d job%s did not reach a checkpoint within %g s (--stop-grace): stopping them now", j->running,
             j->running == 1 ? "" : "s", j->o.stop_grace);
  for (job *jb = j->head; jb != NULL; jb = jb->next) jb->cancel = 1;
}

void ts_jobs_destroy(ts_jobs *j) {
  if (j == NULL) return;
  pthread_mutex_lock(&j->lock);
  stop_running_jobs(j);
  pthread_mutex_unlock(&j->lock);
  for (int i = 0; i < j->nrunners; i++) pthread_join(j->runners[i], NULL);
  while (j->head != NULL) {
    job *n = j->head->next;
    free(j->head);
    j->head = n;
  }
  while (j->shares != NULL) {
    client_share *n = j->shares->next;
    free(j->shares);
    j->shares = n;
  }
  pthread_mutex_destroy(&j->lock);
  pthread_cond_destroy(&j->changed);
  if (j->lock_fd >= 0) close(j->lock_fd); /* the spool is free for the next coordinator */
  free(j);
}

/* Disk a job will use: its reference, and a reserve for its results and
 * checkpoints (the engine's estimate, ts_engine.result_bytes) until they
 * are written and counted. */
static uint64_t job_reserve(const ts_jobspec *s, size_t inputs_len, const ts_image_info *in) {
  return inputs_len + s->engine->result_bytes(&s->params, &s->wants, in) + 65536;
}

static double mib(uint64_t bytes) { return (double)bytes / (1024.0 * 1024.0); }

/* Checks the limits and takes an id and the disk reserve (lock taken). */
static int admit(ts_jobs *j, job *jb, size_t inputs_len, const ts_image_info *in, char *err) {
  uint64_t need = job_reserve(&jb->spec, inputs_len, in);
  int rc = 0;
  pthread_mutex_lock(&j->lock);
  client_share *cs = share_of(j, jb->client);
  if (cs == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory");
  else if (j->o.max_client_jobs > 0 && cs->unfinished >= j->o.max_client_jobs)
    rc = ts_error(err, TS_ELIMIT,
                  "client %s already has %u unfinished jobs, the limit (--max-client-jobs); wait for some to "
                  "finish or cancel some",
                  jb->client, cs->unfinished);
  else if (j->o.max_spool_bytes > 0 && j->spool_bytes + need > j->o.max_spool_bytes)
    rc = ts_error(err, TS_ELIMIT,
                  "the spool is full: %.1f MiB of %.1f MiB (--max-spool) in use and this job needs about "
                  "%.1f MiB; fetch and delete finished jobs (texsyn delete ID) or raise the limit",
                  mib(j->spool_bytes), mib(j->o.max_spool_bytes), mib(need));
  if (rc == 0) {
    rc = note_last_id(j, j->next_id, err);
    jb->id = j->next_id++; /* taken even when its record failed: it may be on disk */
  }
  if (rc == 0) {
    cs->unfinished++;
    jb->bytes = need;
    j->spool_bytes += need;
  }
  pthread_mutex_unlock(&j->lock);
  return rc;
}

/* Gives back what admit took, for a submission that failed. */
static void unadmit(ts_jobs *j, job *jb) {
  pthread_mutex_lock(&j->lock);
  client_share *cs = share_of(j, jb->client);
  if (cs && cs->unfinished > 0) cs->unfinished--;
  j->spool_bytes -= jb->bytes;
  pthread_mutex_unlock(&j->lock);
}

/* The inputs a submission carries must be the ones its engine declares
 * for its spec, in that order: the message lists both when they are not. */
static int check_input_names(const ts_jobspec *spec, const ts_msg_submit *m, const ts_engine_inputs *names,
                             char *err) {
  int same = (int)m->nmore + 1 == names->n;
  for (int k = 1; same && k < names->n; k++) same = strcmp(m->more[k - 1].key, names->name[k]) == 0;
  if (same) return 0;
  char want[1024] = "", got[1024] = "";
  size_t nw = 0, ng = 0;
  for (int k = 0; k < names->n && nw < sizeof(want); k++)
    nw += (size_t)snprintf(want + nw, sizeof(want) - nw, "%s%s", k ? ", " : "", names->name[k]);
  ng += (size_t)snprintf(got, sizeof(got), "%s", names->name[0]);
  for (uint32_t k = 0; k < m->nmore && ng < sizeof(got); k++)
    ng += (size_t)snprintf(got + ng, sizeof(got) - ng, ", %s", m->more[k].key);
  return ts_error(err, TS_EINVAL, "this %s job takes the inputs %s, in that order; the submission has %s",
                  spec->engine->name, want, got);
}

/* Checks a file name's extension and the image header it names, so a
 * file that is no image or is over the limit is refused to its sender at
 * once, not queued to fail later. The extension into ext. */
static int check_input(ts_jobs *j, const char *name, const uint8_t *data, size_t len, char ext[TS_EXT_LEN],
                       ts_image_info *info, char *err) {
  const char *e = ts_path_ext(name);
  /* The spec's extension rule: letters and digits only. */
  if (!ts_ext_valid(e)) return ts_error(err, TS_EINVAL, "input name '%s' needs a plain extension (.png, .tif, ...)", name);
  snprintf(ext, TS_EXT_LEN, "%s", e);
  ts_image_limits limits = {j->o.max_pixels, JOBS_MAX_PIXELS_OPTION};
  return ts_image_probe_mem(name, data, len, &limits, info, err);
}

/* The files of an admitted job: its inputs, client, ref.ext, inputs (with
 * more than one) and, last, job.spec - a job directory without it was
 * never accepted. */
static int write_job_files(job *jb, const char *client, const ts_msg_submit *m, const ts_engine_inputs *names,
                           char *err) {
  char path[JOBS_PATH + 64], list[TS_ENGINE_MAX_INPUTS * (TS_ENGINE_KEY_LEN + TS_EXT_LEN + 2)];
  int rc = 0;
  size_t nl = 0;
  rc = make_dir(jb->dir, err);
  input_path(jb, names, 0, path, sizeof(path));
  if (rc == 0) rc = write_atomic(path, m->ref, m->ref_len, err);
  for (int k = 1; rc == 0 && k < names->n; k++) {
    input_path(jb, names, k, path, sizeof(path));
    rc = write_atomic(path, m->more[k - 1].data, m->more[k - 1].len, err);
    nl += (size_t)snprintf(list + nl, sizeof(list) - nl, "%s=%s\n", names->name[k], jb->more_ext[k - 1]);
  }
  job_path(jb, "client", path, sizeof(path));
  if (rc == 0) rc = write_atomic(path, client, strlen(client), err);
  job_path(jb, "ref.ext", path, sizeof(path));
  if (rc == 0) rc = write_atomic(path, jb->ref_ext, strlen(jb->ref_ext), err);
  job_path(jb, "inputs", path, sizeof(path));
  if (rc == 0 && names->n > 1) rc = write_atomic(path, list, nl, err);
  char text[TS_SPEC_MAX];
  int n = ts_jobspec_format(&jb->spec, text, sizeof(text));
  job_path(jb, "job.spec", path, sizeof(path));
  if (rc == 0) rc = n < 0 ? ts_error(err, TS_ETOOBIG, "job spec too long") : write_atomic(path, text, (size_t)n, err);
  return rc;
}

int ts_jobs_submit(ts_jobs *j, const char *client, const ts_msg_submit *m, uint64_t *id, char *err) {
  job *jb = calloc(1, sizeof(*jb));
  if (jb == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  int rc = ts_jobspec_parse(m->spec, m->spec_len, &jb->spec, err);
  ts_engine_inputs names;
  if (rc == 0) {
    jb->spec.engine->inputs(&jb->spec.params, &names);
    rc = check_input_names(&jb->spec, m, &names, err);
  }
  size_t bytes = m->ref_len;
  ts_image_info info[TS_ENGINE_MAX_INPUTS];
  if (rc == 0) rc = check_input(j, m->ref_name, m->ref, m->ref_len, jb->ref_ext, &info[0], err);
  for (uint32_t k = 0; rc == 0 && k < m->nmore; k++) {
    rc = check_input(j, m->more[k].name, m->more[k].data, m->more[k].len, jb->more_ext[k], &info[k + 1], err);
    bytes += m->more[k].len;
  }
  snprintf(jb->client, sizeof(jb->client), "%s", client);
  if (rc == 0) rc = admit(j, jb, bytes, info, err);
  if (rc != 0) {
    free(jb);
    return rc;
  }
  snprintf(jb->dir, sizeof(jb->dir), "%s/jobs/%" PRIu64, j->spool, jb->id);
  rc = write_job_files(jb, client, m, &names, err);
  if (rc != 0) {
    if (remove_dir(jb->dir) != 0)
      jobs_log(j, "cannot remove %s, a submission refused: %s; remove it by hand before a restart, which would "
               "run the job if its job.spec is there", jb->dir, strerror(errno));
    unadmit(j, jb);
    free(jb);
    return rc;
  }
  jb->st.id = jb->id;
  jb->st.state = TS_JOB_QUEUED;
  jb->st.levels = (uint8_t)jb->spec.engine->levels(&jb->spec.params);
  jb->st.eta_ms = UINT32_MAX;
  pthread_mutex_lock(&j->lock);
  job_append(j, jb);
  job_changed(j, jb);
  pthread_mutex_unlock(&j->lock);
  *id = jb->id;
  return 0;
}

int ts_jobs_status(ts_jobs *j, uint64_t id, ts_job_status *out, uint64_t *version) {
  pthread_mutex_lock(&j->lock);
  job *jb = job_find(j, id);
  if (jb != NULL) {
    *out = jb->st;
    if (version) *version = jb->version;
  }
  pthread_mutex_unlock(&j->lock);
  return jb ? 0 : TS_ENOENT;
}

int ts_jobs_wait(ts_jobs *j, uint64_t id, uint64_t *version, int timeout_ms, ts_job_status *out) {
  struct timespec ts = ts_wait_until(timeout_ms * 1e-3);
  pthread_mutex_lock(&j->lock);
  job *jb = job_find(j, id);
  /* Found again after every wait: the job may have been deleted meanwhile. */
  while (jb != NULL && jb->version == *version && !j->stop) {
    int rc = pthread_cond_timedwait(&j->changed, &j->lock, &ts);
    jb = job_find(j, id);
    if (rc == ETIMEDOUT) break;
  }
  if (jb != NULL) {
    *out = jb->st;
    *version = jb->version;
  }
  pthread_mutex_unlock(&j->lock);
  return jb ? 0 : TS_ENOENT;
}

uint32_t ts_jobs_list(ts_jobs *j, ts_job_status *out, uint32_t cap) {
  pthread_mutex_lock(&j->lock);
  uint32_t n = 0;
  for (job *jb = j->head; jb != NULL && n < cap; jb = jb->next) out[n++] = jb->st;
  pthread_mutex_unlock(&j->lock);
  return n;
}

uint32_t ts_jobs_list_recent(ts_jobs *j, ts_job_status *out, const char **engines, uint32_t cap) {
  pthread_mutex_lock(&j->lock);
  uint64_t total = 0;
  for (const job *jb = j->head; jb != NULL; jb = jb->next) total++;
  uint64_t skip = total > cap ? total - cap : 0;
  uint32_t n = 0;
  uint64_t i = 0;
  for (const job *jb = j->head; jb != NULL; jb = jb->next, i++)
    if (i >= skip) {
      out[n] = jb->st;
      /* A job reloaded without its spec (a damaged spool) has no engine. */
      engines[n++] = jb->spec.engine != NULL ? jb->spec.engine->name : "unknown";
    }
  pthread_mutex_unlock(&j->lock);
  return n;
}

int ts_jobs_cancel(ts_jobs *j, uint64_t id, char *err) {
  pthread_mutex_lock(&j->lock);
  job *jb = job_find(j, id);
  int rc = 0, queued = 0;
  if (jb == NULL) rc = ts_error(err, TS_ENOENT, "no job %" PRIu64, id);
  else if (job_final(jb)) rc = ts_error(err, TS_EINVAL, "job %" PRIu64 " is already %s", id, ts_job_state_name(jb->st.state));
  else {
    /* A queued job stays queued, untaken, until job_finish (once). */
    queued = jb->st.state == TS_JOB_QUEUED && !jb->cancel;
    jb->cancel = 1;
  }
  pthread_mutex_unlock(&j->lock);
  if (queued) job_finish(j, jb, TS_JOB_CANCELED, "canceled by a client");
  return rc;
}

/* Deletes a job's directory (lock held): renamed to ID.deleted first, the
 * one step that takes the job out of the spool (a restart finishes a
 * removal a crash cut short, spool.h), and that rename made durable before
 * the deletion is acknowledged; then its files go. */
static int discard_dir(ts_jobs *j, const job *jb, char *err) {
  char gone[sizeof(jb->dir) + sizeof(TS_SPOOL_DELETED_SUFFIX)];
  snprintf(gone, sizeof(gone), "%s%s", jb->dir, TS_SPOOL_DELETED_SUFFIX);
  if (rename(jb->dir, gone) != 0) return ts_error(err, TS_EIO, "cannot remove %s: %s", jb->dir, strerror(errno));
  if (ts_parent_sync(gone) != 0) {
    int e = errno;
    /* Put back: the job stays, rather than come back after a power loss. */
    if (rename(gone, jb->dir) == 0)
      return ts_error(err, TS_EIO, "cannot remove %s: syncing its parent: %s", jb->dir, strerror(e));
    jobs_log(j, "job %" PRIu64 " deleted, but its deletion may not survive a power loss: syncing the parent of %s: "
             "%s", jb->id, gone, strerror(e));
  }
  if (remove_dir(gone) != 0)
    jobs_log(j, "job %" PRIu64 " deleted, but %s cannot be removed: %s; a restart tries again", jb->id, gone,
             strerror(errno));
  return 0;
}

int ts_jobs_delete(ts_jobs *j, uint64_t id, char *err) {
  pthread_mutex_lock(&j->lock);
  job *jb = job_find(j, id), *prev = NULL;
  int rc = 0;
  if (jb == NULL) rc = ts_error(err, TS_ENOENT, "no job %" PRIu64, id);
  else if (!job_final(jb) && jb->cancel)
    rc = ts_error(err, TS_EINVAL, "job %" PRIu64 " is still stopping after its cancel: delete it once it has "
                  "(texsyn watch %" PRIu64 " waits for that)", id, id);
  else if (!job_final(jb))
    rc = ts_error(err, TS_EINVAL, "job %" PRIu64 " is %s: cancel it first, or wait for it to end", id,
                  ts_job_state_name(jb->st.state));
  else rc = discard_dir(j, jb, err);
  if (rc == 0) {
    for (job *p = j->head; p != jb; p = p->next) prev = p;
    if (prev) prev->next = jb->next;
    else j->head = jb->next;
    if (j->tail == jb) j->tail = prev;
    j->spool_bytes -= jb->bytes;
    free(jb);
    pthread_cond_broadcast(&j->changed); /* watchers find it gone */
  }
  pthread_mutex_unlock(&j->lock);
  return rc;
}

uint64_t ts_jobs_spool_bytes(ts_jobs *j) {
  pthread_mutex_lock(&j->lock);
  uint64_t n = j->spool_bytes;
  pthread_mutex_unlock(&j->lock);
  return n;
}

int ts_jobs_files(ts_jobs *j, uint64_t id, char names[][TS_MSG_NAME_MAX], char paths[][4096], uint32_t *n,
                  char *err) {
  pthread_mutex_lock(&j->lock);
  job *jb = job_find(j, id);
  int rc = 0;
  *n = 0;
  if (jb == NULL) rc = ts_error(err, TS_ENOENT, "no job %" PRIu64, id);
  else if (jb->st.state != TS_JOB_DONE)
    rc = ts_error(err, TS_EINVAL, "job %" PRIu64 " is %s%s%s", id, ts_job_state_name(jb->st.state),
                  jb->st.text[0] ? ": " : "", jb->st.text);
  else {
    const ts_jobspec *s = &jb->spec;
    uint32_t k = 0;
    for (int i = 0; i < s->engine->noutputs && k < TS_FETCH_MAX_FILES; i++) {
      if (s->wants.want[i][0] == '\0') continue;
      char name[64];
      ts_engine_output_file(s->engine, i, &s->wants, name, sizeof(name));
      snprintf(names[k], TS_MSG_NAME_MAX, "%s", name);
      snprintf(paths[k], 4096, "%s/%s", jb->dir, name);
      k++;
    }
    *n = k;
  }
  pthread_mutex_unlock(&j->lock);
  return rc;
}

void ts_jobs_counts(ts_jobs *j, uint32_t counts[TS_JOB_STATE_COUNT]) {
  memset(counts, 0, sizeof(uint32_t) * TS_JOB_STATE_COUNT);
  pthread_mutex_lock(&j->lock);
  for (job *jb = j->head; jb != NULL; jb = jb->next) counts[jb->st.state]++;
  pthread_mutex_unlock(&j->lock);
}

int ts_jobs_current(ts_jobs *j, ts_job_status *out) {
  pthread_mutex_lock(&j->lock);
  const job *first = NULL;
  for (const job *jb = j->head; jb != NULL; jb = jb->next)
    if (jb->st.state == TS_JOB_RUNNING && (first == NULL || jb->started < first->started)) first = jb;
  if (first == NULL) first = job_find(j, j->last_ended);
  if (first != NULL) *out = first->st;
  pthread_mutex_unlock(&j->lock);
  return first != NULL ? 0 : TS_ENOENT;
}

void ts_jobs_pause(ts_jobs *j, int paused) {
  pthread_mutex_lock(&j->lock);
  j->paused = paused != 0;
  pthread_cond_broadcast(&j->changed);
  pthread_mutex_unlock(&j->lock);
  jobs_log(j, "queue %s", paused ? "paused: queued jobs wait" : "resumed");
}

int ts_jobs_paused(ts_jobs *j) {
  pthread_mutex_lock(&j->lock);
  int p = j->paused;
  pthread_mutex_unlock(&j->lock);
  return p;
}
