/* mrf.h - multi-resolution MRF block synthesis (Stahlhut 2004, seed 002
 * §3.2-§3.5, §3.7, §3.8): full synthesis of a texture of any size from a
 * reference, tileable (torus), searched exactly through the search
 * interface. */
#ifndef TS_MRF_H
#define TS_MRF_H

#include <stddef.h>
#include <stdint.h>

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
} ts_mrf_params;

void ts_mrf_params_default(ts_mrf_params *p);

/* Checks parameters against a reference of ref_w x ref_h with `channels`
 * channels. Returns 0, or TS_EINVAL with every problem found listed in msg
 * (one per line). */
int ts_mrf_check(const ts_mrf_params *p, int ref_w, int ref_h, int channels,
                 char *msg, size_t msglen);

typedef struct {
  double seconds;
  uint64_t blocks, steps, pairs;
  uint64_t wire_bytes, round_trips; /* remote search backends only */
  int ref_w, ref_h, out_w, out_h;
  uint32_t vectors; /* reference vectors at this level */
} ts_mrf_level_stats;

typedef struct {
  ts_image image;      /* output, same type and channels as the reference */
  uint32_t *copy_map;  /* width*height (x, y) pairs into the reference */
  uint32_t *usage;     /* ref_w*ref_h counters of level 0 */
  int ref_w, ref_h;
  double usage_mean, usage_variance; /* over the usable reference pixels */
  double seconds;
  ts_mrf_level_stats level[TS_MRF_MAX_LEVELS];
} ts_mrf_result;

/* What a finished level hands to the next finer one, and all a restarted
 * coordinator needs to resume there (per-level checkpoints): the level's
 * canvas planes and copy map, and the statistics of the levels done. The
 * rest (reference pyramid, schedules, usage maps) is rebuilt from the job
 * spec, and synthesis from here on is a function of this state alone, so
 * a resumed job gives the same bytes as an uninterrupted one. */
typedef struct {
  int level;                        /* the finished level */
  int width, height;                /* its canvas */
  int nplanes;
  uint8_t *planes[TS_MAX_PLANES];   /* width*height each */
  uint32_t *copy;                   /* (x, y) per pixel into that level's reference */
  ts_mrf_level_stats stats[TS_MRF_MAX_LEVELS]; /* of level .. levels-1 */
} ts_mrf_checkpoint;

/* Called after every level but the last; the state is the engine's (valid
 * during the call only). A non-zero return fails the synthesis. */
typedef int ts_mrf_checkpoint_fn(void *ctx, const ts_mrf_checkpoint *ck, char *err);

typedef struct {
  ts_progress_fn *progress;     /* may be NULL */
  void *progress_ctx;
  ts_mrf_checkpoint_fn *checkpoint; /* may be NULL */
  void *checkpoint_ctx;
  const ts_mrf_checkpoint *resume;  /* start after this level (NULL: from noise) */
} ts_mrf_hooks;

/* Synthesises p->width x p->height (or, with stop_level > 0, the
 * 8-bit luminance of that level at its size) from ref using `search`.
 * hooks may be NULL. A resume state that does not fit p and ref is
 * refused (TS_EINVAL). On success res owns its buffers
 * (ts_mrf_result_free). */
int ts_mrf_synthesize(const ts_mrf_params *p, const ts_image *ref,
                      ts_search *search, const ts_mrf_hooks *hooks,
                      ts_mrf_result *res, char *err);
void ts_mrf_result_free(ts_mrf_result *res);

#endif
