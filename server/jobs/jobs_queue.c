/* jobs_queue.c - the jobs in memory (jobs_queue.h). */
#include "jobs_queue.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void jobs_changed(ts_jobs *j, job *jb) {
  jb->version++;
  pthread_cond_broadcast(&j->changed);
}

job *jobs_find(ts_jobs *j, uint64_t id) {
  for (job *jb = j->head; jb != NULL; jb = jb->next)
    if (jb->id == id) return jb;
  return NULL;
}

void jobs_append(ts_jobs *j, job *jb) {
  if (j->tail) j->tail->next = jb;
  else j->head = jb;
  j->tail = jb;
}

void jobs_describe(job *jb) {
  ts_job_status *st = &jb->st;
  const ts_jobspec *s = &jb->spec;
  /* A job reloaded without its spec (a damaged spool) has no engine. */
  snprintf(st->engine, sizeof(st->engine), "%s", s->engine != NULL ? s->engine->name : "unknown");
  snprintf(st->owner, sizeof(st->owner), "%s", jb->client);
  if (s->name[0] != '\0') snprintf(st->output, sizeof(st->output), "%s", s->name);
  else if (s->engine != NULL) ts_engine_output_file(s->engine, 0, &s->wants, st->output, sizeof(st->output));
  else st->output[0] = '\0';
}

void jobs_record(const ts_jobs *j, const job *jb, ts_job_status *out) {
  *out = jb->st;
  out->flags = j->paused && jb->st.state == TS_JOB_QUEUED ? TS_JOB_HELD : 0;
}

/* A client's record (lock held); NULL only when out of memory. */
client_share *jobs_share_of(ts_jobs *j, const char *client) {
  for (client_share *s = j->shares; s != NULL; s = s->next)
    if (strcmp(s->client, client) == 0) return s;
  client_share *s = calloc(1, sizeof(*s));
  if (s == NULL) return NULL;
  snprintf(s->client, sizeof(s->client), "%s", client);
  s->next = j->shares;
  j->shares = s;
  return s;
}

/* The next job to start (lock held): fewest started jobs per client, then
 * the oldest. */
job *jobs_pick(ts_jobs *j) {
  job *best = NULL;
  uint64_t best_started = UINT64_MAX;
  for (job *jb = j->head; jb != NULL; jb = jb->next) {
    if (jb->st.state != TS_JOB_QUEUED || jb->cancel) continue;
    client_share *cs = jobs_share_of(j, jb->client);
    uint64_t n = cs ? cs->started : 0;
    if (n < best_started) {
      best = jb;
      best_started = n;
    }
  }
  return best;
}
