/* msg.h - message bodies of the texsyn wire protocol (proto/PROTOCOL.md).
 *
 * One struct per message, one writer and one reader each. Writers append the
 * payload to a ts_wr (the caller frames it); readers decode a frame's payload
 * with full bounds checks and semantic range checks, so a reader that
 * returns 0 hands out a message whose sizes and counts are consistent with
 * the bytes actually received. Bulk parts (planes, queries, counters) are
 * not copied: the decoded struct points into the payload, valid as long as
 * the frame is.
 *
 * Connection start (every connection): I identify, A authenticate.
 * Data plane (coordinator <-> worker): C calibrate, N load slice, R query
 * image, V query batch, Q unload, H heartbeat, E error.
 * Job plane (client <-> coordinator): I identify, S submit, W status/watch,
 * F fetch, X cancel, D delete, P pool. */
#ifndef TS_MSG_H
#define TS_MSG_H

#include <stdint.h>

#include "error.h"
#include "frame.h"
#include "replica.h"
#include "search.h"
#include "slice.h"

enum {
  TS_MSG_IDENT = 'I',
  TS_MSG_AUTH = 'A',
  TS_MSG_CALIBRATE = 'C',
  TS_MSG_SLICE = 'N',
  TS_MSG_QUERY = 'V',
  TS_MSG_IMAGE = 'R',
  TS_MSG_UNLOAD = 'Q',
  TS_MSG_HEARTBEAT = 'H',
  TS_MSG_ERROR = 'E',
  TS_MSG_SUBMIT = 'S',
  TS_MSG_STATUS = 'W',
  TS_MSG_FETCH = 'F',
  TS_MSG_RANGE = 'B',
  TS_MSG_CANCEL = 'X',
  TS_MSG_POOL = 'P',
  TS_MSG_DELETE = 'D',
  TS_MSG_FIELD = 'G',
  TS_MSG_PASS = 'T',
  TS_MSG_PIECE = TS_FRAME_PIECE, /* transport: a piece of a larger message (pieces.h) */
};
/* A worker's answer to 'H': one byte of flags (an empty answer, from a
 * client's peer, means none). */
enum { TS_HEARTBEAT_DRAINING = 1 };

/* ---- I: identify -------------------------------------------------------- */

enum { TS_ROLE_COORD = 1, TS_ROLE_WORKER = 2, TS_ROLE_CLIENT = 3 };
#define TS_CAP_MASK 0x1u   /* masked queries */
#define TS_CAP_PARITY 0x2u /* parity classes */
#define TS_CAP_USAGE 0x4u  /* usage penalty replicas */
#define TS_CAP_ALL (TS_CAP_MASK | TS_CAP_PARITY | TS_CAP_USAGE)
/* The sender has a shared secret and runs the 'A' exchange (auth.h). Not in
 * TS_CAP_ALL: it says how this process is configured, not what it can do. */
#define TS_CAP_AUTH 0x8u
/* Messages in pieces (pieces.h). Not in TS_CAP_ALL: a client takes none. A
 * worker with it reassembles 'M' pieces; when the coordinator has it too,
 * the worker's 'C' reply carries its frame and message limits, and the
 * coordinator splits what is larger than the frame limit. */
#define TS_CAP_PIECES 0x10u
#define TS_MSG_NAME_MAX 128

typedef struct {
  uint8_t role;
  uint32_t caps;
  uint16_t threads; /* scan threads (workers), 0 otherwise */
  uint8_t simd;     /* ts_simd of the kernel in use */
  char name[TS_MSG_NAME_MAX]; /* software and version, free text */
  uint16_t modbus_port; /* the sender's Modbus plane, 0 if none (optional on the wire) */
} ts_msg_ident;

void ts_msg_ident_write(ts_wr *w, const ts_msg_ident *m);
int ts_msg_ident_read(const ts_frame *f, ts_msg_ident *m, char *err);

/* ---- A: authenticate --------------------------------------------------- */

/* Three steps after the 'I' exchange when both sides have a secret: the
 * accepting side's challenge (its nonce), the connecting side's response
 * (its nonce and its proof), the accepting side's proof. auth.h computes
 * the proofs; this is only their wire form. */
#define TS_AUTH_NONCE 32
#define TS_AUTH_MAC 32
enum { TS_AUTH_CHALLENGE = 1, TS_AUTH_RESPONSE = 2, TS_AUTH_PROOF = 3 };

