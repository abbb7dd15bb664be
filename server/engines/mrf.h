/* mrf.h - multi-resolution MRF block synthesis (Stahlhut 2004, seed 002
 * §3.2-§3.5, §3.7, §3.8): full synthesis of a texture of any size from a
 * reference, tileable (torus), searched exactly through the search
 * interface. */
#ifndef TS_MRF_H
#define TS_MRF_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include "param.h"

#include "image.h"
#include "neigh.h"
#include "progress.h"
#include "search.h"

#define TS_MRF_MAX_LEVELS 12

typedef struct {
  int width, height;    /* output size */
  int levels;           /* pyramid levels L (default 5) */
  int wn, wb;           /* neighbourhood and block widths (7, 3) */
  int parity;           /* parity control, §3.3.3 (off) */
  double usage_weight;  /* alpha of the usage penalty, eq. 3.5 (0 = off) */
  double coarse_weight; /* lambda: coarse part weight relative to area (1) */
  int refine;           /* refinement sweeps: whole coarser levels, and the
                           seam band of the finest (2) */
  uint64_t seed;        /* noise initialisation */
  int rgb_search;       /* search on every colour channel, not luminance */
  uint64_t max_pixels;  /* output size limit */
  uint32_t max_batch;   /* split a step into batches of at most this many
                           queries (0 = whole steps); never changes results */
  int stop_level;       /* stop after this level (0 = full synthesis); the
                           output is then that level's luminance, a preview */
  /* Passive usage-variance optimisation (§3.7.1): best_of candidate seeds
   * run the best_of_levels coarsest levels (0: all but the finest two, at
   * least one), and the one whose usage map there has the least variance
   * goes on. 1 = off. */
  int best_of, best_of_levels;
  /* Texture mixing (§4.3): levels >= mix_level from the reference, the
   * finer ones from a second, fine reference (0 = off). */
  int mix_level;
  /* Copy-map acceleration (§3.6.6), lossy: blocks inside coherent regions
   * of the level above's copy map are copied from their predicted source
   * without a search, at levels 1 and 0 once the levels above measured a
   * constancy of at least accel_min. accel_kernel: the n of the n x n
   * coherence kernel (0: W_C). */
  int copy_accel, accel_kernel;
  double accel_min;
  /* Opt-in vector-space partitioning (seed 002 §3.6.5, lbg.h): LBG
   * partitions per class (0: off, exhaustive search), the levels searched
   * so (bit l: level l; TS_MRF_LBG_ALL: every level), the partitions a
   * query scans, and exact pruning (the exhaustive results) instead of the
   * lossy probe. */
  int lbg;
  uint32_t lbg_levels;
  int lbg_probe;
  int lbg_exact;
} ts_mrf_params;

#define TS_MRF_MAX_BEST_OF 64
#define TS_MRF_LBG_ALL UINT32_MAX
/* Parses a --lbg-levels SPEC: "all", or level numbers separated by commas
 * ("0,1"), each below TS_MRF_MAX_LEVELS. 0 or TS_EINVAL. */
int ts_mrf_lbg_levels_parse(const char *spec, uint32_t *mask);
/* Formats a level mask as such a SPEC. */
void ts_mrf_lbg_levels_format(uint32_t mask, char *buf, size_t cap);

/* The parameters' declaration (mrf_params.c): spec keys, flags, ranges,
 * defaults and help; ts_mrf_params_default sets those defaults. */
extern const ts_param ts_mrf_param_table[];
void ts_mrf_params_default(ts_mrf_params *p);
/* The most pyramid levels, up to `most`, whose coarsest level of a w x h
 * output still holds a wn x wn neighbourhood (at least 1). */
int ts_mrf_levels_that_fit(int w, int h, int wn, int most);

/* Checks parameters against a reference of ref_w x ref_h with `channels`
 * channels. Returns 0, or TS_EINVAL with every problem found listed in msg
 * (one per line). */
int ts_mrf_check(const ts_mrf_params *p, int ref_w, int ref_h, int channels,
                 char *msg, size_t msglen);
