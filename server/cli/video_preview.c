/* video_preview.c - see video_preview.h. */
#include "video_preview.h"

#include <stdlib.h>

#include "error.h"
#include "image.h"

/* Output frame t as 8-bit RGB (grey repeated) or RGBA into px; own holds
 * the frame in the output's channels. */
static int preview_frame(const ts_video *v, long t, uint8_t *px, uint8_t *own, char *err) {
  char path[TS_VIDEO_PATH];
  ts_frame_path(v->out, t, path, sizeof(path)); /* fits: checked */
  int rc = ts_video_read8(v, path, own, err);
  int c = v->channels, pc = c == 2 || c == 4 ? 4 : 3;
  for (size_t i = 0; rc == 0 && i < (size_t)v->w * v->h; i++)
    for (int k = 0; k < pc; k++) {
      int from = c <= 2 ? (k < 3 ? 0 : 1) : k; /* grey: its grey thrice, then its alpha */
      px[i * pc + k] = own[i * c + (from < c ? from : c - 1)];
    }
  return rc;
}

int ts_video_preview(const ts_video *v, const char *path, double fps, char *err) {
  int n = (int)(v->fr.last - v->fr.first + 1), pc = v->channels == 2 || v->channels == 4 ? 4 : 3;
  size_t px = (size_t)v->w * v->h;
  ts_image *frames = calloc((size_t)n, sizeof(*frames));
  uint8_t *own = malloc(px * v->channels);
  int rc = frames != NULL && own != NULL ? 0 : ts_error(err, TS_ENOMEM, "out of memory");
  for (int k = 0; rc == 0 && k < n; k++) {
    frames[k] = (ts_image){v->w, v->h, pc, TS_PIX_U8, malloc(px * pc), NULL};
    rc = frames[k].pixels != NULL ? preview_frame(v, v->fr.first + k, frames[k].pixels, own, err)
                                  : ts_error(err, TS_ENOMEM, "out of memory for the preview");
  }
  if (rc == 0) rc = ts_image_write_animation(path, frames, n, fps, err);
  for (int k = 0; frames != NULL && k < n; k++) free(frames[k].pixels);
  free(frames);
  free(own);
  return rc;
}
