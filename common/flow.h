/* flow.h - dense optical flow between frames, warping along it, and
 * occlusions from the forward-backward check.
 *
 * A flow from frame A to frame B is 2*w*h floats, (u, v) per pixel,
 * row-major: the content at pixel (x, y) of A is at (x + u, y + v) in B.
 * Frames are 8-bit grey planes of one size (the luminance of the colour
 * frames: ts_image_luma8).
 *
 * ts_flow_dis is OpenCV's DIS flow (Kroeger et al. 2016), in the shared
 * library libtexsyn-flow.so (flow_lib.h) loaded on the first call; the
 * rest is plain C (flow.c). Determinism is the point: the same frames give
 * the same flow bytes on any x86-64 machine (see flow_cv.cpp for how). */
#ifndef TS_FLOW_H
#define TS_FLOW_H

#include <stddef.h>
#include <stdint.h>

/* Smallest frame side ts_flow_dis takes: DIS needs a few of its 8x8
 * patches on its finest level, which is half the frame's size. */
#define TS_FLOW_MIN_SIDE 32

/* Loads libtexsyn-flow.so now: 0, or TS_ENOTSUP with a message naming the
 * paths tried and why they failed (TEXSYN_FLOW_LIB overrides the search).
 * Idempotent and thread-safe; the library is never unloaded. */
int ts_flow_lib_load(char *err);

/* The flow from frame `from` to frame `to` (w x h bytes each) into uv
 * (2*w*h floats). 0; TS_EINVAL for a side below TS_FLOW_MIN_SIDE;
 * TS_ENOTSUP when the library does not load; TS_ENOMEM; TS_EIO when
 * OpenCV fails (its message in err). Thread-safe. */
int ts_flow_dis(const uint8_t *from, const uint8_t *to, int w, int h, float *uv, char *err);

/* What computes ts_flow_dis's flows, as one line ("OpenCV 4.6.0 DIS, ...")
 * for reports: a flow, and any score made from it, is only comparable
 * with one made by the same. "" if the library does not load. */
const char *ts_flow_method(void);

/* Backward warp: dst(x) = src(x + uv(x)), sampled bilinearly from the
 * w x h image src of `channels` interleaved floats per pixel, positions
 * outside the image clamped to its edge. With uv the flow from frame B to
 * frame A and src frame A, dst is A brought onto B's pixels. */
void ts_flow_warp(const float *src, int w, int h, int channels, const float *uv, float *dst);

/* The inverse of the flow f from A to B: the flow from B to A into inv
 * (2*w*h floats), by splatting. Each pixel x of A whose target x + f(x)
 * lies in B spreads -f(x) over the four pixels of B around the target
 * with its bilinear weights (raster order: the same sums everywhere);
 * each pixel of B takes the weighted mean of what it got. A pixel of B
 * that got a total weight of at most TS_FLOW_HOLE (no content of A lands
 * there: it is disoccluded) is given a flow that points out of the frame,
 * to the left, so that ts_flow_occlusion marks it occluded. Where content
 * of A lands on content of A (an occlusion), B's pixel takes the mean of
 * their motions, which the forward-backward check then finds inconsistent
 * where they differ. weight: w*h floats of scratch. */
#define TS_FLOW_HOLE 1e-3f
void ts_flow_invert(const float *f, int w, int h, float *weight, float *inv);

/* The forward-backward consistency check of Sundaram, Brox and Keutzer,
 * "Dense point trajectories by GPU-accelerated large displacement optical
 * flow" (ECCV 2010): with f the flow from A to B and b the flow
 * from B to A, pixel x of A is occluded (1 in occluded, else 0) when
 * x + f(x) lies outside B (it left the frame) or when following f and then
 * b does not come back:
 *   |f(x) + b(x + f(x))|^2 > 0.01 (|f(x)|^2 + |b(x + f(x))|^2) + 0.5,
 * b sampled bilinearly. The tolerance grows with the motion, as flow
 * errors do. Returns the number of occluded pixels. */
size_t ts_flow_occlusion(const float *f, const float *b, int w, int h, uint8_t *occluded);

#endif