/* With mix_level > 0: checks the fine reference (fine_w x fine_h,
 * fine_channels) against p and the reference's channel count, appending
 * every problem to msg (which may hold ts_mrf_check's). 0 or TS_EINVAL. */
int ts_mrf_check_fine(const ts_mrf_params *p, int fine_w, int fine_h, int fine_channels, int ref_channels,
                      char *msg, size_t msglen);

typedef struct {
  double seconds;
  uint64_t blocks, steps, pairs;
  uint64_t wire_bytes, round_trips; /* remote search backends only */
  int ref_w, ref_h, out_w, out_h;
  uint32_t vectors; /* reference vectors at this level */
} ts_mrf_level_stats;

/* The copy-map shortcut at one level (§3.6.6). Candidates are the blocks
 * whose predicted source lies in a coherent region of the level above's
 * copy map; `measured` of them were searched and `kept` of those found
 * their predicted source (the constancy, kept / measured); `copied` were
 * placed from it without a search (enabled levels only), which saved
 * `searches_saved` block searches over the scan and the sweeps. The
 * decision rested on pool_kept of pool_measured candidates of the levels
 * above. */
typedef enum { TS_ACCEL_NONE = 0, TS_ACCEL_VALIDATE, TS_ACCEL_ON } ts_accel_role;
typedef struct {
  ts_accel_role role; /* NONE: no prediction here (the coarsest or the mix level) */
  uint64_t blocks, candidates, measured, kept, copied, searches_saved;
  uint64_t pool_measured, pool_kept;
} ts_mrf_accel_stats;

/* One candidate of the passive variance optimisation. */
typedef struct {
  uint64_t seed;
  double variance; /* of the usage map at the last candidate level */
  double seconds;
} ts_mrf_candidate;
/* A chosen level of a partitioned search (ts_mrf_params.lbg): the
 * queries its plan makes of each of its two sets (the causal L's, the
 * full window's) and whether each is partitioned or, queried too seldom
 * for a codebook to pay, searched exhaustively (decided before synthesis,
 * from the parameters: on = either); and if this run synthesised the
 * level (ran), each partitioned set's codebook and the reference vectors
 * compared against what exhaustive search would have compared (of this
 * run, when it resumed inside the level). */
typedef struct {
  int on, ran;
  int partitioned[2];
  uint64_t queries[2];
  ts_lbg_report set[2];
  uint64_t pairs, full_pairs;
} ts_mrf_lbg_stats;

/* Where a resumed synthesis went on, for its log and report. */
typedef struct {
  int level;            /* the checkpoint's level */
  uint64_t step, steps; /* its steps done then, of all the level's steps */
  double level_done;    /* share of the level's blocks searched then */
  double saved_at;      /* its wall-clock moment, seconds since the epoch */
  double age;           /* wall-clock seconds from the checkpoint to the resume
                           (the downtime included) */
  /* At most this many seconds of the interrupted run's work are done
   * again: the age, or less when the run had a checkpoint interval (its
   * next checkpoint would have come that long after this one). */
  double redone;
} ts_mrf_resume;

typedef struct {
  ts_image image;      /* output, same type and channels as the reference */
  uint32_t *copy_map;  /* width*height (x, y) pairs into the reference */
  uint32_t *usage;     /* ref_w*ref_h counters of level 0 */
  int ref_w, ref_h;
  double usage_mean, usage_variance; /* over the usable reference pixels */
  double seconds;
  ts_mrf_level_stats level[TS_MRF_MAX_LEVELS];
  ts_mrf_lbg_stats lbg[TS_MRF_MAX_LEVELS];
  int resumed;         /* went on from a checkpoint: where in `resume` */
  ts_mrf_resume resume;
  /* best_of > 1: the candidates (none when a resumed run skipped them),
   * the one chosen, and the level whose usage variance chose it. */
  int ncandidates, chosen, best_of_level;
  ts_mrf_candidate candidate[TS_MRF_MAX_BEST_OF];
  ts_mrf_accel_stats accel[TS_MRF_MAX_LEVELS];
  int lossy; /* the copy-map shortcut was on at some level */
} ts_mrf_result;

