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
#include "lbg.h"
#include "pool.h"
#include "search.h"
#include "usage.h"

enum { TS_SLICE_USAGE_NONE = 0, TS_SLICE_USAGE_ZERO = 1, TS_SLICE_USAGE_COUNTS = 2 };
/* How a slice's labels travel: none, as rows, or as a small tile they
 * repeat (parity classes are a 2 x 2 tile: no need to send a plane). */
enum { TS_SLICE_LABELS_NONE = 0, TS_SLICE_LABELS_ROWS = 1, TS_SLICE_LABELS_TILE = 2 };
#define TS_SLICE_MAX_TILE 16
#define TS_SLICE_MAX_SIDE 65536
#define TS_SLICE_MAX_PIXELS (1u << 28)

/* Rows [y0, y1) of a plane as an 'N' message carries them: rows [y0, k0)
 * at lo and [k1, y1) at hi (`row` bytes each, consecutive); the rows
 * [k0, k1) between are kept from the worker's previous slice of the set
 * and not sent (none of them for a whole slice: k0 == k1). */
typedef struct {
  const uint8_t *lo, *hi;
} ts_slice_rows;

/* The rows a worker's slice holds: what its next slice of the same set
 * may keep instead of receiving them again. */
typedef struct {
  uint32_t gen;
  int32_t fy0, fy1, cy0, cy1, ay0, ay1;
} ts_slice_held;

/* A slice of one reference set: its window, the level's anchors (counts
 * per class; the label and validity rows of the anchor rows it holds), per
 * class the vector range [i0, i1) the worker scans, and the rows of the
 * level planes those vectors read. The worker rebuilds window, anchors and
 * vectors from these alone: it knows no engine.
 *
 * A re-slice moves only what changed: when base_gen names the slice of the
 * set the worker holds, the rows both slices read are kept (kfy0..kay1)
 * and only the others travel; vectors of both ranges are copied, not
 * rebuilt. Generations start at 1; base_gen 0 is a whole slice. */
