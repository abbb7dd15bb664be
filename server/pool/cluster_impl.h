/* cluster_impl.h - what the three parts of the coordinator's cluster share
 * (not for anyone else): the pool and its exchanges (cluster.c), the Modbus
 * supervision of the workers (supervise.c) and the search backend over the
 * pool (search_cluster.c and the files search_state.h lists).
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
#include <stdatomic.h>
#include <stdint.h>

#include "cluster.h"
#include "l1.h"
#include "log.h"
#include "pieces.h"
#include "pool.h"
#include "slice.h"

#define CL_MAX_SETS 8
#define CL_LOCAL_CALIB_MILLIS 50 /* the coordinator's own calibration, when asked */
/* Time constant of the measured-rate averages: long enough to smooth the
 * jitter of single small batches, short against `persist`. */
#define CL_RATE_TAU 0.5
/* A worker's measured rate counts up to this many times its calibrated
 * one: its answers report their own scan time and comparisons, and a
 * worker that claimed to scan ten times faster would otherwise be given
 * most of the reference at the next rebalance. The margin leaves room for
 * a worker calibrated while busy, or warmer caches on real batches. */
#define CL_RATE_CAP 1.25
/* Batches answered faster than this say nothing reliable about a
 * worker's rate (the round trip dominates). */
#define CL_MIN_SAMPLE_SECONDS 0.0002
/* A batch may take this many times its expected scan time before the
 * workers still owing answers are dropped (see batch_deadline). */
#define CL_DEADLINE_SLACK 8.0
/* A job canceled (or its daemon stopping) mid-exchange abandons the
 * answers it awaits (cl_exchange): the flag is looked at every
 * CL_CANCEL_POLL seconds. */
#define CL_CANCEL_POLL 0.1

/* A worker's output is produced as its socket drains (cl_exchange): when
 * fewer than CL_OUT_HIGH bytes wait unsent, the next CL_OUT_CHUNK bytes of
 * its queued messages are encoded. So the coordinator holds about
 * CL_OUT_HIGH + CL_OUT_CHUNK bytes per worker, never a whole slice (a big
 * reference's is hundreds of MB) nor all the frames of a batch. */
#define CL_OUT_HIGH (512u << 10)
#define CL_OUT_CHUNK (256u << 10)

typedef struct {
  uint32_t q0, nq; /* first query (over the whole batch) and count */
  int slice;       /* the worker's slice of the request's set */
} cl_frame_sent;

/* A request sent on a worker's connection and not answered yet. The
 * worker answers in request order (PROTOCOL.md), so every reply must
 * answer the oldest request outstanding, with its id and type (or 'E'):
 * anything else - stray, duplicate, out of order, unsolicited, an answer
 * to a request not sent whole - fails the worker. Ids count the
 * connection's requests and never repeat on it. */
typedef struct {
  uint32_t id;
  uint8_t type;
  uint8_t abandoned; /* its exchange was canceled: the answer is dropped */
  uint32_t tag;      /* the exchange's: what the request asked (see its reply fn) */
  uint64_t end;      /* where its bytes end in the connection's output stream */
} cl_request;

/* The arguments of one V frame's writer (ts_msg_query_write). */
typedef struct {
  uint32_t set, gen, image;
  uint64_t seq;
  const ts_place *place;
  uint32_t nplace;
  const ts_query_batch *b;
  uint32_t q0, q1;
} cl_query_frame;

/* A message queued for a worker. Its writer is run once per chunk on its
 * arguments and what they point at (level planes, the batch's queries and
 * commits), which stay unchanged until the exchange ends. */
typedef struct {
  ts_outmsg m;
  ts_payload_fn *write; /* NULL: empty payload */
  union {
    ts_slice_desc slice;
    cl_query_frame query;
    ts_msg_image image;
    ts_msg_unload unload;
    ts_msg_field field;
    ts_msg_pass pass;
  } arg;
} cl_msg;

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
  uint64_t died_ms; /* when it failed (ms since the epoch), else 0 */
  uint32_t share; /* per mille of the last set sliced */
  uint32_t max_payload; /* its frame limit: larger messages go in pieces */
  uint64_t max_message; /* the largest message it takes, in pieces or whole */
  int pieces;           /* it reassembles messages in pieces */
  int busy; /* leased to an exchange */
  int refs; /* leases holding or awaiting it: not freed while > 0 */
  /* One exchange's state: the lease holder's. */
  cl_msg *queue; /* messages to send, produced into out as it drains */
  uint32_t nqueue, qhead, cap_queue;
  ts_wr out;
  ts_wr plain; /* a sealed connection's frames before they are sealed into out */
  size_t out_off;
  int expect; /* requests of the lease holder's exchange not answered yet */
  /* The connection's requests outstanding, oldest first (a ring), and
   * its output stream's counters. Abandoned requests stay until their
   * answers come, whichever exchange reads them: `abandoned_due` is when
   * the last of them must have been answered. */
  cl_request *reqs;
  uint32_t req_head, nreqs, cap_reqs;
  uint32_t next_id;  /* the next request's frame id (1 was the calibration) */
  uint64_t produced; /* bytes put into out since the connection began */
  uint64_t sent;     /* bytes sent of those */
  double abandoned_due;
  uint32_t unloads;        /* times it was told to free slices ('Q') */
  uint32_t wipes;          /* times it was told to free everything ('Q' of all sets) */
  uint32_t images_sent;    /* query images (bits) whose frames it was sent */
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

/* A worker that loaded a PatchMatch source: it holds it until it is told
 * to free that source or everything (a drain: `wipes` moves), or leaves
 * (it rejoins under a new id). */
typedef struct {
  int worker;
  uint32_t wipes;
} cl_holder;

