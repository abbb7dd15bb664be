/* video_mask.c - see video_mask.h. */
#include "video_mask.h"

#include <stdio.h>
#include <stdlib.h>

#include "error.h"
#include "image.h"

void ts_video_mask_file(const char *dir, long t, char *out, size_t cap) {
  snprintf(out, cap, "%s/mask_%04ld.png", dir, t);
}

int ts_video_mask_prepare(const ts_video *v, const char *dir, char *err) {
  uint8_t *m = malloc((size_t)v->w * v->h);
  int rc = m != NULL ? 0 : ts_error(err, TS_ENOMEM, "out of memory");
  ts_image_limits limits = {v->job.max_pixels, NULL};
  for (long t = v->fr.first; rc == 0 && t <= v->fr.last; t++) {
    char path[TS_VIDEO_PATH];
    ts_image img = {0};
    ts_frame_path(v->mask, t, path, sizeof(path)); /* fits: checked */
    rc = ts_image_read(path, &img, &limits, err);
    if (rc == 0) ts_image_luma8(&img, m);
    ts_image_free(&img);
    ts_image plane = {v->w, v->h, 1, TS_PIX_U8, m, NULL};
    ts_video_mask_file(dir, t, path, sizeof(path));
    if (rc == 0) rc = ts_image_write(path, &plane, NULL, err);
  }
  free(m);
  return rc;
}

/* Input frame t in the output's v->channels 8-bit channels: channel k of
 * the frame's own where it has it; a grey frame's grey in the colour
 * channels; 255 (opaque) for an alpha the frame lacks; the luminance for
 * a one-channel output of a colour frame. */
static int input_frame(const ts_video *v, long t, uint8_t *px, uint8_t *plane, char *err) {
  char path[TS_VIDEO_PATH];
  ts_image img = {0};
  ts_image_limits limits = {v->job.max_pixels, NULL};
  ts_frame_path(v->input, t, path, sizeof(path)); /* fits: checked */
  int rc = ts_image_read(path, &img, &limits, err);
  size_t n = (size_t)v->w * v->h;
  int grey = img.channels <= 2, colours = v->channels >= 3 ? 3 : 1;
  for (int k = 0; rc == 0 && k < v->channels; k++) {
    if (k == 0 && (v->channels == 1 || (v->channels == 2 && !grey))) ts_image_luma8(&img, plane);
    else if (k < img.channels && !(grey && k > 0)) ts_image_channel8(&img, k, plane);
    else if (grey && k < colours) ts_image_channel8(&img, 0, plane);
    else if (grey && k == colours && img.channels == 2) ts_image_channel8(&img, 1, plane);
    else for (size_t i = 0; i < n; i++) plane[i] = 255;
    for (size_t i = 0; i < n; i++) px[i * v->channels + k] = plane[i];
  }
  ts_image_free(&img);
  return rc;
}

static int read_mask(const ts_video *v, const char *dir, long t, uint8_t *m, char *err) {
  char path[TS_VIDEO_PATH];
  ts_image img = {0};
  ts_image_limits limits = {v->job.max_pixels, NULL};
  ts_video_mask_file(dir, t, path, sizeof(path));
  int rc = ts_image_read(path, &img, &limits, err);
  if (rc == 0) ts_image_channel8(&img, 0, m);
  ts_image_free(&img);
  return rc;
}

int ts_video_mask_write(const ts_video *v, const char *dir, const char *stylized, char *err) {
  size_t n = (size_t)v->w * v->h, ns = n * v->channels;
  uint8_t *s = malloc(ns), *in = malloc(ns), *m = malloc(n), *plane = malloc(n);
  int rc = s && in && m && plane ? 0 : ts_error(err, TS_ENOMEM, "out of memory");
  char path[TS_VIDEO_PATH];
  for (long t = v->fr.first; rc == 0 && t <= v->fr.last; t++) {
    ts_frame_path(stylized, t, path, sizeof(path));
    rc = ts_video_read8(v, path, s, err);
    if (rc == 0) rc = input_frame(v, t, in, plane, err);
    if (rc == 0) rc = read_mask(v, dir, t, m, err);
    for (size_t i = 0; rc == 0 && i < ns; i++) {
      unsigned a = m[i / v->channels];
      s[i] = (uint8_t)((s[i] * a + in[i] * (255 - a) + 127) / 255);
    }
    ts_image img = {v->w, v->h, v->channels, TS_PIX_U8, s, NULL};
    ts_frame_path(v->out, t, path, sizeof(path)); /* fits: checked */
    if (rc == 0) rc = ts_image_write(path, &img, NULL, err);
  }
  free(s);
  free(in);
  free(m);
  free(plane);
  return rc;
}
