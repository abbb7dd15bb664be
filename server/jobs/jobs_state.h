/* jobs_state.h - what the job queue's files share (jobs.h is the face):
 * the records of jobs and clients.
 *
 *   jobs_queue.c   the jobs in memory: the list, versions, fair order
 *   jobs_spool.c   the spool on disk: a job's files, reloading, the lock
 *   jobs_runner.c  the runner threads: a job's inputs, engine, results
 *   jobs.c         the face: create, submit, status, cancel, delete
 *
 * Each calls only into the files listed above it. */
#ifndef TS_JOBS_STATE_H
#define TS_JOBS_STATE_H

#include <pthread.h>
#include <stdatomic.h>
#include <stdint.h>

#include "jobs.h"
#include "jobspec.h"
#include "log.h"

#define JOBS_PATH 4096
#define JOBS_SPOOL_LEN 1024 /* longer spool paths are refused */
#define JOBS_CLIENT_LEN 128
#define JOBS_MAX_PIXELS_OPTION "texsyn-server --max-pixels" /* named in limit errors */

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
  int kept; /* its expiry failed (logged): kept until a delete or a restart */
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
  pthread_t expirer; /* with o.keep_ended > 0 */
  int expiring;
  int lock_fd; /* SPOOL/lock, flocked: this coordinator's spool */
};

/* The queue's lines go to the daemon's log (log.h). */
#define jobs_log(j, ...) ((void)(j), ts_log(__VA_ARGS__))

/* The state after a job's last checkpoint (jobs_runner.c, on_checkpoint). */
#define JOBS_CHECKPOINT "checkpoint"
/* Checkpoint pieces (engine.h's save_piece): "piece-NAME" files. */
#define JOBS_PIECE_PREFIX "piece-"

/* A job that ended: done, failed or canceled. */
static inline int job_final(const job *jb) { return jb->st.state >= TS_JOB_DONE; }

#endif
