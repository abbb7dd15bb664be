/* jobs.c - see jobs.h; jobs_state.h lists the queue's files. */
#include "jobs.h"

#include <errno.h>
#include <inttypes.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "error.h"
#include "image.h"
#include "jobs_queue.h"
#include "jobs_runner.h"
#include "jobs_spool.h"
#include "preview.h"
#include "util.h"

_Static_assert(TS_ENGINE_MAX_INPUTS <= TS_MSG_MAX_INPUTS && TS_ENGINE_KEY_LEN == TS_MSG_KEY_MAX,
               "an engine's inputs must fit a submission");

static void *expirer(void *arg);

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
  int rc = jobs_open_spool(j, err);
  if (rc == 0) rc = jobs_load_spool(j, err);
  for (int i = 0; rc == 0 && i < o->runners; i++) {
    if (pthread_create(&j->runners[i], NULL, jobs_runner, j) != 0) rc = ts_error(err, TS_ENOMEM, "cannot start job runners");
    else j->nrunners++;
  }
  if (rc == 0 && o->keep_ended > 0) {
    if (pthread_create(&j->expirer, NULL, expirer, j) != 0) rc = ts_error(err, TS_ENOMEM, "cannot start the expirer");
    else j->expiring = 1;
  }
  if (rc != 0) {
    ts_jobs_destroy(j);
    return rc;
  }
  *out = j;
  return 0;
}

