/* preview.c - see preview.h. */
#include "preview.h"

#include <stdio.h>
#include <stdlib.h>

#include "error.h"
#include "image.h"

struct ts_preview {
  int w, h, ch;  /* the image's */
  int pw, ph;    /* the preview's */
  uint64_t *sum; /* per cell and channel */
  uint32_t *n;   /* pixels added per cell */
  uint8_t *rgba; /* the picture written: ch channels and alpha */
  char path[4096];
};

/* The preview's side for an image side s whose long side is l: scaled to
 * TS_PREVIEW_SIDE, at least 1, never enlarged. */
static int side_of(int s, int l) {
  if (l <= TS_PREVIEW_SIDE) return s;
  int v = (int)((int64_t)s * TS_PREVIEW_SIDE / l);
  return v > 0 ? v : 1;
}

int ts_preview_open(ts_preview **out, const char *path, int w, int h, int channels, char *err) {
  *out = NULL;
  if (w < 1 || h < 1 || channels < 1 || channels > 3)
    return ts_error(err, TS_EINVAL, "a preview of %dx%d pixels of %d channels: need 1..3 channels", w, h, channels);
  ts_preview *p = calloc(1, sizeof(*p));
  if (p == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  int l = w > h ? w : h;
  *p = (ts_preview){.w = w, .h = h, .ch = channels, .pw = side_of(w, l), .ph = side_of(h, l)};
  size_t cells = (size_t)p->pw * (size_t)p->ph;
  p->sum = calloc(cells * (size_t)channels, sizeof(uint64_t));
  p->n = calloc(cells, sizeof(uint32_t));
  p->rgba = calloc(cells, (size_t)channels + 1);
  if (p->sum == NULL || p->n == NULL || p->rgba == NULL) {
    ts_preview_close(p);
    return ts_error(err, TS_ENOMEM, "out of memory");
  }
  snprintf(p->path, sizeof(p->path), "%s", path);
  *out = p;
  return 0;
}

/* The cells of rows [y0, y1) of the preview from their sums. */
static void cells_update(ts_preview *p, int cy0, int cy1) {
  int ch = p->ch;
  for (int cy = cy0; cy < cy1; cy++)
    for (int cx = 0; cx < p->pw; cx++) {
      size_t c = (size_t)cy * (size_t)p->pw + (size_t)cx;
      uint8_t *o = p->rgba + c * (size_t)(ch + 1);
      if (p->n[c] == 0) continue;
      for (int k = 0; k < ch; k++) o[k] = (uint8_t)((p->sum[c * (size_t)ch + (size_t)k] + p->n[c] / 2) / p->n[c]);
      o[ch] = 255;
    }
}

int ts_preview_rows(ts_preview *p, int y0, int rows, const uint8_t *px, char *err) {
  int ch = p->ch;
  if (rows < 1 || y0 < 0 || y0 + rows > p->h)
    return ts_error(err, TS_EINVAL, "preview rows %d..%d of an image of %d rows", y0, y0 + rows - 1, p->h);
  for (int y = 0; y < rows; y++) {
    size_t cy = (size_t)((int64_t)(y0 + y) * p->ph / p->h);
    for (int x = 0; x < p->w; x++) {
      size_t c = cy * (size_t)p->pw + (size_t)((int64_t)x * p->pw / p->w);
      const uint8_t *s = px + ((size_t)y * (size_t)p->w + (size_t)x) * (size_t)ch;
      for (int k = 0; k < ch; k++) p->sum[c * (size_t)ch + (size_t)k] += s[k];
      p->n[c]++;
    }
  }
  int cy0 = (int)((int64_t)y0 * p->ph / p->h), cy1 = (int)((int64_t)(y0 + rows - 1) * p->ph / p->h) + 1;
  cells_update(p, cy0, cy1);
  ts_image img = {p->pw, p->ph, ch + 1, TS_PIX_U8, p->rgba, NULL};
  return ts_image_write(p->path, &img, NULL, err);
}

void ts_preview_close(ts_preview *p) {
  if (p == NULL) return;
  free(p->sum);
  free(p->n);
  free(p->rgba);
  free(p);
}
