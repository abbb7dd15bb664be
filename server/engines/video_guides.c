/* video_guides.c - see video_guides.h. */
#include "video_guides.h"

#include <stddef.h>
#include <stdlib.h>

#include "error.h"
#include "flow.h"
#include "plane.h"

/* The position and temporal weights' floor is twice the others': each
 * of their two guides gets half, and a guide's weight is at least 0.01. */
const ts_param ts_video_params[] = {
    {"edge_weight", "edge-weight", "W", TS_PARAM_DOUBLE, offsetof(ts_video_weights, edge), 0.01, 100, "0.5",
     "the edge guide's weight", .flags = TS_PARAM_ZERO_OFF},
    {"position_weight", "position-weight", "W", TS_PARAM_DOUBLE, offsetof(ts_video_weights, position), 0.02, 100,
     "1", "the positional guide's weight, split between its x and y planes", .flags = TS_PARAM_ZERO_OFF},
    {"temporal_weight", "temporal-weight", "W", TS_PARAM_DOUBLE, offsetof(ts_video_weights, temporal), 0.02, 100,
     "1", "the temporal guide's weight, split between it and its complement", .flags = TS_PARAM_ZERO_OFF},
    {"mask_weight", "mask-weight", "W", TS_PARAM_DOUBLE, offsetof(ts_video_weights, mask), 0.01, 100, "1",
     "with --mask, the mask's weight as a guide, which keeps the inside's patches from the key's inside",
     .flags = TS_PARAM_ZERO_OFF},
    {0}};

const ts_param_default ts_video_defaults[] = {{"budget", "0.1"}, {0}};

/* Sobel magnitude at (x, y): |gx| + |gy| <= 2 * 4 * 255, scaled by 1/8
 * (rounded) to 0..255. */
static int sobel(const uint8_t *p, int w, int h, int x, int y) {
  int xm = ts_plane_mirror(x - 1, w), xp = ts_plane_mirror(x + 1, w), ym = ts_plane_mirror(y - 1, h), yp = ts_plane_mirror(y + 1, h);
  const uint8_t *r0 = p + (size_t)ym * w, *r1 = p + (size_t)y * w, *r2 = p + (size_t)yp * w;
  int gx = (r0[xp] + 2 * r1[xp] + r2[xp]) - (r0[xm] + 2 * r1[xm] + r2[xm]);
  int gy = (r2[xm] + 2 * r2[x] + r2[xp]) - (r0[xm] + 2 * r0[x] + r0[xp]);
  return ((gx < 0 ? -gx : gx) + (gy < 0 ? -gy : gy) + 4) / 8;
}

/* One pass of the binomial kernel along x (dx = 1) or y (dx = 0), in
 * 16ths, rounded. */
static void binomial(const uint8_t *in, int w, int h, int along_x, uint8_t *out) {
  static const int k[5] = {1, 4, 6, 4, 1};
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      int sum = 0;
      for (int t = -2; t <= 2; t++)
        sum += k[t + 2] * (along_x ? in[(size_t)y * w + ts_plane_mirror(x + t, w)] : in[(size_t)ts_plane_mirror(y + t, h) * w + x]);
      out[(size_t)y * w + x] = (uint8_t)((sum + 8) / 16);
    }
}

int ts_guide_edges(const uint8_t *luma, int w, int h, uint8_t *out) {
  uint8_t *mag = malloc((size_t)w * h), *tmp = malloc((size_t)w * h);
  if (mag == NULL || tmp == NULL) {
    free(mag);
    free(tmp);
    return TS_ENOMEM;
  }
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) mag[(size_t)y * w + x] = (uint8_t)sobel(luma, w, h, x, y);
  binomial(mag, w, h, 1, tmp);
  binomial(tmp, w, h, 0, out);
  free(mag);
  free(tmp);
  return 0;
}

/* Pixel (x, y) at its own coordinates, as in the key. */
static void own_place(float *pos, int w, int x, int y) {
  pos[2 * ((size_t)y * w + x)] = (float)x;
  pos[2 * ((size_t)y * w + x) + 1] = (float)y;
}

void ts_guide_position_key(int w, int h, float *pos) {
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) own_place(pos, w, x, y);
}

void ts_guide_position_advect(const float *prev, const float *back, const uint8_t *occluded, int w, int h,
                              float *pos) {
  ts_flow_warp(prev, w, h, 2, back, pos);
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++)
      if (occluded[(size_t)y * w + x]) own_place(pos, w, x, y);
}

/* v in 0..n-1 to 0..255, rounded and clamped. */
static uint8_t scale8(float v, int n) {
  float s = n > 1 ? v * 255.0f / (float)(n - 1) : 0.0f;
  return s <= 0.0f ? 0 : s >= 255.0f ? 255 : (uint8_t)(s + 0.5f);
}

void ts_guide_position_planes(const float *pos, int w, int h, uint8_t *px, uint8_t *py) {
  for (size_t i = 0; i < (size_t)w * h; i++) {
    px[i] = scale8(pos[2 * i], w);
    py[i] = scale8(pos[2 * i + 1], h);
  }
}

static uint8_t round8(float v) { return v <= 0.0f ? 0 : v >= 255.0f ? 255 : (uint8_t)(v + 0.5f); }

void ts_guide_temporal_pair(const float *warped, const uint8_t *occluded, size_t npx, int ch, uint8_t *a,
                            uint8_t *b) {
  for (size_t i = 0; i < npx; i++)
    for (int k = 0; k < ch; k++) {
      size_t j = i * (size_t)ch + (size_t)k;
      uint8_t v = round8(warped[j]);
      a[j] = occluded[i] ? 0 : v;
      b[j] = occluded[i] ? 0 : (uint8_t)(255 - v);
    }
}

void ts_guide_complement(const uint8_t *in, size_t n, uint8_t *out) {
  for (size_t i = 0; i < n; i++) out[i] = (uint8_t)(255 - in[i]);
}
