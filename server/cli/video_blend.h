/* video_blend.h - `texsyn video`'s output frames from its chains
 * (video_chain.h): one chain's frame, or between two keys the two chains'
 * frames merged by their piled-up error and blended in the gradient
 * domain (video_blend.c says how and why). */
#ifndef TS_VIDEO_BLEND_H
#define TS_VIDEO_BLEND_H

#include <stdio.h>

#include "video_chain.h"

/* What the blend did, for the report: per frame between two keys, the
 * share of pixels taken from the backward chain (the later key). */
typedef struct {
  long nframes;
  long *frame;
  double *backward;
} ts_video_blend;

/* Writes every output frame (v->out) from the chains' files in dir. 0 or
 * an error with its message; b filled either way (ts_video_blend_free). */
int ts_video_blend_write(const ts_video *v, const char *dir, ts_video_blend *b, char *err);
void ts_video_blend_free(ts_video_blend *b);

/* The report's "blend" value: one JSON object (the method, its constants,
 * the frames' shares). */
void ts_video_blend_json(FILE *f, const ts_video_blend *b);

#endif
