/* cluster_impl.h - what the three parts of the coordinator's cluster share
 * (not for anyone else): the pool and its exchanges (cluster.c), the Modbus
 * supervision of the workers (supervise.c) and the search backend over the
 * pool (search_cluster.c).
 *
 * Locking: one mutex guards the worker list and the workers' state, and is
 * never held while bytes travel. An exchange *leases* its workers (under
 * the lock, waiting until no other exchange holds any of them), then sends
 * and receives without the lock: a worker's connection, output buffer and
 * per-exchange counters belong to the lease holder. So the batches of
 * concurrent jobs still interleave whole on each connection (one
 * request/answer stream at a time, no demultiplexing), while status and
 * pool requests, heartbeats of idle workers and Modbus supervision go on.
 * A failed worker leaves the list only when no lease holds or awaits it
 * (refs). Slow work that involves a single new worker - connecting,
 * identifying, calibrating - happens before it enters the list.
 */
#ifndef TS_CLUSTER_IMPL_H
#define TS_CLUSTER_IMPL_H

#include <pthread.h>
#include <stdint.h>

#include "cluster.h"
#include "l1.h"
#include "log.h"
#include "pool.h"

#define CL_MAX_SETS 8
/* Time constant of the measured-rate averages: long enough to smooth the
 * jitter of single small batches, short against `persist`. */
#define CL_RATE_TAU 0.5
/* Batches answered faster than this say nothing reliable about a
 * worker's rate (the round trip dominates). */
#define CL_MIN_SAMPLE_SECONDS 0.0002
/* A batch may take this many times its expected scan time before the
 * workers still owing answers are dropped (see batch_deadline). */
#define CL_DEADLINE_SLACK 8.0

typedef struct {
  uint32_t q0, nq; /* first query (over the whole batch) and count */
  int answered;
} cl_frame_sent;

typedef struct {
  int id;
  ts_conn conn;
  ts_msg_ident ident;
  int state; /* TS_WORKER_* */
  /* Rates in bytes of reference vectors scanned per second, so that sets
   * of any vector length compare: a comparison of 1 KB vectors costs 18
   * times one of the 56-byte calibration vectors. */
  double calib_rate;  /* from calibration */
  double slice_rate;  /* rate the current slices were sized with */
  double ewma_rate;   /* measured on batches: the worker's own scan time */
  double ewma_bytes, ewma_secs; /* decayed sums behind ewma_rate */
  double ewma_weight; /* seconds of batches in the average (saturates) */
  uint64_t batches;
  uint32_t share; /* per mille of the last set sliced */
  int busy; /* leased to an exchange */
  int refs; /* leases holding or awaiting it: not freed while > 0 */
  /* One exchange's state: the lease holder's. */
  ts_wr out;
  size_t out_off;
  int expect;
  uint64_t expected_bytes; /* bytes the batch asks it to scan */
  uint64_t answered_bytes; /* bytes the batch's answers report scanned */
  uint64_t answered_nanos; /* scan time the batch's answers report */
  double heard_at;         /* when the worker last sent anything */
  double io_heard_at;      /* the same, as the lease holder saw it */
  double mb_heard_at;      /* when its Modbus plane last answered */
  double cpu_share;        /* share of CPU its threads get (Modbus), < 0 unknown */
  double share_sized;      /* the share when its slices were last sized, < 0 none */
  /* The query frames of the batch in flight, in the order sent: each is
   * answered exactly once, with exactly its number of results. */
  cl_frame_sent *frames;
  uint32_t nframes, cap_frames;
} cl_worker;

typedef struct {
  char addr[TS_NET_ADDR_LEN];
  int worker_id; /* live worker from this address, or 0 */
  int failing;   /* dialling it failed since it last joined (logged once) */
} cl_addr;

struct ts_cluster {
  pthread_mutex_t lock;
  ts_cluster_opts o;
  cl_worker **w; /* o.max_workers slots */
  int nw;
  int admitting; /* slots taken by workers being calibrated */
  cl_addr *addrs; /* --workers addresses (TS_CLUSTER_MAX_WORKERS slots; more
                     than the pool holds may be listed, as spares) */
  int naddrs;
  int next_worker_id;
  uint32_t next_set, next_frame;
  uint64_t epoch; /* bumped when the slicing must change */
  double deviating_since; /* start of the current rate deviation, or 0 */
  double load_deviating_since; /* the same for CPU-share changes */
  uint64_t rebalances;
  ts_pool *local_pool; /* in-process scanning with no worker */
  const ts_l1_impl *simd;
  pthread_t thread, supervisor;
  int stop, supervising;
  pthread_cond_t wake;
  pthread_cond_t released; /* a lease ended */
  uint64_t batches, queries; /* answered for jobs */
};

/* The cluster's lines go to the daemon's log (log.h). */
#define cl_log(c, ...) ((void)(c), ts_log(__VA_ARGS__))

/* Frames into a worker's output buffer: begin returns where the frame
 * starts, end fills in its length. */
size_t cl_frame_begin(ts_wr *w, uint8_t type, uint32_t id);
void cl_frame_end(ts_wr *w, size_t at);

/* Marks a worker failed (lock held): it leaves every slicing. */
void cl_worker_fail(ts_cluster *c, cl_worker *w, const char *why);
/* The ready workers (lock held); returns how many. */
int cl_ready_workers(ts_cluster *c, cl_worker **ws);
/* An array for a list of the pool's workers (o.max_workers entries), or
 * NULL; free() it. */
cl_worker **cl_worker_list(const ts_cluster *c);

/* Leases ws[0..n) (lock held): waits, with the lock released, until no
 * other exchange holds any of them, then holds them all. The pool may
 * have changed meanwhile (a failure moves c->epoch); workers that failed
 * are skipped by the exchange. */
void cl_lease(ts_cluster *c, cl_worker **ws, int n);
/* Ends a lease (lock held). */
void cl_release(ts_cluster *c, cl_worker **ws, int n);

/* Called for every frame a worker sends during an exchange; a negative
 * return fails that worker. */
typedef int cl_reply_fn(void *ctx, cl_worker *w, const ts_frame *f, char *err);
typedef struct {
  uint64_t bytes_out, bytes_in;
} cl_traffic;
/* Sends every leased worker's queued output and feeds each reply to fn
 * until every worker has answered its `expect` frames. Called with the lock
 * held and returns with it held; the lock is released while bytes travel,
 * so fn runs without it and may touch only the caller's context and the
 * leased workers' exchange state. See cluster.c. */
int cl_exchange(ts_cluster *c, cl_worker **ws, int n, double timeout, cl_reply_fn *fn, void *ctx,
                cl_traffic *tr);
/* An 'E' reply as an error. */
int cl_reply_error(const ts_frame *f, char *err);
/* Counts a 'Q' (unload) answer. */
int cl_unloaded_reply(void *ctx, cl_worker *w, const ts_frame *f, char *err);

/* The Modbus supervisor's thread (supervise.c). */
void *cl_supervisor_thread(void *arg);

#endif
