/* cluster.h - the coordinator's pool of workers and the cluster backend of
 * the search interface (seed 002 §3.6.4, in the manner of the Hannover
 * cluster design).
 *
 * Every reference set is cut, class by class, into one contiguous slice per
 * worker, sized in proportion to the worker's scan rate so all workers
 * finish a batch together. A batch goes to every worker holding a slice;
 * each returns its slice's best (global index, distance) per query and the
 * coordinator keeps the smallest distance, ties to the lowest index - the
 * same answer as one exhaustive scan, whatever the slicing.
 *
 * Rates: each worker is calibrated on the standard set when it joins
 * (calib.h), then measured on every batch. When the measured rates drift
 * from the ones the slices were sized with by more than `tolerance` for
 * longer than `persist` seconds, every set is re-sliced with the measured
 * rates; shorter spikes are ignored. A worker that fails (connection lost,
 * protocol error, deadline missed) is dropped and the batch is re-asked
 * from the others; with no worker left the coordinator scans in-process.
 *
 * Supervision: workers that serve a Modbus plane (proto/mbmap.h) are read
 * every `modbus_poll` seconds, apart from the data plane. A worker whose
 * drain coil is set hands its slices back and gets no new ones until the
 * coil is cleared; one whose Modbus and data planes are both silent is
 * dropped; and when the CPU shares the workers get (other load on their
 * machines) change unevenly for `persist` seconds, the slices are resized
 * in proportion. */
#ifndef TS_CLUSTER_H
#define TS_CLUSTER_H

#include <stdatomic.h>
#include <stdint.h>

#include "auth.h"
#include "msg.h"
#include "net.h"
#include "search.h"

/* What may resize slices: batch timings on the data plane (end to end),
 * and changes of the workers' CPU shares read over Modbus (load). */
enum { TS_REBALANCE_BATCHES = 1, TS_REBALANCE_MODBUS = 2 };

typedef struct {
  uint32_t calib_millis;   /* calibration scan length (200 ms) */
  double tolerance;        /* rate deviation that counts (0.25 = 25 %) */
  double persist;          /* seconds a deviation must last to rebalance (3) */
  double batch_timeout;    /* floor of a batch's deadline, seconds (2); the
                              deadline is 8x the batch's expected time */
  uint32_t max_redispatch; /* a batch that loses workers this many times in
                              a row fails its job (5) */
  int local_threads;       /* scan threads when no worker is ready (2) */
  uint32_t max_frame;      /* payload limit of worker replies */
  uint32_t pipeline_queries; /* queries per V frame: later frames are on
                                the wire while the first is scanned (256) */
  double heartbeat;        /* seconds of silence before an idle worker is
                              pinged; no answer in 2x+1 s drops it (2; 0 off) */
  const ts_auth *auth;     /* shared secret for dialled workers (NULL: none);
                              must outlive the cluster */
  double modbus_poll;      /* seconds between reads of each worker's Modbus
                              registers (1; 0 off): drain, liveness, load */
  int rebalance_from;      /* TS_REBALANCE_* signals that may resize slices (both) */
  uint32_t max_workers;    /* pool size, 1..TS_CLUSTER_MAX_WORKERS (256); a worker
                              past it is refused before it is calibrated */
} ts_cluster_opts;

#define TS_CLUSTER_MAX_WORKERS 4096

void ts_cluster_opts_default(ts_cluster_opts *o);

typedef struct ts_cluster ts_cluster;

int ts_cluster_create(ts_cluster **out, const ts_cluster_opts *o, char *err);
/* Stops the reconnect thread, closes every worker. */
void ts_cluster_destroy(ts_cluster *c);
/* A worker listening at addr (from --workers): connected, and reconnected
 * after a failure, by the cluster's own thread. */
int ts_cluster_add_address(ts_cluster *c, const char *addr, char *err);
/* A worker that connected to us (--join), past identify and
 * authentication (ts_auth_accept): the cluster calibrates it and takes
 * ownership of conn (on failure too: conn is closed). */
int ts_cluster_adopt(ts_cluster *c, ts_conn *conn, const ts_msg_ident *ident, char *err);

/* Pool snapshot for `texsyn workers`; returns the number of entries. */
uint32_t ts_cluster_info(ts_cluster *c, ts_worker_info *out, uint32_t cap);
int ts_cluster_ready(ts_cluster *c);
uint64_t ts_cluster_rebalances(ts_cluster *c);

typedef struct {
  uint32_t ready;           /* workers ready */
  uint64_t rate;            /* their rates summed, bytes scanned/s */
  uint64_t batches, queries; /* answered for jobs, by workers or locally */
} ts_cluster_stats;
void ts_cluster_stats_get(ts_cluster *c, ts_cluster_stats *out);

/* A search backend over the pool for one job. cancel (may be NULL) is
 * polled before each batch: non-zero fails the batch with TS_ECANCELED. */
int ts_search_cluster_create(ts_search **out, ts_cluster *c, const atomic_int *cancel,
                             char *err);

#endif