typedef struct {
  uint32_t set, gen; /* coordinator's set id, slice generation */
  uint32_t base_gen; /* 0, or the generation of the slice rows are kept from */
  uint32_t image;    /* the query image its queries read */
  ts_window_spec win; /* offsets: the coordinator's window, or offbuf */
  int32_t w, h, cw, ch; /* level and coarser level sizes (cw, ch 0: none) */
  uint16_t nclass;
  uint8_t labelled; /* TS_SLICE_LABELS_* */
  uint8_t masked;   /* validity rows follow */
  /* LABELS_TILE: the label of anchor (x, y) is tile[(y % tile_h) * tile_w
   * + x % tile_w]. */
  uint8_t tile_w, tile_h;
  uint8_t tile[TS_SLICE_MAX_TILE * TS_SLICE_MAX_TILE];
  uint32_t count[TS_MAX_CLASSES];        /* the set's anchors per class */
  uint32_t i0[TS_MAX_CLASSES], i1[TS_MAX_CLASSES]; /* this slice's ranges */
  int32_t ay0, ay1;                      /* anchor rows held */
  uint32_t above[TS_MAX_CLASSES];        /* labelled or masked: per class, anchors above ay0 */
  int32_t fy0, fy1;      /* fine rows [fy0, fy1) read, plane by plane */
  int32_t cy0, cy1;      /* coarse rows [cy0, cy1) read */
  int32_t kfy0, kfy1, kcy0, kcy1, kay0, kay1; /* of those, and of the anchor rows, the kept ones */
  /* 1: the fine rows to send are the reference planes of the query image
   * (replica.h) the worker holds, so they do not travel; fine_sum
   * (ts_slice_fine_sum) lets the worker check it holds the same. */
  uint8_t fine_from_image;
  uint64_t fine_sum;
  ts_slice_rows fine[TS_WIN_MAX_PLANES], coarse[TS_WIN_MAX_PLANES]; /* w, cw bytes a row */
  ts_slice_rows labels, valid; /* anchor rows [ay0, ay1), w bytes a row */
  uint8_t usage;          /* TS_SLICE_USAGE_* */
  ts_slice_rows counts;   /* COUNTS: u32 LE per pixel of the fine rows, 4 w bytes a row */
  /* A partitioned set (lbg.h): the codebook (its centroids the
   * coordinator's, or the message's); mode TS_LBG_OFF: exhaustive. The
   * worker finds each vector's partition itself. */
  ts_lbg_codebook lbg;
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
 * is not NULL and holds any use, the usage counters of those rows. With
 * held (what the worker's slice of the set holds; NULL: nothing), the
 * rows it holds already are kept, not sent. */
void ts_slice_describe(ts_slice_desc *m, const ts_refset *rs, const ts_usage *counts, uint32_t set,
                       uint32_t gen, uint32_t image, const uint32_t *i0, const uint32_t *i1,
                       const ts_slice_held *held);
/* The set is partitioned by cb (kept alive while m is): m carries it. */
void ts_slice_describe_lbg(ts_slice_desc *m, const ts_lbg_codebook *cb);
/* A checksum of the fine rows m sends (FNV-1a over 8-byte words, plane
 * by plane). */
uint64_t ts_slice_fine_sum(const ts_slice_desc *m);

/* If the labels repeat a tile of at most TS_SLICE_MAX_TILE on each side,
 * its size and bytes, and 1; else 0. */
int ts_slice_label_tile(const ts_plane *labels, uint8_t *tw, uint8_t *th, uint8_t *tile);

/* What a worker holds once it has loaded m. */
ts_slice_held ts_slice_held_by(const ts_slice_desc *m);
/* Bytes of rows m sends, and of rows it keeps. */
uint64_t ts_slice_row_bytes(const ts_slice_desc *m, int kept);

/* Builds a slice from a described or decoded 'N' message (the message's
 * bulk data may go away afterwards), its vectors on the threads of pool
 * (NULL: the calling thread; the pool must be idle). base is the slice of
 * the same set the worker holds (or NULL): kept rows, and vectors both
 * ranges hold, come from it; it is left as it was. Geometry the vectors
 * can't be built from - rows missing from the region, ranges past a class
 * or its anchor rows, a base that is not the one named, a codebook that
 * does not fit the set - is refused with a message. A partitioned slice
 * (m->lbg) keeps its vectors sorted by partition (slice_lbg.c). */
int ts_slice_load(ts_slice **out, const ts_slice_desc *m, const ts_slice *base, ts_pool *pool, char *err);
void ts_slice_free(ts_slice *s);

uint32_t ts_slice_set(const ts_slice *s);
uint32_t ts_slice_gen(const ts_slice *s);
uint64_t ts_slice_vectors(const ts_slice *s);
uint32_t ts_slice_image(const ts_slice *s);
uint32_t ts_slice_vbytes(const ts_slice *s);
/* TS_LBG_OFF, or how the partitioned slice is searched. */
int ts_slice_lbg(const ts_slice *s);
/* About how many comparisons a query of class c costs (exhaustive: the
 * class's vectors held; partitioned: the centroids and the probed
 * partitions' share of them). */
uint64_t ts_slice_query_cost(const ts_slice *s, int c);
const ts_window *ts_slice_window(const ts_slice *s);

/* Records copies in the usage replica (a no-op without usage). */
int ts_slice_commit(ts_slice *s, const ts_commit *c, uint32_t n, char *err);

/* Scans a batch with `threads` threads of pool (1 = the calling thread
 * alone): out[i] = best match of query i in this slice, as a global index
 * (UINT32_MAX if the slice holds no vector of its class). *pairs =
 * reference vectors compared (a partitioned slice's comparisons with its
 * centroids are not counted). A partitioned slice answers the best of the
 * query's probed partitions, or with TS_LBG_EXACT the exact best (lbg.h). */
int ts_slice_scan(ts_slice *s, ts_pool *pool, int threads, const ts_l1_impl *simd,
                  const ts_vec_batch *b, ts_l1_best *out, uint64_t *pairs, char *err);

#endif