#define TS_AUTH_KEY_NAME_MAX 64 /* bytes of a key's name (auth.h) */
typedef struct {
  uint8_t step;                 /* TS_AUTH_* */
  uint8_t nonce[TS_AUTH_NONCE]; /* challenge and response */
  /* Challenge and response: the key the proofs use, by kind (TS_KEY_*,
   * auth.h) and name. A challenge names none (kind 0, empty name) when the
   * connecting side is to name its own. */
  uint8_t key_kind;
  char key_name[TS_AUTH_KEY_NAME_MAX + 1];
  uint8_t mac[TS_AUTH_MAC]; /* response and proof */
} ts_msg_auth;

void ts_msg_auth_write(ts_wr *w, const ts_msg_auth *m);
/* Strict: the payload must be exactly the step's fields; a kind above 4,
 * or a name of other bytes than A-Z a-z 0-9 . _ @ -, is refused. */
int ts_msg_auth_read(const ts_frame *f, ts_msg_auth *m, char *err);

/* ---- C: calibrate ------------------------------------------------------- */

/* Request: scan the standard set (ts_calib_*) for about `millis`. */
typedef struct {
  uint32_t millis;
} ts_msg_calib_req;
/* Reply: comparisons done and the time they took: a rate, not seconds.
 * A worker answering a coordinator that speaks pieces (TS_CAP_PIECES) adds
 * its limits, so the coordinator knows what it may send it. */
typedef struct {
  uint64_t pairs, nanos;
  uint32_t max_payload; /* the worker's frame payload limit; 0: not sent */
  uint64_t max_message; /* the largest message it reassembles from pieces */
} ts_msg_calib;

void ts_msg_calib_req_write(ts_wr *w, const ts_msg_calib_req *m);
int ts_msg_calib_req_read(const ts_frame *f, ts_msg_calib_req *m, char *err);
void ts_msg_calib_write(ts_wr *w, const ts_msg_calib *m);
int ts_msg_calib_read(const ts_frame *f, ts_msg_calib *m, char *err);

/* ---- N: load slice ------------------------------------------------------ */

void ts_msg_slice_write(ts_wr *w, const ts_slice_desc *m);
int ts_msg_slice_read(const ts_frame *f, ts_slice_desc *m, char *err);

/* Reply to N: the slice is built; the vectors it holds. */
typedef struct {
  uint32_t set, gen;
  uint64_t vectors;
} ts_msg_loaded;

void ts_msg_loaded_write(ts_wr *w, const ts_msg_loaded *m);
int ts_msg_loaded_read(const ts_frame *f, ts_msg_loaded *m, char *err);

/* ---- R: query image ---------------------------------------------------- */
/* The worker's replica of a job's query image (replica.h). LOAD replaces
 * it with a whole state, numbered seq; NEXT applies the placements of the
 * level's last step to state seq and predicts the next level (its
 * reference planes follow), state 0; CLOSE frees it. Reply: R with the
 * image id. */
enum { TS_IMAGE_LOAD = 1, TS_IMAGE_NEXT = 2, TS_IMAGE_CLOSE = 3 };
/* Flags of a load: the done map follows; the image is bounded (no torus);
 * it keeps no copy map (none follows). */
enum { TS_LOAD_DONE = 1, TS_LOAD_BOUNDED = 2, TS_LOAD_NO_COPY = 4 };
#define TS_PLACE_BYTES 8
typedef struct {
  uint32_t image;
  uint8_t op;
  /* LOAD: the state. Written from d.copy; read, d.copy is NULL and the
   * copy map is copy_le (x then y, u32 LE per pixel) */
  ts_replica_desc d;
  const uint8_t *copy_le;
  uint64_t seq; /* LOAD: the state's number; NEXT: the placements' state */
  /* NEXT: the placements of the last step, then the level w x h, its
   * reference rw x rh (nplanes planes: d.ref) */
  const ts_place *place;  /* writing */
  const uint8_t *places;  /* reading: nplace x TS_PLACE_BYTES, ts_msg_place_at */
  uint32_t nplace;
  int w, h, rw, rh, nplanes;
} ts_msg_image;
void ts_msg_image_write(ts_wr *w, const ts_msg_image *m);
int ts_msg_image_read(const ts_frame *f, ts_msg_image *m, char *err);
void ts_msg_place_at(const uint8_t *places, uint32_t i, ts_place *p);
void ts_msg_image_ack_write(ts_wr *w, uint32_t image);
int ts_msg_image_ack_read(const ts_frame *f, uint32_t *image, char *err);

