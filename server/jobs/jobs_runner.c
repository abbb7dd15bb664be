/* jobs_runner.c - the job queue's runner threads (jobs_runner.h): each takes
 * the next queued job, reads its inputs, runs its engine with progress and
 * checkpoint hooks, writes its results and records its end. */
#include "jobs_runner.h"

#include <errno.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "checkpoint.h"
#include "error.h"
#include "image.h"
#include "preview.h"
#include "jobs_queue.h"
#include "jobs_spool.h"
#include "util.h"

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
  jobs_changed(pc->j, pc->jb);
  pthread_mutex_unlock(&pc->j->lock);
}

/* Every output the job asked for, into its directory. */
static int write_results(job *jb, const ts_engine_run *run, char *err) {
  const ts_jobspec *s = &jb->spec;
  int rc = 0;
  for (int k = 0; rc == 0 && k < s->engine->noutputs; k++) {
    if (s->wants.want[k][0] == '\0' || s->engine->outputs[k].streamed) continue;
    char name[64], path[JOBS_PATH + 64];
    ts_engine_output_file(s->engine, k, &s->wants, name, sizeof(name));
    jobs_file_path(jb, name, path, sizeof(path));
    rc = s->engine->write_output(run, k, path, 0, err);
  }
  /* Their names durable before jobs_finish records "done" (which a restart
   * trusts without looking at the results): the image library fsyncs an
   * image before its rename but leaves the directory to its caller. */
  if (rc == 0 && ts_dir_sync(jb->dir) != 0)
    rc = ts_error(err, TS_EIO, "cannot write the results in %s: syncing the directory: %s", jb->dir, strerror(errno));
  return rc;
}

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
  jobs_file_path(cc->jb, JOBS_CHECKPOINT, path, sizeof(path));
  if (ts_file_write(path, buf, len, why) == 0)
    jobs_log(cc->j, "job %" PRIu64 ": checkpoint %s (%zu bytes)", cc->jb->id, what, len);
  else
    jobs_log(cc->j, "job %" PRIu64 ": no checkpoint %s: %s; the job goes on without it", cc->jb->id, what, why);
  return 0;
}

/* A checkpoint piece, "piece-NAME" in the job's directory, written
 * atomically; like a checkpoint, one that cannot be written does not fail
 * the job. */
static int piece_path(const checkpoint_ctx *cc, const char *name, char *path, size_t cap, char *err) {
  char file[64];
  size_t n = strlen(name);
  if (n < 1 || n > 31 || strspn(name, "abcdefghijklmnopqrstuvwxyz0123456789-") != n)
    return ts_error(err, TS_EINVAL, "checkpoint piece name '%.40s': need 1..31 of a-z, 0-9, '-'", name);
  snprintf(file, sizeof(file), JOBS_PIECE_PREFIX "%s", name);
  jobs_file_path(cc->jb, file, path, cap);
  return 0;
}

static int on_save_piece(void *arg, const char *name, const uint8_t *buf, size_t len, char *err) {
  checkpoint_ctx *cc = arg;
  char path[JOBS_PATH + 64], why[TS_ERR_LEN];
  int rc = piece_path(cc, name, path, sizeof(path), err);
  if (rc != 0) return rc;
  if (ts_file_write(path, buf, len, why) != 0)
    jobs_log(cc->j, "job %" PRIu64 ": no checkpoint piece %s: %s; the job goes on without it", cc->jb->id, name, why);
  return 0;
}

static int on_load_piece(void *arg, const char *name, uint8_t **buf, size_t *len, char *err) {
  checkpoint_ctx *cc = arg;
  char path[JOBS_PATH + 64];
  int rc = piece_path(cc, name, path, sizeof(path), err);
  if (rc != 0) return rc;
  if (access(path, F_OK) != 0) return TS_ENOENT;
  return ts_file_read(path, SIZE_MAX, buf, len, err);
}

/* A damaged or foreign checkpoint: the job starts over, which gives the
 * same bytes, only later. */
static void on_checkpoint_refused(void *arg, const char *why) {
  checkpoint_ctx *cc = arg;
  char path[JOBS_PATH + 32];
  jobs_file_path(cc->jb, JOBS_CHECKPOINT, path, sizeof(path));
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
  jobs_file_path(jb, JOBS_CHECKPOINT, path, sizeof(path));
  uint8_t *resume = NULL;
  size_t resume_len = 0;
  if (ts_file_read(path, SIZE_MAX, &resume, &resume_len, NULL) != 0) resume = NULL;
  /* Streamed outputs go straight to their files in the job's directory. */
  const ts_jobspec *s = &jb->spec;
  char out_path[TS_ENGINE_MAX_OUTPUTS][JOBS_PATH + 64];
  const char *out_paths[TS_ENGINE_MAX_OUTPUTS] = {0};
  for (int k = 0; k < s->engine->noutputs; k++) {
    if (s->wants.want[k][0] == '\0' || !s->engine->outputs[k].streamed) continue;
    char name[64];
    ts_engine_output_file(s->engine, k, &s->wants, name, sizeof(name));
    jobs_file_path(jb, name, out_path[k], sizeof(out_path[k]));
    out_paths[k] = out_path[k];
  }
  char preview[JOBS_PATH + 64];
  jobs_file_path(jb, TS_PREVIEW_FILE, preview, sizeof(preview));
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
                           .stop = &j->stopping,
                           .output_paths = out_paths,
                           .preview_path = preview,
                           .save_piece = on_save_piece,
                           .load_piece = on_load_piece};
  int rc = jb->spec.engine->run(&jb->spec.params, in, search, &hooks, run, err);
  free(resume);
  return rc;
}