/* The PatchMatch sources the workers hold, shared by every job
 * (search_field.c): a field set a job prepares with the same window and
 * planes as a source some workers already hold - an earlier frame of a
 * sequence, another job on the same exemplar - goes only to the workers
 * that lack it. A source stays after its last set is released, until a
 * new one needs its entry (least recently used first). A worker never
 * holds more sources than there are entries: the worker takes 8
 * (PROTOCOL.md, 'G'). */
#define CL_MAX_SOURCES 8
#define CL_SOURCE_KEY 32 /* BLAKE2b of the 'G' message with set id 0 */

typedef struct {
  int used;
  int refs; /* field sets using it */
  uint8_t key[CL_SOURCE_KEY];
  uint32_t gid; /* its set id on the wire */
  uint64_t last_use;
  cl_holder *held; /* o.max_workers slots */
  int nheld;
} cl_source;

/* How long a dropped worker stays listed (as failed: `texsyn workers`
 * says dead) unless a worker of its name or address joins first. */
#define CL_DEAD_KEEP_MS (3600u * 1000u)

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
  ts_worker_info *dead; /* dropped workers still listed, oldest first (o.max_workers slots) */
  int ndead;
  int admitting; /* slots taken by workers being calibrated */
  cl_addr *addrs; /* --workers addresses (TS_CLUSTER_MAX_WORKERS slots; more
                     than the pool holds may be listed, as spares) */
  int naddrs;
  int next_worker_id;
  uint32_t next_set;
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
  cl_source sources[CL_MAX_SOURCES];
  uint64_t source_clock; /* last_use's clock */
  double local_rate; /* local_pool's calibrated rate, 0 until asked */
};

/* The cluster's lines go to the daemon's log (log.h). */
#define cl_log(c, ...) ((void)(c), ts_log(__VA_ARGS__))

/* Queue a request to w (leased) for the next cl_exchange, which sends it
 * whole, or in pieces when it exceeds w's frame limit, under the next id of
 * w's connection, and awaits its answer: an 'N' (slice) or a 'V' (query
 * frame). tag is the exchange's note of what it asked, handed back with
 * the answer (cl_reply_fn). 0, or TS_ENOMEM / TS_ETOOBIG (w cannot take
 * it) with a message. */
int cl_queue_slice(cl_worker *w, uint32_t tag, const ts_slice_desc *m, char *err);
int cl_queue_query(cl_worker *w, uint32_t tag, const cl_query_frame *q, char *err);
/* An 'R' (query image). */
int cl_queue_image(cl_worker *w, uint32_t tag, const ts_msg_image *m, char *err);
/* A 'G' (PatchMatch source) and a 'T' (PatchMatch pass). */
int cl_queue_field(cl_worker *w, uint32_t tag, const ts_msg_field *m, char *err);
int cl_queue_pass(cl_worker *w, uint32_t tag, const ts_msg_pass *m, char *err);
/* Payload bytes of an 'R' message. */
uint64_t cl_image_bytes(const ts_msg_image *m);
/* Payload bytes of a slice's 'N' message. */
uint64_t cl_slice_bytes(const ts_slice_desc *m);
/* Whether w takes a message of that many payload bytes: under its frame
 * limit whole, or under its message limit in pieces. */
int cl_worker_takes(const cl_worker *w, uint64_t bytes);
/* Drops what the exchange of w left unsent (queue and output) and the
 * requests it awaits, but for abandoned ones. */
void cl_out_reset(cl_worker *w);

/* Queues an 'H' to w (leased); its answer carries the worker's drain
 * flag (TS_HEARTBEAT_DRAINING). A worker it cannot be queued to is failed. */
void cl_queue_heartbeat(ts_cluster *c, cl_worker *w);
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

/* Called with every answer of a worker to a request of the exchange (rq:
 * the request it answers, matched by cl_exchange), an 'E' too; it checks
 * the answer against what rq asked. A negative return fails that worker. */
typedef int cl_reply_fn(void *ctx, cl_worker *w, const ts_frame *f, const cl_request *rq, char *err);
typedef struct {
  uint64_t bytes_out, bytes_in;
} cl_traffic;
/* Flags of cl_exchange. CL_X_SEND_ALL: once canceled, still send every
 * queued request (a clean-up: the workers must free what it names). */
enum { CL_X_SEND_ALL = 1 };
/* Sends every leased worker's queued requests and feeds each answer to fn
 * (NULL: any well-matched answer will do) until every request is answered
 * or its worker has failed; a worker still owing answers `timeout` seconds
 * after the start (plus the time its abandoned requests may still take)
 * fails. Called with the lock held and returns with it held; the lock is
 * released while bytes travel, so fn runs without it and may touch only
 * the caller's context and the leased workers' exchange state. Returns 0,
 * TS_ECONN when a worker failed, or TS_ECANCELED once *cancel (may be
 * NULL) is set: then the requests already under way are sent whole, the
 * others dropped (but with CL_X_SEND_ALL), and every answer awaited is
 * abandoned - the workers stay ready. See cluster.c. */
int cl_exchange(ts_cluster *c, cl_worker **ws, int n, double timeout, const atomic_int *cancel, unsigned flags,
                cl_reply_fn *fn, void *ctx, cl_traffic *tr);
/* An 'E' reply as an error. */
int cl_reply_error(const ts_frame *f, char *err);
/* Tells ws[0..n) to free a set (lock held): leases them, sends each a
 * 'Q' and awaits the answers - unless *cancel (may be NULL) is set: the
 * job is over, and they need not be awaited. */
void cl_unload_set(ts_cluster *c, cl_worker **ws, int n, uint32_t set, const atomic_int *cancel);

/* The Modbus supervisor's thread (supervise.c). */
void *cl_supervisor_thread(void *arg);

#endif
