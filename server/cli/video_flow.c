/* video_flow.c - see video_flow.h. */
#include "video_flow.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "error.h"
#include "flow.h"
#include "image.h"
#include "util.h"

static int check_one(const ts_video *v, const char *option, const char *pattern, long t, char *err) {
  char path[TS_VIDEO_PATH];
  if (ts_frame_path(pattern, t, path, sizeof(path)) != 0) return ts_error(err, TS_EINVAL, "%s: path too long", pattern);
  uint8_t *buf = NULL;
  size_t len = 0;
  ts_image_info info;
  ts_image_limits limits = {v->job.max_pixels, NULL};
  int rc = ts_file_read(path, 1ull << 32, &buf, &len, err);
  if (rc == 0) rc = ts_image_probe_mem(path, buf, len, &limits, &info, err);
  free(buf);
  if (rc != 0) {
    char why[TS_ERR_LEN];
    snprintf(why, sizeof(why), "%s", err);
    return ts_error(err, rc, "%s frame %ld: %s (nothing was stylized)", option, t, why);
  }
  if (info.width != v->w || info.height != v->h)
    return ts_error(err, TS_EINVAL, "%s frame %ld (%s) is %dx%d, the frames %dx%d: a flow has the frames' size",
                    option, t, path, info.width, info.height, v->w, v->h);
  if (info.channels < 2)
    return ts_error(err, TS_EINVAL, "%s frame %ld (%s) has %d channel: a flow needs two (x, y; any more are "
                    "not used)", option, t, path, info.channels);
  if (info.type != TS_PIX_F16 && info.type != TS_PIX_F32)
    return ts_error(err, TS_EINVAL, "%s frame %ld (%s) has %s samples: a flow is in pixels, as floats "
                    "(OpenEXR or a float TIFF)", option, t, path, ts_pixtype_name(info.type));
  return 0;
}

int ts_video_flow_check(const ts_video *v, char *err) {
  int rc = 0;
  const char *const opt[2] = {"--flow", "--flow-back"};
  const char *const pat[2] = {v->flow, v->flow_back};
  for (int d = 0; d < 2 && rc == 0; d++) {
    if (pat[d] == NULL) continue;
    int n = ts_frame_pattern(pat[d], err);
    if (n < 0) return n;
    if (n == 0)
      return ts_error(err, TS_EINVAL, "%s %s: put the frame number in the name (%%d or %%04d, e.g. "
                      "flow/%%04d.exr)", opt[d], pat[d]);
    /* --flow maps t to t+1: A..B-1; --flow-back t to t-1: A+1..B. */
    for (long t = v->fr.first + d; rc == 0 && t <= v->fr.last - 1 + d; t++) rc = check_one(v, opt[d], pat[d], t, err);
  }
  return rc;
}

/* Frame t's flow from pattern into uv: the first two channels, a
 * non-finite value pointing out of the frame, the rest clamped. */
static int read_flow(const ts_video *v, const char *pattern, long t, float *uv, char *err) {
  char path[TS_VIDEO_PATH];
  ts_frame_path(pattern, t, path, sizeof(path)); /* fits: checked */
  ts_image img = {0};
  ts_image_limits limits = {v->job.max_pixels, NULL};
  int rc = ts_image_read(path, &img, &limits, err);
  if (rc == 0 && (img.width != v->w || img.height != v->h || img.channels < 2))
    rc = ts_error(err, TS_EFORMAT, "%s changed since it was checked", path);
  float lim = 2.0f * (float)(v->w > v->h ? v->w : v->h);
  for (int y = 0; rc == 0 && y < v->h; y++)
    for (int x = 0; x < v->w; x++) {
      float *p = uv + 2 * ((size_t)y * v->w + x);
      float u = ts_image_sample(&img, x, y, 0), w = ts_image_sample(&img, x, y, 1);
      if (!isfinite(u) || !isfinite(w)) {
        p[0] = -(float)(x + v->w);
        p[1] = 0.0f;
      } else {
        p[0] = fminf(fmaxf(u, -lim), lim);
        p[1] = fminf(fmaxf(w, -lim), lim);
      }
    }
  ts_image_free(&img);
  return rc;
}

/* The flow from frame `from` to frame `to` = from +- 1, given: read, or
 * the other direction's inverted. */
static int given(const ts_video *v, long from, long to, float *uv, float *scratch, char *err) {
  if (to == from + 1) return read_flow(v, v->flow, from, uv, err);
  if (v->flow_back != NULL) return read_flow(v, v->flow_back, from, uv, err);
  float *f = malloc(sizeof(float) * 2 * (size_t)v->w * v->h);
  if (f == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  int rc = read_flow(v, v->flow, to, f, err); /* to -> from */
  if (rc == 0) ts_flow_invert(f, v->w, v->h, scratch, uv);
  free(f);
  return rc;
}

int ts_video_flows(const ts_video *v, long prev, long t, const uint8_t *luma_prev, const uint8_t *luma_t,
                   float *back, float *fwd, float *scratch, char *err) {
  if (v->flow == NULL) {
    int rc = ts_flow_dis(luma_t, luma_prev, v->w, v->h, back, err);
    return rc == 0 ? ts_flow_dis(luma_prev, luma_t, v->w, v->h, fwd, err) : rc;
  }
  int rc = given(v, t, prev, back, scratch, err);
  return rc == 0 ? given(v, prev, t, fwd, scratch, err) : rc;
}
