/* jobs_runner.h - the job queue's runner threads (jobs_runner.c). */
#ifndef TS_JOBS_RUNNER_H
#define TS_JOBS_RUNNER_H

#include "jobs_state.h"

/* A runner thread's body (arg: the ts_jobs). */
void *jobs_runner(void *arg);
/* Asks the running jobs to stop at a checkpoint, waits o.stop_grace at
 * most, then cancels what still runs (lock held). */
void jobs_stop_running(ts_jobs *j);

#endif
