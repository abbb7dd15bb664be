/* window.h - the window of a feature set: which pixels of which planes make
 * a vector, and how its parts are weighted.
 *
 * Every engine describes its vectors with this one structure, and a worker
 * rebuilds them from it and the image rows it is sent, so the search
 * service knows nothing of any engine: the MRF's multi-scale block
 * neighbourhoods (neigh.h in server/engines), a StyLit job's style and
 * guide channels, a class map's labelled windows.
 *
 * Planes come from two *sources*: the level being searched (fine) and,
 * optionally, the next coarser level (coarse). Each source has its planes
 * (u8; engines quantise 16-bit or float inputs to u8 themselves and say
 * how) and its offsets: fine offsets are taken from the anchor (x, y);
 * coarse offsets from the anchor's coarse centre ((x + centre) / 2,
 * (y + centre) / 2) on the reference, or the block centre scaled to the
 * coarse canvas for queries (ts_vec_query).
 *
 * A vector is a sequence of *parts*, each a run of planes of one source with
 * its integer weight (the L1 kernels' weighted parts, l1.h). Part p holds,
 * plane by plane, the source's pixels at its offsets, then zeros to the next
 * 8-byte chunk. The MRF's two parts - fine neighbourhood, coarse window -
 * give exactly the layout the engine had before this structure existed.
 *
 * The extents are the boxes the anchors' windows must fit in: an anchor is a
 * reference vector only when its extent box lies inside the level (and the
 * coarse box inside the coarser level). Several windows sharing one set of
 * anchors (the MRF's causal L and its full square) give the same extents;
 * every offset must lie in its source's extent. */
#ifndef TS_WINDOW_H
#define TS_WINDOW_H

#include <stdint.h>

#include "l1.h"
#include "plane.h"

#define TS_WIN_MAX_PLANES 32   /* planes per source */
#define TS_WIN_MAX_OFFSETS 2048 /* offsets per source (a 45 x 45 window) */
#define TS_WIN_MAX_REACH 1024  /* |offset| and |extent| bound, pixels */

enum { TS_SRC_FINE = 0, TS_SRC_COARSE = 1, TS_NSRC = 2 };

/* A box of offsets [dx0, dx1) x [dy0, dy1). */
typedef struct {
  int16_t dx0, dy0, dx1, dy1;
} ts_box;

typedef struct {
  uint8_t source;          /* TS_SRC_* */
  uint8_t plane0, nplanes; /* planes [plane0, plane0 + nplanes) of the source */
  uint32_t weight;         /* integer weight, 0 = the part counts for nothing */
} ts_part;

/* What an engine gives ts_window_init. The offset arrays are copied. */
typedef struct {
  int nplanes[TS_NSRC]; /* coarse 0: no coarse source */
  int noff[TS_NSRC];
  const int16_t *dx[TS_NSRC], *dy[TS_NSRC];
  ts_box extent[TS_NSRC];
  int centre;           /* coarse centre of anchor x is (x + centre) / 2 */
  int block;            /* side of the square a copy takes from an anchor
                           (usage counters, usage.h); 1 = the anchor pixel */
  int nparts;
  ts_part part[TS_L1_MAX_PARTS];
  /* NULL, or one flag per fine offset: 1 = the offset always counts in a
   * masked query, placed or not (ts_vec_mask). */
  const uint8_t *known;
} ts_window_spec;

typedef struct {
  ts_window_spec spec; /* offsets point at the window's own copies */
  int16_t *off;        /* the copies: dx then dy of each source, then the
                          known flags */
  uint32_t part_end[TS_L1_MAX_PARTS]; /* chunk where each part ends */
  uint32_t nchunks;
} ts_window;

/* Checks a spec (every limit above, parts on existing planes, offsets in
 * their extents) and builds the window: 0, or TS_EINVAL / TS_ENOMEM with a
 * message. */
int ts_window_init(ts_window *w, const ts_window_spec *spec, char *err);
void ts_window_free(ts_window *w);
static inline uint32_t ts_window_bytes(const ts_window *w) {
  return w->nchunks * TS_L1_CHUNK;
}
static inline int ts_window_has_coarse(const ts_window *w) {
  return w->spec.nplanes[TS_SRC_COARSE] > 0;
}
/* The window's parts on a set of vectors (ts_l1_set_weigh). */
int ts_window_weigh(const ts_window *w, ts_l1_set *set, char *err);

/* The states of a query image's pixels (its `done` map, replica.h): what
 * a masked query may use and what a placement may write. */
enum {
  TS_DONE_FREE = 0,   /* not placed yet: masked; a placement writes it */
  TS_DONE_PLACED = 1, /* placed: counts (outside the block being filled); a
                         sweep's placement writes it again */
  TS_DONE_FIXED = 2,  /* given (a constraint): counts, inside the block too;
                         never written */
  TS_DONE_CLOSED = 3  /* unknown (a later class's area): masked; never written */
};

/* The mask of a masked query at (x, y) of a cw x ch canvas whose pixel
 * states are `done` (a torus if torus, else bounded: offsets outside it
 * never count): a fine offset counts (0xFF) when the window calls it
 * known, when its pixel is FIXED, or when it is PLACED outside the block
 * the query will fill (block x block at (x, y), clipped at the canvas
 * edge); coarse parts always count. Returns whether the mask differs from
 * the known flags alone. The window must have known flags. */
int ts_vec_mask(const ts_window *w, const uint8_t *done, int cw, int ch, int torus, int x, int y, uint8_t *mask);

/* The distance of an error of one grey level in every component: the
 * weighted count of components (the usage penalty's unit, usage.h). */
uint64_t ts_window_unit_distance(const ts_window *w);

/* Planes of one level: the level itself and the next coarser one. */
typedef struct {
  const ts_plane *fine[TS_WIN_MAX_PLANES];
  const ts_plane *coarse[TS_WIN_MAX_PLANES]; /* unused without a coarse source */
} ts_levelplanes;

/* Reference vector of the anchor (x, y), whose extents lie in the planes. */
void ts_vec_ref(const ts_window *w, const ts_levelplanes *ref, int x, int y, uint8_t *out);
/* Query vector at (x, y) of a canvas, read as a torus (torus = 1) or
 * bounded (offsets outside the fine planes read 0 - masked queries never
 * count them - and coarse ones the nearest edge pixel); the coarse centre
 * is the block centre (x + centre) scaled to the coarse canvas. */
void ts_vec_query(const ts_window *w, const ts_levelplanes *canvas, int torus, int x, int y, uint8_t *out);

#endif
