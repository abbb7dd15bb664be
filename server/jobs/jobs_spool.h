/* jobs_spool.h - the job queue's spool on disk (jobs_spool.c). */
#ifndef TS_JOBS_SPOOL_H
#define TS_JOBS_SPOOL_H

#include "jobs_state.h"

/* SPOOL/jobs made if missing, and SPOOL/lock taken: one coordinator per
 * spool. */
int jobs_open_spool(ts_jobs *j, char *err);
/* Reloads the spool's jobs; unfinished ones queue again. */
int jobs_load_spool(ts_jobs *j, char *err);
/* Records id as given out (SPOOL/last-id), before its job is acknowledged. */
int jobs_note_last_id(ts_jobs *j, uint64_t id, char *err);
/* A file of a job's directory; its input k (ref.EXT, then NAME.EXT). */
void jobs_file_path(const job *jb, const char *name, char *out, size_t cap);
void jobs_input_path(const job *jb, const ts_engine_inputs *names, int k, char *out, size_t cap);
/* The directory and files of an admitted job, job.spec last. */
int jobs_write_files(job *jb, const char *client, const ts_msg_submit *m, const ts_engine_inputs *names, char *err);
/* A final state recorded on disk, then in memory (lock not held). */
void jobs_finish(ts_jobs *j, job *jb, int state, const char *text);
/* Runs of a job that never ended ("attempts" in its directory): one
 * counted before each run starts, the count cleared when the run ends
 * whichever way (done, failed, stopped at a checkpoint). What is left at a
 * restart are runs the coordinator died in; at JOBS_MAX_CRASHES the job
 * is failed with that reason instead of queued a third time. A count that
 * cannot be written does not stop the job (logged). */
#define JOBS_MAX_CRASHES 2
void jobs_attempt_begin(ts_jobs *j, const job *jb);
void jobs_attempt_end(ts_jobs *j, const job *jb);
/* What a killed coordinator left half-written in a job's directory. */
void jobs_remove_temporaries(const char *dir);
/* A directory and its files: 0, or -1 with errno of the first failure. */
int jobs_remove_dir(const char *dir);
/* A finished job's directory out of the spool (lock held). */
int jobs_discard_dir(ts_jobs *j, const job *jb, char *err);

#endif
