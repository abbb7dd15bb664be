/* video_mask.h - `texsyn video --mask PATTERN`: only the inside of a mask
 * is stylized, the outside is the input frame.
 *
 * The whole frame is stylized as without a mask, with the mask as one more
 * guide pair (the mask at the key's frame / at frame t, weight
 * --mask-weight), so patches of the inside come from the key's inside and
 * the stylized inside does not take the outside's style along. The
 * sequence is then composited per sample, rounded,
 *   out = (S * m + I * (255 - m) + 127) / 255,
 * S the stylized (blended) frame, I the input frame in the output's
 * channels, m the mask (255 inside: white = stylize, 0 outside: black =
 * keep): where the mask is black the output is the input frame's bytes,
 * where white the stylized ones, a soft edge blends. Integer arithmetic:
 * the same bytes everywhere. */
#ifndef TS_VIDEO_MASK_H
#define TS_VIDEO_MASK_H

#include "video_chain.h"

/* The work directory's 8-bit mask of frame t (the guide, and what the
 * composite uses). */
void ts_video_mask_file(const char *dir, long t, char *out, size_t cap);

/* Writes every frame's mask to dir as one 8-bit plane: a one-channel mask
 * as it is (converted to 8 bits), a grey+alpha one by its grey, a colour
 * one by its luminance (ts_image_luma8). */
int ts_video_mask_prepare(const ts_video *v, const char *dir, char *err);

/* The output frames (v->out) from the stylized ones (pattern `stylized`,
 * lossless, the output's channels), composited over the input frames by
 * the masks in dir. */
int ts_video_mask_write(const ts_video *v, const char *dir, const char *stylized, char *err);

#endif
