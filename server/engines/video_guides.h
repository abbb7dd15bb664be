/* video_guides.h - the per-frame guides of video stylization (issue 27,
 * after Jamriška et al., "Stylizing Video by Example", SIGGRAPH 2019):
 * besides the frame's own colours,
 *   edges     where the frame's structure is, so strokes follow contours
 *             whatever their colour;
 *   position  where each pixel's content was in the keyframe: the key's
 *             pixel coordinates carried along the optical flow frame after
 *             frame, so the same content keeps taking its style from the
 *             same place of the key (what stops strokes swimming).
 * 8-bit planes as the StyLit engine takes them; integer arithmetic or
 * plain float without contraction, so the same bytes everywhere.
 * `texsyn video` makes its guides with these (server/cli/video_chain.c). */
#ifndef TS_VIDEO_GUIDES_H
#define TS_VIDEO_GUIDES_H

#include <stddef.h>
#include <stdint.h>

#include "param.h"

/* The made guides' weights, each 0 (the guide is not made) or in its
 * range; declared once in ts_video_params, from which `texsyn video`'s
 * options, their --help, ranges and defaults and `texsyn params video`
 * come. The position weight is split between its x and y planes. */
typedef struct {
  double edge, position, temporal, mask;
} ts_video_weights;
extern const ts_param ts_video_params[];
/* Where texsyn video starts the stylize engine's parameters elsewhere than
 * stylize does: the search budget, 0.1 s an exact level at the reference
 * speed instead of 1, since a sequence pays it on every frame (at 256x192
 * with the video's guides, the second-finest level takes PatchMatch and a
 * frame about a fifth of the time, at the same energy). */
extern const ts_param_default ts_video_defaults[];

/* The edge guide of a w x h luminance plane into out (w x h): the Sobel
 * gradient magnitude |gx| + |gy| scaled to 0..255, then blurred by the
 * binomial kernel (1 4 6 4 1)/16 across and down, so that an edge guides
 * the patches near it too and one-pixel noise does not. Borders mirror.
 * 0, or TS_ENOMEM. */
int ts_guide_edges(const uint8_t *luma, int w, int h, uint8_t *out);

/* The positional guide of the keyframe itself: pos (2*w*h floats) holds
 * each pixel's own (x, y). */
void ts_guide_position_key(int w, int h, float *pos);

/* The positional guide one frame on: pixel x of the new frame takes the
 * previous guide at x + back(x) (back: the flow from the new frame to the
 * previous one, flow.h), sampled bilinearly; where occluded (1: the
 * content is not in the previous frame, ts_flow_occlusion on the new
 * frame) nothing can be carried, and the pixel is reset to its own
 * coordinates, as in the key. prev and pos must not overlap. */
void ts_guide_position_advect(const float *prev, const float *back, const uint8_t *occluded, int w, int h,
                              float *pos);

/* pos as two 8-bit planes, x and y, scaled so that the key's w x h pixels
 * span 0..255 (rounded, clamped: content carried beyond the key's edge
 * stays at the edge value). */
void ts_guide_position_planes(const float *pos, int w, int h, uint8_t *px, uint8_t *py);

/* The temporal guide, weighted out per pixel where occluded (Jamriška et
 * al. 2019 weigh it out there: the previous frame warped from elsewhere
 * would vote for whatever occluded the content). A stylize job weighs
 * whole images, so the guide is a pair with half the weight each:
 *   a = the warped frame (rounded to 8 bits), b = 255 - a,
 * against the key's painting s and its complement 255 - s
 * (ts_guide_complement). Where visible, |s - a| + |(255 - s) - b| =
 * 2 |s - a|: the single guide at full weight. Where occluded, a = b = 0
 * and the pair adds s + (255 - s) = 255 to every candidate alike, so the
 * choice of match is exactly that without the guide there, on every
 * search mode and backend. warped and a, b: npx pixels of ch interleaved
 * channels; occluded: 1 per occluded pixel. */
void ts_guide_temporal_pair(const float *warped, const uint8_t *occluded, size_t npx, int ch, uint8_t *a,
                            uint8_t *b);
/* out[i] = 255 - in[i]. */
void ts_guide_complement(const uint8_t *in, size_t n, uint8_t *out);

#endif
