/* progress.h - how far a job is: what every engine reports while it runs,
 * for progress bars, ETAs and the job status. */
#ifndef TS_PROGRESS_H
#define TS_PROGRESS_H

#include <stdint.h>

typedef struct {
  int level, levels;     /* level (pyramid level, counts down to 0) */
  uint64_t done, total;  /* units (blocks, patches) of this level */
  /* Work of all levels in units of the finest level's cost (a block at
   * level l costs about 4^-l of one at level 0), for an ETA. */
  double work_done, work_total;
  /* What part of the level is under way, for engines whose levels have
   * parts (an aerial job's classes: "forest, class 1 of 4"); "" if none. */
  char stage[64];
} ts_progress;

typedef void ts_progress_fn(void *ctx, const ts_progress *p);

/* The hooks of an engine whose core reports progress only (fill, segment,
 * stylit; the MRF's take checkpoints too: mrf.h). */
typedef struct {
  ts_progress_fn *progress; /* may be NULL */
  void *progress_ctx;
} ts_progress_hooks;

#endif
