/* flow.c - warping along a flow and the forward-backward occlusion check
 * (flow.h); plain C, no OpenCV: these run on every frame of every
 * sequence and must give the same bytes everywhere, which plain float
 * arithmetic compiled without FMA contraction (-std=c11) does. */
#include "flow.h"

#include <math.h>

/* Bilinear sample of `channels` interleaved floats at (x, y), the position
 * clamped to the image, into out. */
static void sample(const float *img, int w, int h, int channels, float x, float y, float *out) {
  x = fminf(fmaxf(x, 0.0f), (float)(w - 1));
  y = fminf(fmaxf(y, 0.0f), (float)(h - 1));
  int x0 = (int)x, y0 = (int)y;
  int x1 = x0 + (x0 < w - 1), y1 = y0 + (y0 < h - 1);
  float ax = x - (float)x0, ay = y - (float)y0;
  const float *p00 = img + ((size_t)y0 * w + x0) * channels, *p01 = img + ((size_t)y0 * w + x1) * channels;
  const float *p10 = img + ((size_t)y1 * w + x0) * channels, *p11 = img + ((size_t)y1 * w + x1) * channels;
  for (int c = 0; c < channels; c++) {
    float top = p00[c] + ax * (p01[c] - p00[c]);
    float bottom = p10[c] + ax * (p11[c] - p10[c]);
    out[c] = top + ay * (bottom - top);
  }
}

void ts_flow_warp(const float *src, int w, int h, int channels, const float *uv, float *dst) {
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      size_t i = (size_t)y * w + x;
      sample(src, w, h, channels, (float)x + uv[2 * i], (float)y + uv[2 * i + 1], dst + i * channels);
    }
}

size_t ts_flow_occlusion(const float *f, const float *b, int w, int h, uint8_t *occluded) {
  size_t n = 0;
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      size_t i = (size_t)y * w + x;
      float fu = f[2 * i], fv = f[2 * i + 1];
      float tx = (float)x + fu, ty = (float)y + fv;
      int out = !(tx >= 0.0f && ty >= 0.0f && tx <= (float)(w - 1) && ty <= (float)(h - 1));
      if (!out) {
        float bb[2];
        sample(b, w, h, 2, tx, ty, bb);
        float du = fu + bb[0], dv = fv + bb[1];
        out = du * du + dv * dv > 0.01f * (fu * fu + fv * fv + bb[0] * bb[0] + bb[1] * bb[1]) + 0.5f;
      }
      occluded[i] = (uint8_t)out;
      n += (size_t)out;
    }
  return n;
}

/* Adds weight wt of the motion (u, v) to B's pixel (x, y) if it is in B. */
static void splat(float *inv, float *weight, int w, int h, int x, int y, float wt, float u, float v) {
  if (x < 0 || y < 0 || x >= w || y >= h || wt <= 0.0f) return;
  size_t i = (size_t)y * w + x;
  inv[2 * i] += wt * u;
  inv[2 * i + 1] += wt * v;
  weight[i] += wt;
}

void ts_flow_invert(const float *f, int w, int h, float *weight, float *inv) {
  for (size_t i = 0; i < (size_t)w * h; i++) inv[2 * i] = inv[2 * i + 1] = weight[i] = 0.0f;
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      size_t i = (size_t)y * w + x;
      float u = f[2 * i], v = f[2 * i + 1], tx = (float)x + u, ty = (float)y + v;
      if (!(tx >= 0.0f && ty >= 0.0f && tx <= (float)(w - 1) && ty <= (float)(h - 1))) continue;
      int x0 = (int)tx, y0 = (int)ty;
      float ax = tx - (float)x0, ay = ty - (float)y0;
      splat(inv, weight, w, h, x0, y0, (1.0f - ax) * (1.0f - ay), -u, -v);
      splat(inv, weight, w, h, x0 + 1, y0, ax * (1.0f - ay), -u, -v);
      splat(inv, weight, w, h, x0, y0 + 1, (1.0f - ax) * ay, -u, -v);
      splat(inv, weight, w, h, x0 + 1, y0 + 1, ax * ay, -u, -v);
    }
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      size_t i = (size_t)y * w + x;
      if (weight[i] > TS_FLOW_HOLE) {
        inv[2 * i] /= weight[i];
        inv[2 * i + 1] /= weight[i];
      } else {
        inv[2 * i] = -(float)(x + w); /* lands at -w: out of the frame */
        inv[2 * i + 1] = 0.0f;
      }
    }
}