/* Reads every input of a job (ts_engine_input_read: decoded, or the
 * header of one the engine reads by regions); on failure the ones read are
 * freed. */
static int read_inputs(ts_jobs *j, const job *jb, ts_engine_file *in, int *n, char *err) {
  ts_engine_inputs names;
  jb->spec.engine->inputs(&jb->spec.params, &names);
  ts_image_limits limits = {j->o.max_pixels, JOBS_MAX_PIXELS_OPTION};
  char path[JOBS_PATH + 64];
  for (int k = 0; k < names.n; k++) {
    jobs_input_path(jb, &names, k, path, sizeof(path));
    int rc = ts_engine_input_read(jb->spec.engine, &jb->spec.params, k, path, &limits, &in[k], err);
    if (rc != 0) {
      for (int i = 0; i <= k; i++) ts_image_free(&in[i].img);
      return rc;
    }
  }
  *n = names.n;
  return 0;
}

static int run_job(ts_jobs *j, job *jb, char *err) {
  jobs_remove_temporaries(jb->dir);
  ts_engine_file *in = calloc(TS_ENGINE_MAX_INPUTS, sizeof(*in)); /* 4 KB of path each */
  const ts_image *inp[TS_ENGINE_MAX_INPUTS];
  int n;
  if (in == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  int rc = read_inputs(j, jb, in, &n, err);
  if (rc != 0) {
    free(in);
    return rc;
  }
  for (int k = 0; k < n; k++) inp[k] = &in[k].img;
  const ts_engine *e = jb->spec.engine;
  char msg[2048];
  e->set_max_pixels(&jb->spec.params, j->o.max_pixels);
  if (e->check(&jb->spec.params, inp, msg, sizeof(msg)) != 0)
    rc = ts_error(err, TS_EINVAL, "invalid parameters for the %dx%d %s: %s", in[0].img.width, in[0].img.height,
                  n == 1 ? "reference" : "inputs", msg);
  ts_search *search = NULL;
  ts_engine_run *run = NULL;
  if (rc == 0) rc = ts_search_cluster_create(&search, j->o.cluster, &jb->cancel, err);
  if (rc == 0) rc = run_engine(j, jb, inp, search, &run, err);
  if (rc == 0) rc = write_results(jb, run, err);
  e->run_free(run);
  ts_search_destroy(search);
  for (int k = 0; k < n; k++) ts_image_free(&in[k].img);
  free(in);
  return rc;
}

void *jobs_runner(void *arg) {
  ts_jobs *j = arg;
  pthread_mutex_lock(&j->lock);
  for (;;) {
    job *jb = NULL;
    while (!j->stop && (j->paused || (jb = jobs_pick(j)) == NULL)) pthread_cond_wait(&j->changed, &j->lock);
    if (j->stop) break;
    client_share *cs = jobs_share_of(j, jb->client);
    if (cs) cs->started++;
    jb->st.state = TS_JOB_RUNNING;
    jb->st.workers = (uint16_t)ts_cluster_ready(j->o.cluster); /* for jobs that report no progress (energy) */
    jb->st.level = jb->st.levels > 0 ? jb->st.levels - 1 : 0;    /* the coarsest, until progress says more */
    jb->started = ts_now();
    jb->st.started_ms = ts_clock_ms();
    j->running++;
    jobs_changed(j, jb);
    pthread_mutex_unlock(&j->lock);
    char err[TS_ERR_LEN] = "";
    jobs_attempt_begin(j, jb);
    int rc = run_job(j, jb, err);
    jobs_attempt_end(j, jb);
    if (rc == TS_ESTOPPED)
      jobs_log(j, "job %" PRIu64 ": %s, checkpoint saved; a restart resumes it there", jb->id, err);
    else if (rc != 0 && atomic_load(&j->stopping)) /* j->stop needs the lock; stopping is set with it */
      jobs_log(j, "job %" PRIu64 ": stopped before its step ended (%s); a restart resumes it from its last "
               "checkpoint", jb->id, err);
    else if (rc == TS_ECANCELED) jobs_finish(j, jb, TS_JOB_CANCELED, "canceled by a client");
    else jobs_finish(j, jb, rc == 0 ? TS_JOB_DONE : TS_JOB_FAILED, rc == 0 ? "" : err);
    pthread_mutex_lock(&j->lock);
    j->running--;
    pthread_cond_broadcast(&j->changed);
  }
  pthread_mutex_unlock(&j->lock);
  return NULL;
}

/* Asks the running jobs to stop at a checkpoint and waits up to
 * o.stop_grace seconds for them (lock held); then cancels what still runs,
 * which ends its search at once. */
void jobs_stop_running(ts_jobs *j) {
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
