/* video_flow.h - the flows of `texsyn video`: given (--flow, --flow-back)
 * or computed (OpenCV's DIS, flow.h).
 *
 * A given flow is one image per frame, float samples (OpenEXR, or a float
 * TIFF), at least two channels of which the first two are used: frame t's
 * --flow file maps t to t+1, in pixels, x to the right and y down: the
 * content at (x, y) of frame t is at (x + u, y + v) in frame t+1 (flow.h's
 * convention; a renderer's motion vectors towards the next frame). So
 * --flow is needed for frames A..B-1. --flow-back, frame t mapping t to
 * t-1 (A+1..B), is optional: without it the backward flow is the forward
 * one inverted (ts_flow_invert), which keeps both directions the one
 * motion the renderer gave, exact and the same bytes everywhere, where
 * computing it (DIS on the frames) would disagree with the given flow
 * and the forward-backward check would take the disagreement for
 * occlusions. Non-finite samples mean "no correspondence": they point out
 * of the frame (occluded); values are clamped to twice the frame's size. */
#ifndef TS_VIDEO_FLOW_H
#define TS_VIDEO_FLOW_H

#include "video_chain.h"

/* Checks before any work: every given flow file of the frames it is
 * needed for readable, the frames' size, float, two channels or more; an
 * error names the option, the frame and the file. */
int ts_video_flow_check(const ts_video *v, char *err);

/* The flows between chain frames `prev` and t = prev +- 1: back from t
 * to prev, fwd from prev to t (2*w*h floats each). luma_t and luma_prev
 * are the frames' luminance (used when the flow is computed); scratch:
 * w*h floats. */
int ts_video_flows(const ts_video *v, long prev, long t, const uint8_t *luma_prev, const uint8_t *luma_t,
                   float *back, float *fwd, float *scratch, char *err);

#endif
