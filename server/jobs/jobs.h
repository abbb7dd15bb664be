/* jobs.h - the coordinator's job queue and spool.
 *
 * A submitted job gets the next id and a directory SPOOL/jobs/ID holding
 * its spec (job.spec), its input images (ref.EXT, then NAME.EXT for an
 * engine's further inputs: spool.h), its results and, last, a
 * `state` file ("done", or "failed: reason"). Everything is written
 * atomically (temporary name, then rename), so a coordinator killed at any
 * moment restarts from a consistent spool: finished jobs are served again,
 * unfinished ones queue again (synthesis is deterministic: same bytes).
 *
 * Runner threads (several jobs in flight) take queued jobs fairly between
 * clients: the next job comes from the client that has had the fewest jobs
 * started, ties to the oldest job.
 *
 * Limits keep one client from crowding out the others: unfinished jobs per
 * client, and the spool's disk use (inputs, a reserve for the results,
 * checkpoints) - a submission past either is refused with the reason, and
 * deleting finished jobs gives the space back.
 *
 * Retention: with keep_ended, an expirer thread removes each finished job
 * that long after it ended. A job's end is its `state` file's modification
 * time (its directory's for a job kept as failed without one), so a
 * restart keeps counting from the same moment. */
#ifndef TS_JOBS_H
#define TS_JOBS_H

#include <stddef.h>
#include <stdint.h>

#include "cluster.h"
#include "jobspec.h"
#include "msg.h"

typedef struct {
  const char *spool; /* directory, created if missing */
  int runners;       /* jobs run at once (2) */
  uint64_t max_pixels; /* reference and output pixel limit */
  uint32_t max_client_jobs; /* unfinished jobs per client (0 = no limit) */
  uint64_t max_spool_bytes; /* disk use of all jobs (0 = no limit) */
  ts_cluster *cluster;
  double checkpoint_interval; /* seconds of work between checkpoints inside a
                                 level (0: after whole levels only) */
  double stop_grace; /* ts_jobs_destroy waits this long for running jobs to
                        stop at a checkpoint of their own */
  double keep_ended; /* seconds a finished job stays after it ended, then it
                        is removed as ts_jobs_delete removes one (0: forever) */
  uint64_t max_input_bytes; /* one job's input images decoded, checked from
                               their headers before decoding (0 = no limit) */
} ts_jobs_opts;

typedef struct ts_jobs ts_jobs;

/* Opens the spool (reloading earlier jobs) and starts the runners. */
int ts_jobs_create(ts_jobs **out, const ts_jobs_opts *o, char *err);
/* Stops the runners and frees everything. Running jobs are not failed:
 * each finishes the step under way and saves a checkpoint there, so a
 * restart resumes it with nothing redone; one still busy after
 * o->stop_grace seconds (a step waiting for workers) is abandoned, and
 * resumes from its last checkpoint. */
void ts_jobs_destroy(ts_jobs *j);

/* Accepts a job from `client` (a fairness key): checks the spec and that
 * the inputs are the ones its engine takes, stores spec and inputs,
 * queues it. */
int ts_jobs_submit(ts_jobs *j, const char *client, const ts_msg_submit *m, uint64_t *id, char *err);
/* Status of one job: 0, or TS_ENOENT. *version changes whenever the
 * status does. */
int ts_jobs_status(ts_jobs *j, uint64_t id, ts_job_status *out, uint64_t *version);
/* Waits up to timeout_ms for job id's version to differ from *version. */
int ts_jobs_wait(ts_jobs *j, uint64_t id, uint64_t *version, int timeout_ms, ts_job_status *out);
/* Every job, oldest first; returns how many were written (<= cap). */
uint32_t ts_jobs_list(ts_jobs *j, ts_job_status *out, uint32_t cap);
/* The newest cap jobs, oldest first; returns how many were written. For
 * the operations page. */
uint32_t ts_jobs_list_recent(ts_jobs *j, ts_job_status *out, uint32_t cap);
/* A job that is one frame of a `texsyn video` sequence (its spec's
 * sequence keys, jobspec.h), for the operations page. */
typedef struct {
  uint64_t id;
  uint8_t state;     /* ts_job_state */
  uint16_t permille; /* its progress */
  ts_jobspec_seq seq;
} ts_job_frame;
/* The newest cap jobs that are frames of a sequence, oldest first;
 * returns how many were written. */
uint32_t ts_jobs_list_frames(ts_jobs *j, ts_job_frame *out, uint32_t cap);
int ts_jobs_cancel(ts_jobs *j, uint64_t id, char *err);
/* Removes a finished (done, failed or canceled) job and its files from the
 * spool; its id is never given out again. The expirer removes jobs the
 * same way. */
int ts_jobs_delete(ts_jobs *j, uint64_t id, char *err);
/* Bytes the spool's jobs use (or have reserved for their results). */
uint64_t ts_jobs_spool_bytes(ts_jobs *j);
/* A finished job's result files: names (out.EXT, copymap.EXT, ...) and
 * their paths in the spool. */
int ts_jobs_files(ts_jobs *j, uint64_t id, char names[][TS_MSG_NAME_MAX], char paths[][4096],
                  uint32_t *n, char *err);
/* The path of a job's growing preview (preview.h), in any state, and
 * whether the job is running (the picture may still change): 0, or
 * TS_ENOENT when there is no such job or it has no preview. */
int ts_jobs_preview(ts_jobs *j, uint64_t id, char *path, size_t cap, int *running, char *err);
/* Jobs queued / running / done / failed (for monitoring). */
void ts_jobs_counts(ts_jobs *j, uint32_t counts[TS_JOB_STATE_COUNT]);
/* The status of the running job that started first, else of the job that
 * ended last: 0, or TS_ENOENT. */
int ts_jobs_current(ts_jobs *j, ts_job_status *out);
/* Paused, no queued job starts (running ones go on) and their records say
 * held (TS_JOB_HELD); resumed, they do. */
void ts_jobs_pause(ts_jobs *j, int paused);
int ts_jobs_paused(ts_jobs *j);

#endif
