/* stylit_params.h - a stylization's parameters (stylit_params.c declares
 * them once, param.h): the limits, the search modes, the struct, the order
 * of the inputs, and the scene's entries the energy engine shares. What
 * the method does with them is stylit.h's. */
#ifndef TS_STYLIT_PARAMS_H
#define TS_STYLIT_PARAMS_H

#include <stddef.h>
#include <stdint.h>

#include "param.h"

#define TS_STYLIT_MAX_GUIDES 16
#define TS_STYLIT_MAX_LEVELS 12
#define TS_STYLIT_MAX_PATCH 15
#define TS_STYLIT_WEIGHT_STEPS 840 /* a weight's integer unit: lcm(1..8) / w, exact per channel count */

/* How a level's search step runs: exact (every source patch compared),
 * patchmatch (patchmatch.h: passes of propagation and random search over
 * fixed seeded tiles), size (the default): exact where the level's exact
 * comparisons would take at most the budget at a fixed reference speed
 * (TS_STYLIT_SIZE_RATE), else patchmatch - a rule of the job alone; auto:
 * the same at the search backend's calibrated rate (search.h: the pool's,
 * on a cluster), so its bytes depend on the pool and it is opt-in; or a
 * list: the mode of each level, coarsest first (what a run's report
 * records, to run the same job again anywhere). size and auto decide every
 * level before the first runs. */
enum { TS_STYLIT_EXACT = 0, TS_STYLIT_PATCHMATCH = 1, TS_STYLIT_AUTO = 2, TS_STYLIT_SIZE = 3, TS_STYLIT_LIST = 4 };
/* size's reference speed, in patch comparisons a second: about what the
 * exact search does on 2 cores with AVX-512 (1.1e9 measured on the StyLit
 * scene's 4 guides, Xeon and EPYC of 2026), so a level of at most --budget
 * seconds there runs exact. A constant: never the machine's. */
#define TS_STYLIT_SIZE_RATE 1e9
/* The longest search value: a list of TS_STYLIT_MAX_LEVELS modes. */
#define TS_STYLIT_SEARCH_LEN (TS_STYLIT_MAX_LEVELS * 11)

typedef struct {
  int patch;          /* p: odd, 3..TS_STYLIT_MAX_PATCH (5) */
  int levels;         /* 1..TS_STYLIT_MAX_LEVELS; 0: as many as fit (see ts_stylit_levels) */
  int iters;          /* EM iterations per level, 1..100 (6) */
  double uniformity;  /* λ, 0..1000 (0: off) */
  uint64_t seed;      /* the coarsest level's random NNF */
  uint64_t max_pixels;
  int guides;         /* 1..TS_STYLIT_MAX_GUIDES */
  double style_weight; /* 0 or 0.01..100 (1) */
  double weight[TS_STYLIT_MAX_GUIDES]; /* 0 or 0.01..100; < 0: 1 / guides */
  int search;         /* TS_STYLIT_EXACT / PATCHMATCH / AUTO / LIST (AUTO) */
  int nlevel_modes;   /* LIST: the modes of the levels, coarsest first */
  uint8_t level_mode[TS_STYLIT_MAX_LEVELS];
  int pm_iters;       /* patchmatch passes per search step, 1..100 (4) */
  double budget;      /* auto: seconds an exact level may take, 0..1e6 (1) */
  double scale;       /* the inputs resampled to this fraction first, (0, 1] (1) */
} ts_stylit_params;

/* Inputs in the engine's order: style, then per guide K source, target. */
enum { TS_STYLIT_IN_STYLE = 0 };
static inline int ts_stylit_in_src(int k) { return 1 + 2 * k; }
static inline int ts_stylit_in_tgt(int k) { return 2 + 2 * k; }

/* The scene's parameters (param.h) as entries of a table whose struct
 * holds a ts_stylit_params at byte `base`: the stylize and the energy
 * engines' tables start with them. The guides' weights are set by
 * --weight after what they weigh, as spec keys weight_K. */
#define TS_STYLIT_SCENE_PARAMS(base)                                                                          \
  {"patch_size", "patch-size", "P", TS_PARAM_INT, (base) + offsetof(ts_stylit_params, patch), 3,              \
   TS_STYLIT_MAX_PATCH, "5", "patch width", .flags = TS_PARAM_ODD},                                           \
  {"max_pixels", NULL, NULL, TS_PARAM_U64, (base) + offsetof(ts_stylit_params, max_pixels), 0, 0,             \
   "268435456", "image size limit", .flags = TS_PARAM_UNBOUNDED},                                             \
  {"guides", NULL, NULL, TS_PARAM_INT, (base) + offsetof(ts_stylit_params, guides), 1, TS_STYLIT_MAX_GUIDES, \
   "1", "guide pairs"},                                                                                        \
  {"style_weight", NULL, NULL, TS_PARAM_DOUBLE, (base) + offsetof(ts_stylit_params, style_weight), 0, 100,   \
   "1", "the style's weight"}

/* The stylize engine's parameters (stylit_params.c) and their defaults. */
extern const ts_param ts_stylit_param_table[];
void ts_stylit_params_default(ts_stylit_params *p);
/* Search mode names: "exact", "patchmatch", "auto". */
const char *ts_stylit_search_name(int mode);
/* The search value: a mode name, or a list of exact and patchmatch, one
 * per level, coarsest first, comma-separated. */
int ts_stylit_search_parse(const char *text, ts_stylit_params *p, char *err);
/* The search value as the parser reads it (TS_STYLIT_SEARCH_LEN bytes). */
void ts_stylit_search_format(const ts_stylit_params *p, char *out, size_t cap);
/* Guide k's weight, the default resolved. */
double ts_stylit_weight(const ts_stylit_params *p, int k);

#endif
