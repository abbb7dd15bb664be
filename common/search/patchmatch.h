/* patchmatch.h - an approximate nearest-patch field (PatchMatch, Barnes et
 * al. 2009) whose result depends on nothing but its inputs and a seed:
 * not on the threads, the workers or the order they finish in.
 *
 * The field maps every target pixel to the centre of a p x p source patch
 * (the window of a square ts_window: offsets (0..p-1, 0..p-1), parts on
 * fine planes). A pass improves it in place of an exact scan:
 *
 *   the target is cut into fixed T x T tiles (TS_PM_TILE); each tile is
 *   swept in scan order (even passes: left to right, top to bottom, taking
 *   the left and upper neighbour's match shifted by one; odd passes: the
 *   reverse, from the right and lower neighbour), and every pixel then
 *   tries random centres around its best at radii max(sw, sh), halved down
 *   to 1 (the random search), keeping a candidate only when it is strictly
 *   better: a smaller distance, or an equal one at a lower source index.
 *
 * Determinism: a neighbour inside the tile gives its match of this pass, a
 * neighbour outside it the match the pass started from; each tile draws
 * from its own stream of the seed (pass and tile index mixed in). A tile
 * is thus a pure function of the pass's input, and tiles may run anywhere
 * in any order.
 *
 * Uniformity: with a penalty factor K (usage.h) a candidate's distance
 * gains ts_usage_penalty(U_j, K), U_j the occurrence counts (every target
 * pixel's patch counts once on each source pixel it covers) summed over
 * source patch j. The counts are those of the pass's input field, plus the
 * moves the tile has made so far in its own sweep (so a tile's pixels do
 * not crowd into one source patch together); the moves of other tiles
 * count from the next pass on. */
#ifndef TS_PATCHMATCH_H
#define TS_PATCHMATCH_H

#include <stddef.h>
#include <stdint.h>

#include "window.h"

#define TS_PM_TILE 64 /* tile side in target pixels */

/* Planes repacked per part: for part k, w * h pixels of ch[k] interleaved
 * bytes (one span per patch row), with slack after for 16-byte loads. */
typedef struct {
  int w, h, nparts;
  uint8_t ch[TS_L1_MAX_PARTS];
  uint8_t *part[TS_L1_MAX_PARTS];
} ts_pm_image;

/* Repacks planes (w x h, the window's fine planes) for the window's
 * parts: 0 or TS_ENOMEM. */
int ts_pm_image_pack(ts_pm_image *im, const ts_window *win, const ts_plane *const *planes);
void ts_pm_image_free(ts_pm_image *im);
/* Whether win is a square p x p window over fine planes that patchmatch
 * can run; *patch = p. 0, or TS_EINVAL with a message. */
int ts_pm_window_check(const ts_window *win, int *patch, char *err);

/* One pass. src: sw x sh; tgt: (tw + p - 1) x (th + p - 1), so target
 * pixel (x, y)'s patch is the window at (x, y). Fields hold x, y source
 * centres per target pixel, each in [r, sw - r) x [r, sh - r). */
typedef struct {
  const ts_window *win;
  int patch;
  const ts_pm_image *src, *tgt;
  int tw, th;
  const uint32_t *in;      /* the field the pass starts from */
  const uint32_t *ublock;  /* U_j per source patch (y * (sw - p + 1) + x of
                              its top-left corner); NULL: no penalty */
  uint64_t k;              /* penalty factor, 0: none */
  uint64_t seed;
  uint32_t pass;           /* parity: the sweep's direction */
  int scalar;              /* 1: the scalar distance (TEXSYN_SIMD=scalar);
                              0: SSE2 where built (every x86-64); the same
                              result either way */
} ts_pm_pass;

/* Per-thread scratch of tile sweeps. */
typedef struct {
  uint32_t *usage; /* with a penalty: U_j of the pass's input plus the moves
                      of the tile under way (ublock again between tiles) */
  size_t usage_cap;
  uint32_t *moves; /* the tile's moves (anchor from, anchor to) */
  size_t nmoves, cap;
  uint8_t *query;  /* the target patch a pixel's candidates are compared with */
  size_t query_cap;
  uint32_t *area;  /* overlap areas of two patches, (2p - 1)^2 offsets */
  size_t area_cap;
} ts_pm_scratch;

int ts_pm_tiles(int tw, int th);
/* Readies scr for the tiles of pass ps (once per pass and thread, before
 * its first tile): 0 or TS_ENOMEM. */
int ts_pm_scratch_begin(ts_pm_scratch *scr, const ts_pm_pass *ps);
/* Sweeps tile t with scr readied for ps: writes the tile's entries of out
 * (a whole field, tw x th entries; the rest untouched) and returns the sum
 * of its pixels' final distances. 0 or TS_ENOMEM in *rc. */
uint64_t ts_pm_sweep_tile(const ts_pm_pass *ps, int t, ts_pm_scratch *scr, uint32_t *out, int *rc);
void ts_pm_scratch_free(ts_pm_scratch *scr);

/* Occurrence counts (sw x sh) of a field of n centres, patch p, and their
 * sums over every source patch (ublock, (sw - p + 1) x (sh - p + 1); col:
 * sw counters of scratch). */
void ts_pm_occurrences(const uint32_t *field, size_t n, int p, int sw, int sh, uint32_t *counts);
void ts_pm_block_sums(const uint32_t *counts, int p, int sw, int sh, uint32_t *col, uint32_t *ublock);

#endif

/* ---- a pass over many tiles (patchmatch_run.c) -------------------------
 *
 * What a holder of the source keeps between passes: the packed source, the
 * target of the image under way, the occurrence sums, per-thread scratch. */
typedef struct ts_pool ts_pool;

typedef struct {
  const ts_window *win;
  int patch;
  ts_pm_image src, tgt;
  uint32_t *counts, *ublock, *col;
  ts_pm_scratch *scr;
  int nscr;
} ts_pm_field;

/* Packs the source planes (sw x sh, the window's fine planes): 0, or
 * TS_EINVAL / TS_ENOMEM with a message. */
int ts_pm_field_init(ts_pm_field *f, const ts_window *win, const ts_plane *const *src, int nthreads, char *err);
void ts_pm_field_free(ts_pm_field *f);
/* The target planes of the passes that follow ((tw + p - 1) x (th + p - 1)). */
int ts_pm_field_target(ts_pm_field *f, const ts_plane *const *tgt, char *err);

typedef struct {
  int tw, th;
  const uint32_t *in;
  uint64_t k;      /* 0: no penalty; else counts are taken from in */
  uint64_t seed;
  uint32_t pass;
  int scalar;
} ts_pm_job;

/* Sweeps tiles[0..n) of the pass (all of them when tiles is NULL: n is
 * then ignored) on the pool, into out. 0, or a TS_E* code with a message. */
int ts_pm_field_pass(ts_pm_field *f, const ts_pm_job *j, const uint32_t *tiles, int n, ts_pool *pool, uint32_t *out,
                     char *err);
