/* slice.h - a slice of one reference set: the vectors of one range per
 * class, built from the level rows those vectors read, the usage replica
 * their penalties need, and the scan of a batch against them.
 *
 * The same code scans everywhere: on a worker (slices from 'N' messages),
 * in the local backend (one slice holding every vector) and on a
 * coordinator that has no worker. So a worker can never disagree with the
 * embedded engine about a distance. */
#ifndef TS_SLICE_H
#define TS_SLICE_H

#include <stdint.h>

#include "anchors.h"
#include "l1.h"
#include "pool.h"
#include "search.h"
#include "usage.h"

enum { TS_SLICE_USAGE_NONE = 0, TS_SLICE_USAGE_ZERO = 1, TS_SLICE_USAGE_COUNTS = 2 };
#define TS_SLICE_MAX_SIDE 65536
#define TS_SLICE_MAX_PIXELS (1u << 28)

/* A slice of one reference set: its window, the level's anchors (counts
 * per class; the label and validity rows of the anchor rows it holds), per
 * class the vector range [i0, i1) the worker scans, and the rows of the
 * level planes those vectors read. The worker rebuilds window, anchors and
 * vectors from these alone: it knows no engine. */
typedef struct {
  uint32_t set, gen; /* coordinator's set id, slice generation */
  uint32_t image;    /* the query image its queries read */
  ts_window_spec win; /* offsets: the coordinator's window, or offbuf */
  int32_t w, h, cw, ch; /* level and coarser level sizes (cw, ch 0: none) */
  uint16_t nclass;
  uint8_t labelled, masked; /* label / validity rows follow */
  uint32_t count[TS_MAX_CLASSES];        /* the set's anchors per class */
  uint32_t i0[TS_MAX_CLASSES], i1[TS_MAX_CLASSES]; /* this slice's ranges */
  int32_t ay0, ay1;                      /* anchor rows held */
  uint32_t above[TS_MAX_CLASSES];        /* labelled or masked: per class, anchors above ay0 */
  int32_t fy0, fy1;      /* fine rows [fy0, fy1) follow, plane by plane */
  int32_t cy0, cy1;      /* coarse rows [cy0, cy1) follow */
  const uint8_t *fine[TS_WIN_MAX_PLANES], *coarse[TS_WIN_MAX_PLANES]; /* first row of the region */
  const uint8_t *labels, *valid; /* anchor rows [ay0, ay1), w wide */
  uint8_t usage;          /* TS_SLICE_USAGE_* */
  const uint8_t *counts;  /* COUNTS: u32 LE per fine-region pixel */
  int16_t offbuf[2 * TS_NSRC * TS_WIN_MAX_OFFSETS]; /* decoded offsets */
  uint8_t knownbuf[TS_WIN_MAX_OFFSETS];              /* decoded known flags */
} ts_slice_desc;

typedef struct ts_slice ts_slice;

/* Query vectors as the scans take them: read out of a query image
 * (replica.h) by whoever holds it. */
typedef struct {
  uint32_t nq;
  const uint8_t *queries; /* nq vectors of the window's bytes */
  const uint8_t *masks;   /* NULL, or nq masks laid out like queries */
  const uint8_t *klass;   /* NULL = all class 0 */
  uint64_t usage_k;
} ts_vec_batch;

/* Describes vectors [i0[c], i1[c]) of every class of a set as an 'N'
 * message: the rows they read (pointers into rs's planes) and, if counts
 * is not NULL and holds any use, the usage counters of those rows. */
void ts_slice_describe(ts_slice_desc *m, const ts_refset *rs, const ts_usage *counts, uint32_t set,
                       uint32_t gen, uint32_t image, const uint32_t *i0, const uint32_t *i1);

/* Builds a slice from a described or decoded 'N' message (the message's
 * bulk data may go away afterwards), its vectors on the threads of pool
 * (NULL: the calling thread; the pool must be idle). Geometry the vectors
 * can't be built from - rows missing from the region, ranges past a class
 * or its anchor rows - is refused with a message. */
int ts_slice_load(ts_slice **out, const ts_slice_desc *m, ts_pool *pool, char *err);
void ts_slice_free(ts_slice *s);

uint32_t ts_slice_set(const ts_slice *s);
uint32_t ts_slice_gen(const ts_slice *s);
uint64_t ts_slice_vectors(const ts_slice *s);
uint32_t ts_slice_image(const ts_slice *s);
uint32_t ts_slice_vbytes(const ts_slice *s);
const ts_window *ts_slice_window(const ts_slice *s);

/* Records copies in the usage replica (a no-op without usage). */
int ts_slice_commit(ts_slice *s, const ts_commit *c, uint32_t n, char *err);

/* Scans a batch with `threads` threads of pool (1 = the calling thread
 * alone): out[i] = best match of query i in this slice, as a global index
 * (UINT32_MAX if the slice holds no vector of its class). *pairs =
 * comparisons made. */
int ts_slice_scan(ts_slice *s, ts_pool *pool, int threads, const ts_l1_impl *simd,
                  const ts_vec_batch *b, ts_l1_best *out, uint64_t *pairs, char *err);

#endif
