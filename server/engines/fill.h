/* fill.h - constrained MRF block synthesis (Stahlhut 2004, seed 002 §3.2,
 * §3.3.1, §3.7.2, §5.1.3): fills the work areas of an image that is partly
 * given - a hole, an extension, the land-use classes of an aerial scene -
 * from reference images, searched exactly through the search interface.
 *
 * The image's pixels each have a state: given (state 0: a constraint,
 * never changed) or the work area of class c = 1..nclass. Every class has
 * its own reference (one or more source images, each with the area that
 * may be copied from). Per pyramid level, coarsest first, the classes are
 * filled one after another in class order; while class c is filled, the
 * given pixels and those of classes < c (filled at this level already)
 * count in every comparison, class c's own pixels count once placed, and
 * those of later classes are unknown and never compared: the three-state
 * work mask of §5.1.3. Level by level, every class's coarse context is the
 * whole coarser level, all classes filled (the seed fills class by class
 * over the whole pyramid; this keeps its order within each level).
 *
 * Within a class the blocks (W_B x W_B on the block grid, clipped at the
 * edges; the image is no torus) are taken in the "puzzle" order of §3.2.4:
 * most given or placed pixels in the block's window first, from a bucket
 * queue with the blocks' grid as spatial index, so a placement re-sorts only
 * its neighbours. A step takes, from the top of the queue down, a set of
 * blocks none of which lies in another's window, and searches them as one
 * batch: exactly what placing them one by one in that order gives, so the
 * result is a pure function of the job (seed 002 digest §5.2), never of the
 * backend, its threads or workers. The alternative order of §3.2.5
 * (threshold) takes every block whose window has at least a share of its
 * pixels known, in rounds without re-sorting.
 *
 * A query is the block's whole W_N window with the variable mask of §3.2.6
 * (given and placed pixels count, the block's own given pixels too) plus the
 * coarse window; a reference block qualifies only when its whole window,
 * and its coarse window one level up, lie in its source's usable area
 * (§3.2.3). Pyramids of the image and of the sources are built with the
 * masked (normalised) Gaussian of §3.3.1. An area with nothing known around
 * it at the coarsest level starts from one reference block drawn with the
 * seed. A block writes only its work pixels of the class being filled. */
#ifndef TS_FILL_H
#define TS_FILL_H

#include <stdint.h>
#include <stdio.h>

#include "neigh.h"
#include "param.h"
#include "progress.h"
#include "search.h"
#include "fill_seams.h"

#define TS_FILL_MAX_CLASSES 64
#define TS_FILL_MAX_SOURCES 8 /* source images of one class's reference */
#define TS_FILL_MAX_LEVELS 12
#define TS_FILL_NO_SOURCE 0xFF

typedef enum { TS_FILL_PUZZLE = 0, TS_FILL_THRESHOLD = 1 } ts_fill_order;

typedef struct {
  int levels;           /* pyramid levels L */
  int wn, wb;           /* neighbourhood and block widths */
  int parity;           /* parity control, §3.3.3 */
  double coarse_weight; /* lambda, as in mrf.h */
  int order;            /* TS_FILL_PUZZLE or TS_FILL_THRESHOLD */
  double threshold;     /* THRESHOLD: share of the window a block needs known */
  uint64_t seed;        /* the blocks that start areas without context */
  uint32_t max_batch;   /* split a step's queries into batches of at most
                           this many (0 = whole steps); never changes results */
  int seam_cut;         /* the seam cut's reach (fill_seams.h), 0: none */
} ts_fill_params;

/* The fill's parameters (param.h) as entries of a table whose struct
 * holds a ts_fill_params at byte `base`, with the defaults of levels and
 * wn given (the fill job's and the aerial job's differ); the engines'
 * tables start with them, in their spec order. */
extern const char *const ts_fill_order_names[];
#define TS_FILL_PARAMS(base, levels_def, wn_def, seam_def)                                                            \
  {"levels", "levels", "L", TS_PARAM_INT, (base) + offsetof(ts_fill_params, levels), 1, TS_FILL_MAX_LEVELS,   \
   levels_def, "pyramid levels"},                                                                              \
  {"wn", "wn", "N", TS_PARAM_INT, (base) + offsetof(ts_fill_params, wn), 3, TS_MAX_WN, wn_def,                \
   "neighbourhood width, wider than --wb", .flags = TS_PARAM_ODD},                                            \
  {"wb", "wb", "B", TS_PARAM_INT, (base) + offsetof(ts_fill_params, wb), 1, 15, "3", "block width",          \
   .flags = TS_PARAM_ODD},                                                                                     \
  {"parity", "parity", NULL, TS_PARAM_FLAG, (base) + offsetof(ts_fill_params, parity), 0, 1, "0",            \
   "parity control (4x fewer comparisons, coarser joins)"},                                                  \
  {"coarse_weight", "coarse-weight", "W", TS_PARAM_DOUBLE, (base) + offsetof(ts_fill_params, coarse_weight), \
   0, 100, "1", "weight of the coarse-level part", .flags = TS_PARAM_MIN_OPEN},                               \
  {"order", "order", "O", TS_PARAM_ENUM, (base) + offsetof(ts_fill_params, order), 0, 0, "puzzle",           \
   "puzzle: the best known blocks first, re-sorted after every step; threshold: in rounds, every block with " \
   "at least --threshold of its window known (seed §3.2.5)", .names = ts_fill_order_names},                  \
  {"threshold", "threshold", "F", TS_PARAM_DOUBLE, (base) + offsetof(ts_fill_params, threshold), 0, 1,       \
   "0.25", "threshold order: the share of the window a block needs known", .flags = TS_PARAM_MIN_OPEN},      \
  {"seed", "seed", "S", TS_PARAM_U64, (base) + offsetof(ts_fill_params, seed), 0, 0, "1",                    \
   "seed of the blocks that start areas with nothing known around them", .flags = TS_PARAM_UNBOUNDED},         \
  {"seam_cut", "seam-cut", "N", TS_PARAM_INT, (base) + offsetof(ts_fill_params, seam_cut), 0,                \
   TS_SEAM_MAX_REACH, seam_def,                                                                               \
   "after the last level, move each join of two copies (block edges, the edge of the given pixels) up to N " \
   "pixels to where the two copies agree best (a minimum-cost cut, as image quilting); 0: joins stay on the " \
   "block grid"}

