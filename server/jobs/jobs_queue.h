/* jobs_queue.h - the jobs in memory (jobs_queue.c), the lock held. */
#ifndef TS_JOBS_QUEUE_H
#define TS_JOBS_QUEUE_H

#include "jobs_state.h"

/* A job's status changed: its version moves on and waiters wake. */
void jobs_changed(ts_jobs *j, job *jb);
job *jobs_find(ts_jobs *j, uint64_t id);
void jobs_append(ts_jobs *j, job *jb);
/* The record's fixed fields from the job's spec and client: engine, owner,
 * output. */
void jobs_describe(job *jb);
/* A copy of the job's record for a client: held while the queue is paused. */
void jobs_record(const ts_jobs *j, const job *jb, ts_job_status *out);
/* A client's record; NULL only when out of memory. */
client_share *jobs_share_of(ts_jobs *j, const char *client);
/* The next job to start: fewest started jobs per client, then the oldest. */
job *jobs_pick(ts_jobs *j);

#endif
