/* thumb.h - small PNG previews of finished jobs' results for the
 * operations page (http.c). */
#ifndef TS_THUMB_H
#define TS_THUMB_H

#include <stddef.h>
#include <stdint.h>

#include "image.h"
#include "jobs.h"

/* The sizes served, pixels on the long side at most, each kept in the
 * job's spool directory under the name it is served by (/jobs/ID/NAME):
 * thumb.png for a look at one result, small.png for the operations
 * page's strips of video frames, a few KB each however many frames. */
#define TS_THUMB_SIDE 160
#define TS_THUMB_SMALL_SIDE 64

/* A box-filtered copy of src, 8-bit, with src's channels (the first four
 * of more, as PNG holds no more), whose long side is
 * max_side (or src's own when smaller: never enlarged), the aspect ratio
 * kept (each side at least 1 pixel). 0, TS_EINVAL or TS_ENOMEM. */
int ts_thumb_scale(const ts_image *src, int max_side, ts_image *dst, char *err);

/* The PNG bytes (malloc'ed into *png) of job id's thumbnail of long side
 * `side`: the file `name` in the job's spool directory, made from its
 * result image (out.EXT), or from its preview when it has one
 * (preview.h: a tiled scene's), the first time it is asked for, then
 * served from there. A running job's preview is scaled afresh at every
 * call, and *growing set: the picture may change. TS_ENOENT when there is
 * no such job or nothing to show, TS_EINVAL when it is neither done nor
 * showing a preview, else the image library's error. */
int ts_thumb_get(ts_jobs *j, uint64_t id, const char *name, int side, uint8_t **png, size_t *len, int *growing,
                 char *err);

#endif