/* Those entries alone (base 0), with the fill job's defaults. */
extern const ts_param ts_fill_param_table[];
void ts_fill_params_default(ts_fill_params *p);

/* A source image of a class's reference: nplanes feature planes and the
 * pixels that may be copied (NULL: all). */
typedef struct {
  int w, h;
  const uint8_t *planes[TS_MAX_PLANES];
  const uint8_t *usable;
} ts_fill_source;

typedef struct {
  int nsources;
  ts_fill_source src[TS_FILL_MAX_SOURCES];
  double usage_weight; /* the active usage penalty (eq. 3.5, usage.h) */
} ts_fill_class;

typedef struct {
  int w, h, nplanes;
  const uint8_t *planes[TS_MAX_PLANES]; /* w*h each: valid where state is 0 */
  const uint8_t *state;                 /* w*h: 0 given, 1..nclass work areas */
  int nclass;
  const ts_fill_class *cls; /* cls[c - 1] is class c's reference */
  const char *const *names; /* names[c - 1] names class c in progress; NULL: none */
  /* Optional, for the seam cut: given pixels that are copies too (a
   * neighbouring fill's), so the cut may join the work to them. Per pixel
   * its class (0: not a copy), and where in that class's first source it
   * was copied from. */
  const uint8_t *given_from;
  const uint32_t *given_copy; /* 2 per pixel: x, y */
  /* Optional: given pixels (copies) that the cut may change too, so a
   * join between the work and given copies may go either way; the result
   * has a copy for those it changed. */
  const uint8_t *given_cut;
} ts_fill_input;

/* Appends the parameters' problems to msg (ts_problem), counting them. */
void ts_fill_check_params(const ts_fill_params *p, char *msg, size_t len, int *count);

/* Checks the parameters and that every class's reference has blocks to
 * copy at every level: 0, or TS_EINVAL with every problem listed in msg,
 * one per line; `names` (may be NULL) names the classes in messages. */
int ts_fill_check(const ts_fill_params *p, const ts_fill_input *in, const char *const *names, char *msg,
                  size_t len);

typedef struct {
  double seconds;
  uint64_t blocks, steps, seeds, pairs;
  uint64_t wire_bytes, round_trips;
  int w, h;
} ts_fill_level_stats;

typedef struct {
  double usage_mean, usage_variance; /* level 0, over the usable pixels */
  uint64_t blocks;                   /* level 0 */
} ts_fill_class_stats;

typedef struct {
  int w, h, nplanes;
  uint8_t *planes[TS_MAX_PLANES]; /* the filled feature planes */
  /* Per pixel: the source pixel it was copied from (x, y) and the source's
   * number in its class (TS_FILL_NO_SOURCE for given pixels, but those
   * the seam cut changed: ts_fill_input.given_cut). */
  uint32_t *copy;
  uint8_t *source;
  double seconds;
  ts_fill_level_stats level[TS_FILL_MAX_LEVELS];
  ts_fill_class_stats cls[TS_FILL_MAX_CLASSES];
} ts_fill_result;

/* Progress (progress.h's hooks): ts_progress after every step, its stage
 * naming the class being filled when there are several. */

/* Fills in's work areas. hooks may be NULL. On success res owns its
 * buffers (ts_fill_result_free). */
int ts_fill_synthesize(const ts_fill_params *p, const ts_fill_input *in, ts_search *search,
                       const ts_progress_hooks *hooks, ts_fill_result *res, char *err);
void ts_fill_result_free(ts_fill_result *res);

/* Report parts (JSON): the parameters as members of an object (no
 * braces), and the "levels" member with every level's statistics. */
void ts_fill_report_params(FILE *f, const ts_fill_params *p);
void ts_fill_report_levels(FILE *f, const ts_fill_params *p, const ts_fill_result *r);

#endif
