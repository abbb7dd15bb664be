/* video_preview.h - `texsyn video --preview OUT.gif`: the output frames
 * once more as one looping animated GIF, to look at the motion (at most
 * 256 colours a frame, OpenImageIO's GIF writer: a preview, not a copy).
 * GIF keeps a frame's delay in hundredths of a second, so 24 fps plays as
 * 25. The frames are held in memory while it is written. */
#ifndef TS_VIDEO_PREVIEW_H
#define TS_VIDEO_PREVIEW_H

#include "video_chain.h"

/* The output frames v->out A..B as the GIF `path` at fps frames a second:
 * 8-bit RGB, or RGBA for outputs with alpha, a grey output's grey in the
 * three colours. */
int ts_video_preview(const ts_video *v, const char *path, double fps, char *err);

#endif
