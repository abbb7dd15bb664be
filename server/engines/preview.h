/* preview.h - a small picture of a result that grows while the run goes:
 * the operations page's thumbnail of a running job (http/thumb.c).
 *
 * Why its own file beside the result: a tiled scene's result is streamed
 * to a tiled file of up to a gigapixel and more, which no thumbnail can
 * afford to decode while the run writes it (or after: 3 GB for a 32768²
 * scene). The run feeds its finished rows here, top to bottom, as it
 * writes them; each call box-averages them into a picture whose long side
 * is TS_PREVIEW_SIDE and rewrites it as a PNG (atomically: a reader sees
 * the last whole picture). Cells no row has reached yet are transparent.
 * The preview is for looking only: it never changes a result byte, and a
 * failure to write it is the caller's to ignore. */
#ifndef TS_PREVIEW_H
#define TS_PREVIEW_H

#include <stdint.h>

#define TS_PREVIEW_SIDE 256
#define TS_PREVIEW_FILE "preview.png"

typedef struct ts_preview ts_preview;

/* A preview of a w x h image of `channels` 8-bit channels (1..3), written
 * to path. 0, TS_EINVAL or TS_ENOMEM with a message. */
int ts_preview_open(ts_preview **out, const char *path, int w, int h, int channels, char *err);
/* Adds `rows` finished rows from row y0 (w pixels each, interleaved) and
 * rewrites the file. Rows come top to bottom, each once. 0 or the image
 * library's error. */
int ts_preview_rows(ts_preview *p, int y0, int rows, const uint8_t *px, char *err);
void ts_preview_close(ts_preview *p);

#endif