void ts_jobs_destroy(ts_jobs *j) {
  if (j == NULL) return;
  pthread_mutex_lock(&j->lock);
  jobs_stop_running(j);
  pthread_mutex_unlock(&j->lock);
  for (int i = 0; i < j->nrunners; i++) pthread_join(j->runners[i], NULL);
  if (j->expiring) pthread_join(j->expirer, NULL);
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

/* One job may reserve at most this share of --max-spool: a maximum-size
 * job would otherwise hold most of the spool, and nobody else's fit. */
#define JOBS_SPOOL_SHARE 2

/* Checks the limits and takes an id and the disk reserve (lock taken). */
static int admit(ts_jobs *j, job *jb, size_t inputs_len, const ts_image_info *in, char *err) {
  uint64_t need = job_reserve(&jb->spec, inputs_len, in);
  int rc = 0;
  pthread_mutex_lock(&j->lock);
  client_share *cs = jobs_share_of(j, jb->client);
  if (cs == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory");
  else if (j->o.max_client_jobs > 0 && cs->unfinished >= j->o.max_client_jobs)
    rc = ts_error(err, TS_ELIMIT,
                  "client %s already has %u unfinished jobs, the limit (--max-client-jobs); wait for some to "
                  "finish or cancel some",
                  jb->client, cs->unfinished);
  else if (j->o.max_spool_bytes > 0 && need > j->o.max_spool_bytes / JOBS_SPOOL_SHARE)
    rc = ts_error(err, TS_ELIMIT,
                  "this job alone needs about %.1f MiB of spool, more than half of --max-spool (%.1f MiB): one "
                  "job may not take the room every other job needs; raise --max-spool to at least %.1f MiB",
                  mib(need), mib(j->o.max_spool_bytes), mib(need * JOBS_SPOOL_SHARE));
  else if (j->o.max_spool_bytes > 0 && j->spool_bytes + need > j->o.max_spool_bytes)
    rc = ts_error(err, TS_ELIMIT,
                  "the spool is full: %.1f MiB of %.1f MiB (--max-spool) in use and this job needs about "
                  "%.1f MiB; fetch and delete finished jobs (texsyn delete ID) or raise the limit",
                  mib(j->spool_bytes), mib(j->o.max_spool_bytes), mib(need));
  if (rc == 0) {
    rc = jobs_note_last_id(j, j->next_id, err);
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
  client_share *cs = jobs_share_of(j, jb->client);
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
 * once, not queued to fail later. The extension into ext. An input the
 * engine reads by regions (a tiled scene's class map) has no pixel limit:
 * the engine's own limit is on a tile. */
static int check_input(ts_jobs *j, const char *name, const uint8_t *data, size_t len, int by_regions, int is_file,
                       char ext[TS_EXT_LEN], ts_image_info *info, char *err) {
  const char *e = ts_path_ext(name);
  /* The spec's extension rule: letters and digits only. */
  if (!ts_ext_valid(e)) return ts_error(err, TS_EINVAL, "input name '%s' needs a plain extension (.png, .tif, ...)", name);
  snprintf(ext, TS_EXT_LEN, "%s", e);
  memset(info, 0, sizeof(*info));
  if (is_file) return 0; /* no image: the engine's check reads it */
  ts_image_limits limits = {by_regions ? UINT64_MAX : j->o.max_pixels, JOBS_MAX_PIXELS_OPTION};
  return ts_image_probe_mem(name, data, len, &limits, info, err);
}

/* The bytes the inputs decode to, from their headers (in; by_region
 * inputs and files have none), against --max-input-memory: a 256-Mpixel
 * float RGBA image is within --max-pixels and decodes to 16 GiB. */
static int check_decoded(const ts_jobs *j, const ts_msg_submit *m, const ts_image_info *in, char *err) {
  uint64_t total = 0, largest = 0;
  uint32_t at = 0;
  for (uint32_t k = 0; k <= m->nmore; k++) {
    uint64_t b = (uint64_t)in[k].width * (uint64_t)in[k].height * (uint64_t)in[k].channels *
                 (in[k].width > 0 ? ts_pixtype_size(in[k].type) : 0);
    total += b;
    if (b > largest) largest = b, at = k;
  }
  if (j->o.max_input_bytes == 0 || total <= j->o.max_input_bytes) return 0;
  const ts_image_info *w = &in[at];
  return ts_error(err, TS_ELIMIT,
                  "the job's input images decode to %.1f MiB, over texsyn-server --max-input-memory (%.1f MiB); the "
                  "largest, %s, is %dx%d with %d channels of %s (%.1f MiB): convert it to 8 bits or fewer "
                  "channels, or raise the limit",
                  mib(total), mib(j->o.max_input_bytes), at == 0 ? m->ref_name : m->more[at - 1].name, w->width,
                  w->height, w->channels, ts_pixtype_name(w->type), mib(largest));
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
  const ts_engine *e = jb->spec.engine;
  const void *params = &jb->spec.params;
  if (rc == 0)
    rc = check_input(j, m->ref_name, m->ref, m->ref_len, ts_engine_input_by_regions(e, params, 0),
                     ts_engine_input_is_file(e, params, 0), jb->ref_ext, &info[0], err);
  for (uint32_t k = 0; rc == 0 && k < m->nmore; k++) {
    rc = check_input(j, m->more[k].name, m->more[k].data, m->more[k].len,
                     ts_engine_input_by_regions(e, params, (int)k + 1), ts_engine_input_is_file(e, params, (int)k + 1),
                     jb->more_ext[k], &info[k + 1], err);
    bytes += m->more[k].len;
  }
  snprintf(jb->client, sizeof(jb->client), "%s", client);
  if (rc == 0) rc = check_decoded(j, m, info, err);
  if (rc == 0) rc = admit(j, jb, bytes, info, err);
  if (rc != 0) {
    free(jb);
    return rc;
  }
  snprintf(jb->dir, sizeof(jb->dir), "%s/jobs/%" PRIu64, j->spool, jb->id);
  rc = jobs_write_files(jb, client, m, &names, err);
  if (rc != 0) {
    if (jobs_remove_dir(jb->dir) != 0)
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
  jb->st.submitted_ms = ts_clock_ms();
  jobs_describe(jb);
  pthread_mutex_lock(&j->lock);
  jobs_append(j, jb);
  jobs_changed(j, jb);
  pthread_mutex_unlock(&j->lock);
  *id = jb->id;
  return 0;
}

int ts_jobs_status(ts_jobs *j, uint64_t id, ts_job_status *out, uint64_t *version) {
  pthread_mutex_lock(&j->lock);
  job *jb = jobs_find(j, id);
  if (jb != NULL) {
    jobs_record(j, jb, out);
    if (version) *version = jb->version;
  }
  pthread_mutex_unlock(&j->lock);
  return jb ? 0 : TS_ENOENT;
}

int ts_jobs_wait(ts_jobs *j, uint64_t id, uint64_t *version, int timeout_ms, ts_job_status *out) {
  struct timespec ts = ts_wait_until(timeout_ms * 1e-3);
  pthread_mutex_lock(&j->lock);
  job *jb = jobs_find(j, id);
  /* Found again after every wait: the job may have been deleted meanwhile. */
  while (jb != NULL && jb->version == *version && !j->stop) {
    int rc = pthread_cond_timedwait(&j->changed, &j->lock, &ts);
    jb = jobs_find(j, id);
    if (rc == ETIMEDOUT) break;
  }
  if (jb != NULL) {
    jobs_record(j, jb, out);
    *version = jb->version;
  }
  pthread_mutex_unlock(&j->lock);
  return jb ? 0 : TS_ENOENT;
}

uint32_t ts_jobs_list(ts_jobs *j, ts_job_status *out, uint32_t cap) {
  pthread_mutex_lock(&j->lock);
  uint32_t n = 0;
  for (job *jb = j->head; jb != NULL && n < cap; jb = jb->next) jobs_record(j, jb, &out[n++]);
  pthread_mutex_unlock(&j->lock);
  return n;
}

uint32_t ts_jobs_list_recent(ts_jobs *j, ts_job_status *out, uint32_t cap) {
  pthread_mutex_lock(&j->lock);
  uint64_t total = 0;
  for (const job *jb = j->head; jb != NULL; jb = jb->next) total++;
  uint64_t skip = total > cap ? total - cap : 0;
  uint32_t n = 0;
  uint64_t i = 0;
  for (const job *jb = j->head; jb != NULL; jb = jb->next, i++)
    if (i >= skip) jobs_record(j, jb, &out[n++]);
  pthread_mutex_unlock(&j->lock);
  return n;
}

uint32_t ts_jobs_list_frames(ts_jobs *j, ts_job_frame *out, uint32_t cap) {
  pthread_mutex_lock(&j->lock);
  uint64_t total = 0;
  for (const job *jb = j->head; jb != NULL; jb = jb->next) total += jb->spec.seq.id[0] != '\0';
  uint64_t skip = total > cap ? total - cap : 0;
  uint32_t n = 0;
  for (const job *jb = j->head; jb != NULL; jb = jb->next) {
    if (jb->spec.seq.id[0] == '\0') continue;
    if (skip > 0) {
      skip--;
      continue;
    }
    out[n++] = (ts_job_frame){jb->id, jb->st.state, jb->st.permille, jb->spec.seq};
  }
  pthread_mutex_unlock(&j->lock);
  return n;
}

int ts_jobs_cancel(ts_jobs *j, uint64_t id, char *err) {
  pthread_mutex_lock(&j->lock);
  job *jb = jobs_find(j, id);
  int rc = 0, queued = 0;
  if (jb == NULL) rc = ts_error(err, TS_ENOENT, "no job %" PRIu64, id);
  else if (job_final(jb)) rc = ts_error(err, TS_EINVAL, "job %" PRIu64 " is already %s", id, ts_job_state_name(jb->st.state));
  else {
    /* A queued job stays queued, untaken, until jobs_finish (once). */
    queued = jb->st.state == TS_JOB_QUEUED && !jb->cancel;
    jb->cancel = 1;
  }
  pthread_mutex_unlock(&j->lock);
  if (queued) jobs_finish(j, jb, TS_JOB_CANCELED, "canceled by a client");
  return rc;
}

/* Removes a finished job (lock held): its directory out of the spool,
 * then its record. What a delete and an expiry both do. */
static int remove_job(ts_jobs *j, job *jb, char *err) {
  int rc = jobs_discard_dir(j, jb, err);
  if (rc != 0) return rc;
  job *prev = NULL;
  for (job *p = j->head; p != jb; p = p->next) prev = p;
  if (prev) prev->next = jb->next;
  else j->head = jb->next;
  if (j->tail == jb) j->tail = prev;
  j->spool_bytes -= jb->bytes;
  free(jb);
  pthread_cond_broadcast(&j->changed); /* watchers find it gone */
  return 0;
}

int ts_jobs_delete(ts_jobs *j, uint64_t id, char *err) {
  pthread_mutex_lock(&j->lock);
  job *jb = jobs_find(j, id);
  int rc = 0;
  if (jb == NULL) rc = ts_error(err, TS_ENOENT, "no job %" PRIu64, id);
  else if (!job_final(jb) && jb->cancel)
    rc = ts_error(err, TS_EINVAL, "job %" PRIu64 " is still stopping after its cancel: delete it once it has "
                  "(texsyn watch %" PRIu64 " waits for that)", id, id);
  else if (!job_final(jb))
    rc = ts_error(err, TS_EINVAL, "job %" PRIu64 " is %s: cancel it first, or wait for it to end", id,
                  ts_job_state_name(jb->st.state));
  else rc = remove_job(j, jb, err);
  pthread_mutex_unlock(&j->lock);
  return rc;
}

/* ---- retention ---------------------------------------------------------- */

/* Removes the finished jobs that ended o.keep_ended seconds ago or more
 * (lock held); returns when the next one is due (UINT64_MAX: none). */
static uint64_t expire_due(ts_jobs *j, uint64_t now) {
  uint64_t keep = (uint64_t)(j->o.keep_ended * 1000.0), next = UINT64_MAX;
  for (job *jb = j->head, *after; jb != NULL; jb = after) {
    after = jb->next;
    if (!job_final(jb) || jb->kept) continue;
    uint64_t due = jb->st.ended_ms + keep;
    if (due > now) {
      if (due < next) next = due;
      continue;
    }
    char err[TS_ERR_LEN];
    uint64_t id = jb->id;
    if (remove_job(j, jb, err) == 0) {
      jobs_log(j, "job %" PRIu64 " removed: it ended more than %g s ago (--keep-ended)", id, j->o.keep_ended);
    } else {
      jb->kept = 1;
      jobs_log(j, "job %" PRIu64 " not removed after --keep-ended: %s; it stays until texsyn delete %" PRIu64
               " or a restart", id, err, id);
    }
  }
  return next;
}

/* The expirer: wakes when a job is due, on any change (a job that ends
 * has a new due time), and at least every keep/10 seconds (1..60 s), so a
 * step of the clock is caught up with. */
static void *expirer(void *arg) {
  ts_jobs *j = arg;
  double period = j->o.keep_ended / 10 < 1 ? 1 : j->o.keep_ended / 10 > 60 ? 60 : j->o.keep_ended / 10;
  pthread_mutex_lock(&j->lock);
  while (!j->stop) {
    uint64_t now = ts_clock_ms(), next = expire_due(j, now);
    double wait = next == UINT64_MAX ? period : (double)(next - now) / 1000.0;
    struct timespec until = ts_wait_until(wait < period ? wait : period);
    pthread_cond_timedwait(&j->changed, &j->lock, &until);
  }
  pthread_mutex_unlock(&j->lock);
  return NULL;
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
  job *jb = jobs_find(j, id);
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

int ts_jobs_preview(ts_jobs *j, uint64_t id, char *path, size_t cap, int *running, char *err) {
  pthread_mutex_lock(&j->lock);
  job *jb = jobs_find(j, id);
  if (jb != NULL) {
    snprintf(path, cap, "%s/%s", jb->dir, TS_PREVIEW_FILE);
    *running = jb->st.state == TS_JOB_RUNNING;
  }
  pthread_mutex_unlock(&j->lock);
  if (jb == NULL) return ts_error(err, TS_ENOENT, "no job %" PRIu64, id);
  return access(path, R_OK) == 0 ? 0 : ts_error(err, TS_ENOENT, "job %" PRIu64 " has no preview", id);
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
  if (first == NULL) first = jobs_find(j, j->last_ended);
  if (first != NULL) jobs_record(j, first, out);
  pthread_mutex_unlock(&j->lock);
  return first != NULL ? 0 : TS_ENOENT;
}

void ts_jobs_pause(ts_jobs *j, int paused) {
  pthread_mutex_lock(&j->lock);
  j->paused = paused != 0;
  for (job *jb = j->head; jb != NULL; jb = jb->next) /* their records say held, or no longer */
    if (jb->st.state == TS_JOB_QUEUED) jobs_changed(j, jb);
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