/* A checkpoint: the state after `step` of the `steps` steps of a level
 * (the wavefront scan's steps, then every sweep pass's, in order), all a
 * restarted coordinator needs to go on from there. The rest (reference
 * pyramid, schedules) is rebuilt from the job spec, and synthesis from
 * here on is a function of this state alone, so a resumed job gives the
 * same bytes as an uninterrupted one, whichever step it was taken after.
 *
 * step == steps: the level is finished, and the finer levels read only
 * its canvas and copy map. Inside a level (step < steps), the steps left
 * also read the blocks placed so far (done), the usage counters (the
 * penalty, and the usage map at level 0) and the level above's canvas
 * (the coarse part of every query). */
typedef struct {
  int level;
  uint64_t step, steps;
  double saved_at;                  /* wall clock, seconds since the epoch */
  double interval;                  /* the run's checkpoint interval (ts_mrf_hooks) */
  int width, height;                /* the level's canvas */
  int nplanes;
  uint8_t *planes[TS_MAX_PLANES];   /* width*height each */
  uint32_t *copy;                   /* (x, y) per pixel into that level's reference */
  /* Inside a level only (NULL and 0 at a level's end): */
  uint8_t *done;                    /* width*height: 1 where a block was placed */
  int coarse_width, coarse_height;  /* the level above's canvas; 0x0 at the coarsest */
  uint8_t *coarse[TS_MAX_PLANES];
  int ref_width, ref_height;        /* the level's reference */
  uint32_t *usage;                  /* its usage counters */
  /* Of level .. levels-1; of `level` so far when inside it. */
  ts_mrf_level_stats stats[TS_MRF_MAX_LEVELS];
} ts_mrf_checkpoint;

/* Called after every level but the last, and between two steps once
 * checkpoint_interval seconds have passed since the last checkpoint; the
 * state is the engine's (valid during the call only). A non-zero return
 * fails the synthesis. */
typedef int ts_mrf_checkpoint_fn(void *ctx, const ts_mrf_checkpoint *ck, char *err);

typedef struct {
  ts_progress_fn *progress;     /* may be NULL */
  void *progress_ctx;
  ts_mrf_checkpoint_fn *checkpoint; /* may be NULL */
  void *checkpoint_ctx;
  /* Seconds of work between checkpoints inside a level (0: at level ends
   * only). Only the step a checkpoint follows is in it, never the time. */
  double checkpoint_interval;
  const ts_mrf_checkpoint *resume;  /* go on from here (NULL: from noise) */
  /* Called once resume is found to fit the job (may be NULL). */
  void (*resumed)(void *ctx, const ts_mrf_resume *r);
  /* Called when resume does not fit the job; synthesis then starts from
   * noise. NULL: synthesis fails with TS_EINVAL instead. */
  void (*refused)(void *ctx, const char *why);
  void *resume_ctx;
  /* Set (by another thread) when the run should stop early: after the
   * step under way it saves a checkpoint and returns TS_ESTOPPED, so a
   * later run resumes there with nothing redone. NULL: never. */
  const atomic_int *stop;
} ts_mrf_hooks;

/* Synthesises p->width x p->height (or, with stop_level > 0, the
 * 8-bit luminance of that level at its size) from ref using `search`.
 * hooks may be NULL. A resume state that does not fit p and ref is
 * refused (see ts_mrf_hooks.refused). On success res owns its buffers
 * (ts_mrf_result_free). */
int ts_mrf_synthesize(const ts_mrf_params *p, const ts_image *ref,
                      ts_search *search, const ts_mrf_hooks *hooks,
                      ts_mrf_result *res, char *err);
/* The same with texture mixing: with p->mix_level > 0 the levels below it
 * come from ref_fine, and so do the output's pixels; ref_fine is NULL
 * otherwise. */
int ts_mrf_synthesize_mixed(const ts_mrf_params *p, const ts_image *ref, const ts_image *ref_fine,
                            ts_search *search, const ts_mrf_hooks *hooks, ts_mrf_result *res, char *err);
void ts_mrf_result_free(ts_mrf_result *res);

#endif