/* ---- V: query batch ----------------------------------------------------- */
/* Queries are positions in the set's query image, which is at state `seq`
 * once the frame's placements (if any: the step's, in its first frame)
 * are applied to the state before them, seq - 1. */
#define TS_QUERY_MASKS 0x1u
#define TS_QUERY_CLASSES 0x2u
#define TS_RESULT_BYTES 12
typedef struct {
  uint32_t set, gen, image;
  uint64_t seq;
  uint32_t nplace;
  const uint8_t *places; /* nplace x TS_PLACE_BYTES, ts_msg_place_at */
  uint32_t nq;
  uint8_t flags;
  uint64_t usage_k;
  const uint8_t *pos;   /* nq x u32 LE pixel indices */
  const uint8_t *klass; /* NULL if absent */
} ts_msg_query;
/* Writes queries [q0, q1) of b with the placements. */
void ts_msg_query_write(ts_wr *w, uint32_t set, uint32_t gen, uint32_t image, uint64_t seq,
                        const ts_place *p, uint32_t np, const ts_query_batch *b,
                        uint32_t q0, uint32_t q1);
int ts_msg_query_read(const ts_frame *f, ts_msg_query *m, char *err);
/* Query i's position. */
uint32_t ts_msg_pos_at(const ts_msg_query *m, uint32_t i);
/* Reply: per query the best (global index, distance) in the worker's slice
 * (index UINT32_MAX when its slice of that class is empty), and what the
 * scan cost, for the coordinator's rate tracking. */
typedef struct {
  uint32_t set, gen, nq;
  uint64_t scan_nanos, pairs;
  const uint8_t *results; /* nq x TS_RESULT_BYTES, ts_msg_result_at */
} ts_msg_answer;

void ts_msg_answer_write(ts_wr *w, uint32_t set, uint32_t gen,
                         uint64_t scan_nanos, uint64_t pairs,
                         const ts_l1_best *best, uint32_t nq);
int ts_msg_answer_read(const ts_frame *f, ts_msg_answer *m, char *err);
void ts_msg_result_at(const ts_msg_answer *m, uint32_t i, ts_l1_best *b);

/* ---- G: PatchMatch source ---------------------------------------------- */
/* A field set's source (patchmatch.h), whole: the window and its planes.
 * Reply: G with the set id. */
typedef struct {
  uint32_t set;
  ts_window_spec win;
  int w, h, nplanes;
  const uint8_t *plane[TS_WIN_MAX_PLANES];
  int16_t offbuf[2 * TS_NSRC * TS_WIN_MAX_OFFSETS]; /* decoded offsets */
  uint8_t knownbuf[TS_WIN_MAX_OFFSETS];
} ts_msg_field;
void ts_msg_field_write(ts_wr *w, const ts_msg_field *m);
int ts_msg_field_read(const ts_frame *f, ts_msg_field *m, char *err);
void ts_msg_field_ack_write(ts_wr *w, uint32_t set);
int ts_msg_field_ack_read(const ts_frame *f, uint32_t *set, char *err);

/* ---- T: PatchMatch pass ------------------------------------------------- */
/* Tiles of one pass over the field of query image `image` at state seq;
 * the field travels whole (each entry u16 x, u16 y: sources are at most
 * 65535 pixels on a side). Reply: the tiles' new entries, tile after tile
 * in the order asked, each row-major. */
#define TS_PASS_MAX_SIDE 65535
typedef struct {
  uint32_t set, image;
  uint64_t seq;
  uint32_t tw, th;
  uint64_t usage_k, seed;
  uint32_t pass, ntiles;
  const uint32_t *tiles;   /* writing */
  const uint32_t *field;   /* writing: tw * th x, y pairs */
  const uint8_t *tiles_le; /* reading: ntiles u32 */
  const uint8_t *field_le; /* reading: tw * th u16 pairs */
} ts_msg_pass;
void ts_msg_pass_write(ts_wr *w, const ts_msg_pass *m);
int ts_msg_pass_read(const ts_frame *f, ts_msg_pass *m, char *err);
/* Entry i of the field as u32 pairs; tile i's index. */
void ts_msg_pass_field(const ts_msg_pass *m, uint32_t *field);
uint32_t ts_msg_pass_tile(const ts_msg_pass *m, uint32_t i);

