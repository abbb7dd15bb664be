/* resample.c - see resample.h. Separable: rows first, then columns, each
 * output sample the overlap-weighted mean of the input samples under it. */
#include "resample.h"

#include <math.h>
#include <stdlib.h>

#include "error.h"

/* The weights of one axis: output i covers input [i * n / m, (i+1) * n / m). */
typedef struct {
  int *first, *count; /* per output: first input index, how many */
  double *w;          /* per output, count weights from offset[i] */
  int *offset;
} axis;

static void axis_free(axis *a) {
  free(a->first);
  free(a->count);
  free(a->w);
  free(a->offset);
}

static int axis_make(axis *a, int n, int m) {
  a->first = malloc(sizeof(int) * (size_t)m);
  a->count = malloc(sizeof(int) * (size_t)m);
  a->offset = malloc(sizeof(int) * (size_t)m);
  a->w = malloc(sizeof(double) * ((size_t)n + 2 * (size_t)m));
  if (!a->first || !a->count || !a->offset || !a->w) return TS_ENOMEM;
  int at = 0;
  for (int i = 0; i < m; i++) {
    double lo = (double)i * n / m, hi = (double)(i + 1) * n / m;
    int k0 = (int)floor(lo), k1 = (int)ceil(hi);
    if (k1 > n) k1 = n;
    a->first[i] = k0;
    a->count[i] = k1 - k0;
    a->offset[i] = at;
    for (int k = k0; k < k1; k++) {
      double l = k > lo ? k : lo, r = k + 1 < hi ? k + 1 : hi;
      a->w[at++] = (r - l) / (hi - lo);
    }
  }
  return 0;
}

static void store(ts_image *out, size_t i, double v) {
  switch (out->type) {
  case TS_PIX_U8: ((uint8_t *)out->pixels)[i] = (uint8_t)lrint(fmin(fmax(v, 0), 1) * 255.0); break;
  case TS_PIX_U16: ((uint16_t *)out->pixels)[i] = (uint16_t)lrint(fmin(fmax(v, 0), 1) * 65535.0); break;
  default: ((float *)out->pixels)[i] = (float)v; break;
  }
}

int ts_image_resample(const ts_image *in, int w, int h, ts_image *out, char *err) {
  if (w < 1 || h < 1) return ts_error(err, TS_EINVAL, "cannot resample to %dx%d", w, h);
  int c = in->channels;
  ts_pixtype type = in->type == TS_PIX_U8 || in->type == TS_PIX_U16 ? in->type : TS_PIX_F32;
  axis ax = {0}, ay = {0};
  double *rows = malloc(sizeof(double) * (size_t)w * (size_t)in->height * (size_t)c);
  int rc = rows == NULL ? TS_ENOMEM : axis_make(&ax, in->width, w);
  if (rc == 0) rc = axis_make(&ay, in->height, h);
  if (rc == 0) rc = ts_image_alloc(out, w, h, c, type, err);
  else ts_error(err, rc, "out of memory resampling %dx%d to %dx%d", in->width, in->height, w, h);
  for (int y = 0; rc == 0 && y < in->height; y++)
    for (int x = 0; x < w; x++)
      for (int ch = 0; ch < c; ch++) {
        double s = 0;
        for (int k = 0; k < ax.count[x]; k++) s += ax.w[ax.offset[x] + k] * ts_image_sample(in, ax.first[x] + k, y, ch);
        rows[((size_t)y * w + x) * c + ch] = s;
      }
  for (int y = 0; rc == 0 && y < h; y++)
    for (int x = 0; x < w; x++)
      for (int ch = 0; ch < c; ch++) {
        double s = 0;
        for (int k = 0; k < ay.count[y]; k++)
          s += ay.w[ay.offset[y] + k] * rows[((size_t)(ay.first[y] + k) * w + x) * c + ch];
        store(out, ((size_t)y * w + x) * c + ch, s);
      }
  axis_free(&ax);
  axis_free(&ay);
  free(rows);
  return rc;
}