typedef struct {
  uint32_t set, pass, nentries;
  uint64_t nanos;
  const uint8_t *entries; /* nentries u16 pairs */
} ts_msg_pass_answer;
/* Writes the entries of tiles[0..n) of a tw x th field `out`. */
void ts_msg_pass_answer_write(ts_wr *w, uint32_t set, uint32_t pass, uint64_t nanos, const uint32_t *tiles,
                              uint32_t n, uint32_t tw, uint32_t th, const uint32_t *out);
int ts_msg_pass_answer_read(const ts_frame *f, ts_msg_pass_answer *m, char *err);

/* ---- Q: unload ---------------------------------------------------------- */

#define TS_UNLOAD_ALL UINT32_MAX
typedef struct {
  uint32_t set; /* or TS_UNLOAD_ALL */
} ts_msg_unload;

void ts_msg_unload_write(ts_wr *w, const ts_msg_unload *m);
int ts_msg_unload_read(const ts_frame *f, ts_msg_unload *m, char *err);

/* ---- E: error ----------------------------------------------------------- */

typedef struct {
  int32_t code; /* a TS_E* code */
  char text[TS_ERR_LEN];
} ts_msg_error;

void ts_msg_error_write(ts_wr *w, int code, const char *text);
int ts_msg_error_read(const ts_frame *f, ts_msg_error *m, char *err);

/* ---- S: submit ---------------------------------------------------------- */

#define TS_SPEC_MAX 16384
/* Input images a job takes: the first (the reference of an MRF job, the
 * style exemplar of a stylization) and up to TS_MSG_MAX_INPUTS - 1 more,
 * each named by the key its engine declares (server/engines/engine.h). */
#define TS_MSG_MAX_INPUTS 64
#define TS_MSG_KEY_MAX 32 /* an input key's bytes, NUL included */

/* An input after the first: its key ("guide_src_0"), its file name (for
 * its format) and its bytes. */
typedef struct {
  char key[TS_MSG_KEY_MAX];
  char name[TS_MSG_NAME_MAX];
  const uint8_t *data;
  uint32_t len;
} ts_msg_input;

typedef struct {
  const char *spec;      /* job spec text (jobspec.h), spec_len bytes */
  uint32_t spec_len;
  char ref_name[TS_MSG_NAME_MAX]; /* first input's file name (for its format) */
  const uint8_t *ref;    /* first input's file bytes */
  uint32_t ref_len;
  /* The inputs after the first, in the engine's order. On the wire they
   * follow the first as an optional tail, so a one-input submission is the
   * bytes it always was (PROTOCOL.md). */
  uint32_t nmore; /* 0..TS_MSG_MAX_INPUTS - 1 */
  ts_msg_input more[TS_MSG_MAX_INPUTS - 1];
} ts_msg_submit;

/* Whether key is a valid input key: 1..TS_MSG_KEY_MAX - 1 bytes of
 * lower-case letters, digits and '_' (it names a file in the spool). */
int ts_msg_key_valid(const char *key);

void ts_msg_submit_write(ts_wr *w, const ts_msg_submit *m);
int ts_msg_submit_read(const ts_frame *f, ts_msg_submit *m, char *err);

/* Reply to S, X: the job id. */
void ts_msg_jobid_write(ts_wr *w, uint64_t id);
int ts_msg_jobid_read(const ts_frame *f, uint64_t *id, char *err);

/* ---- W: status / watch -------------------------------------------------- */

typedef enum {
  TS_JOB_QUEUED = 0,
  TS_JOB_RUNNING,
  TS_JOB_DONE,
  TS_JOB_FAILED,
  TS_JOB_CANCELED,
  TS_JOB_STATE_COUNT
} ts_job_state;

const char *ts_job_state_name(int state);

/* Request: one job (id), or every job (id 0); follow: keep sending updates
 * of that one job until it ends. */
typedef struct {
  uint64_t id;
  uint8_t follow;
} ts_msg_status_req;

/* Flags of a job record. HELD: queued while the queue is paused (texsyn
 * status says "held"): it starts only once the queue is resumed. */
#define TS_JOB_HELD 0x1u
#define TS_JOB_ENGINE_MAX 32

typedef struct {
  uint64_t id;
  uint8_t state, level, levels;
  uint16_t permille;
  uint32_t eta_ms; /* UINT32_MAX = unknown */
  uint16_t workers;
  char text[TS_ERR_LEN]; /* failure reason, or a short description */
  uint8_t flags;         /* TS_JOB_HELD */
  /* When it was submitted, started (the last time: a restart runs it
   * again) and ended, in ms since the epoch on the coordinator's clock;
   * 0 = not yet, or not known (a job ended before a restart has no start). */
  uint64_t submitted_ms, started_ms, ended_ms;
  char engine[TS_JOB_ENGINE_MAX];  /* "synth", "stylize", ...; "unknown" if its spec is damaged */
  char owner[TS_MSG_NAME_MAX];     /* the submitting client, as it named itself: USER@HOST */
  char output[TS_MSG_NAME_MAX];    /* the result's name: the file the client asked for, else the spool's */
} ts_job_status;

void ts_msg_status_req_write(ts_wr *w, const ts_msg_status_req *m);
int ts_msg_status_req_read(const ts_frame *f, ts_msg_status_req *m, char *err);
/* Reply: a count and that many ts_job_status records. */
void ts_msg_status_write(ts_wr *w, const ts_job_status *s, uint32_t n);
/* Decodes up to cap records into s; *n = records in the frame. */
int ts_msg_status_read(const ts_frame *f, ts_job_status *s, uint32_t cap,
                       uint32_t *n, char *err);

/* ---- F: fetch ----------------------------------------------------------- */

/* Reply: named files (output image, copy maps, usage map, report), each
 * with its size; a file of up to TS_FETCH_INLINE bytes comes whole in the
 * reply, a larger one (a tiled scene of gigabytes) with no bytes: the
 * client takes it in 'B' ranges, so neither side holds it whole. */
#define TS_FETCH_MAX_FILES 8
#define TS_FETCH_INLINE (16u << 20)
typedef struct {
  uint32_t n;
  char name[TS_FETCH_MAX_FILES][TS_MSG_NAME_MAX];
  uint64_t size[TS_FETCH_MAX_FILES];
  const uint8_t *data[TS_FETCH_MAX_FILES]; /* NULL: a file taken in ranges */
  uint32_t len[TS_FETCH_MAX_FILES];        /* bytes inline: size, or 0 */
} ts_msg_files;

void ts_msg_files_write(ts_wr *w, const ts_msg_files *m);
int ts_msg_files_read(const ts_frame *f, ts_msg_files *m, char *err);

/* ---- B: a range of a fetched file ---------------------------------------- */

/* Request: bytes [offset, offset + len) of a finished job's file (a name
 * of its 'F' reply); reply: those bytes. len 1..TS_RANGE_MAX. */
#define TS_RANGE_MAX (16u << 20)
typedef struct {
  uint64_t id;
  char name[TS_MSG_NAME_MAX];
  uint64_t offset;
  uint32_t len;
} ts_msg_range;

void ts_msg_range_write(ts_wr *w, const ts_msg_range *m);
int ts_msg_range_read(const ts_frame *f, ts_msg_range *m, char *err);

/* ---- P: pool ------------------------------------------------------------ */

typedef struct {
  char addr[TS_MSG_NAME_MAX];
  uint16_t threads;
  uint8_t simd, state; /* state: ts_worker_state */
  uint64_t calibrated; /* bytes of vectors scanned per second at calibration */
  uint64_t rate;       /* bytes per second the slices are sized with
                          (calibrated, then measured on batches) */
  uint16_t share;      /* slice share, per mille (0 while draining or dead) */
  uint64_t batches;
  char name[TS_MSG_NAME_MAX]; /* its --name; "" without one */
  uint64_t died_ms; /* FAILED: when it was dropped (ms since the epoch); else 0 */
} ts_worker_info;

/* DRAINING: its Modbus `drain` coil is set; it holds and gets no slice.
 * FAILED: dropped from the pool (dead); listed until the coordinator
 * forgets it (cluster.h). */
enum { TS_WORKER_CALIBRATING = 0, TS_WORKER_READY, TS_WORKER_FAILED, TS_WORKER_DRAINING, TS_WORKER_STATE_COUNT };
const char *ts_worker_state_name(int state);

#define TS_POOL_MAX_REPORT 4096 /* the coordinator's largest pool */
void ts_msg_pool_write(ts_wr *w, const ts_worker_info *wi, uint32_t n);
int ts_msg_pool_read(const ts_frame *f, ts_worker_info *wi, uint32_t cap,
                     uint32_t *n, char *err);

/* Strings: u16 length and bytes, no terminator. */
void ts_wr_str(ts_wr *w, const char *s);
/* Copies a string into buf (cap bytes incl. the terminator); fails on an
 * over-long string or an embedded NUL. */
void ts_rd_str(ts_rd *r, char *buf, size_t cap);

#endif
