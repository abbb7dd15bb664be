/* segment_post.c - what a segmentation does with the levels' class maps
 * once the search has made them (segment.h): the level weights from the
 * self-segmentation counts, the weighted vote across levels, the noise
 * reduction and the accuracy counts. Plain arrays in, arrays out, so the
 * unit tests drive them on small synthetic maps. */
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "segment_post.h"

void ts_seg_weights(int levels, int nclass, const uint64_t *correct, const uint64_t *total, double *rate,
                    double *weight) {
  for (int k = 0; k < nclass; k++) {
    double sum = 0;
    for (int l = 0; l < levels; l++) {
      size_t i = (size_t)l * (size_t)nclass + (size_t)k;
      rate[i] = total[i] > 0 ? (double)correct[i] / (double)total[i] : -1.0;
      sum += rate[i] > 0 ? rate[i] : 0.0;
    }
    for (int l = 0; l < levels; l++) {
      size_t i = (size_t)l * (size_t)nclass + (size_t)k;
      weight[i] = sum > 0 ? (rate[i] > 0 ? rate[i] / sum : 0.0) : 1.0 / levels;
    }
  }
}

void ts_seg_fuse(int levels, int nclass, const uint8_t *const *lab, const int *lw, const int *lh, const double *weight,
                 int w, int h, uint8_t *out) {
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      /* The classes the levels vote for, and the sum of their weights. */
      uint8_t cls[TS_SEG_MAX_LEVELS];
      double score[TS_SEG_MAX_LEVELS];
      int n = 0;
      for (int l = 0; l < levels; l++) {
        uint8_t k = lab[l][(size_t)ts_seg_nearest(y, l, lh[l]) * (size_t)lw[l] + (size_t)ts_seg_nearest(x, l, lw[l])];
        int j = 0;
        while (j < n && cls[j] != k) j++;
        if (j == n) {
          cls[n] = k;
          score[n++] = 0;
        }
        score[j] += weight[(size_t)l * (size_t)nclass + k];
      }
      int best = 0;
      for (int j = 1; j < n; j++)
        if (score[j] > score[best] || (score[j] == score[best] && cls[j] < cls[best])) best = j;
      out[(size_t)y * (size_t)w + (size_t)x] = cls[best];
    }
}

void ts_seg_upsample(const uint8_t *lab, int lw, int lh, int l, int w, int h, uint8_t *out) {
  for (int y = 0; y < h; y++) {
    const uint8_t *row = lab + (size_t)ts_seg_nearest(y, l, lh) * (size_t)lw;
    for (int x = 0; x < w; x++) out[(size_t)y * (size_t)w + (size_t)x] = row[ts_seg_nearest(x, l, lw)];
  }
}

void ts_seg_count(const uint8_t *pred, const uint8_t *truth, size_t n, uint64_t *pixels, uint64_t *correct) {
  for (size_t i = 0; i < n; i++) {
    pixels[truth[i]]++;
    correct[truth[i]] += pred[i] == truth[i];
  }
}

/* ---- regions ------------------------------------------------------------- */

#define UNSEEN UINT32_MAX

/* Fills the region of pixel `seed` with id, depth first on an explicit
 * stack (room for every pixel: each is pushed once). */
static void flood(const uint8_t *lab, int w, int h, uint32_t seed, uint32_t id, uint32_t *comp, uint32_t *stack) {
  size_t top = 0;
  uint8_t k = lab[seed];
  comp[seed] = id;
  stack[top++] = seed;
  while (top > 0) {
    uint32_t i = stack[--top];
    int x = (int)(i % (uint32_t)w), y = (int)(i / (uint32_t)w);
    uint32_t next[4];
    int nn = 0;
    if (x > 0) next[nn++] = i - 1;
    if (x + 1 < w) next[nn++] = i + 1;
    if (y > 0) next[nn++] = i - (uint32_t)w;
    if (y + 1 < h) next[nn++] = i + (uint32_t)w;
    for (int j = 0; j < nn; j++)
      if (comp[next[j]] == UNSEEN && lab[next[j]] == k) {
        comp[next[j]] = id;
        stack[top++] = next[j];
      }
  }
}

int ts_seg_components(const uint8_t *lab, int w, int h, uint32_t *comp, uint32_t *n) {
  size_t np = (size_t)w * (size_t)h;
  uint32_t *stack = malloc(np * sizeof(*stack));
  if (stack == NULL) return TS_ENOMEM;
  for (size_t i = 0; i < np; i++) comp[i] = UNSEEN;
  uint32_t id = 0;
  for (size_t i = 0; i < np; i++)
    if (comp[i] == UNSEEN) flood(lab, w, h, (uint32_t)i, id++, comp, stack);
  *n = id;
  free(stack);
  return 0;
}

/* ---- noise reduction ----------------------------------------------------- */

typedef struct {
  uint8_t *lab;
  int w, h;
  uint32_t *comp, ncomp;
  uint32_t *size, *start, *pixels; /* per region its size and its pixels at pixels[start..] */
  uint64_t *order;                 /* the small regions, smallest first (by_key) */
  uint8_t *touched;                /* regions next to one changed in this pass */
} denoiser;

/* The regions' sizes and pixel lists (counting sort by region). */
static void index_regions(denoiser *d) {
  size_t np = (size_t)d->w * (size_t)d->h;
  memset(d->size, 0, sizeof(*d->size) * d->ncomp);
  for (size_t i = 0; i < np; i++) d->size[d->comp[i]]++;
  uint32_t at = 0;
  for (uint32_t c = 0; c < d->ncomp; c++) {
    d->start[c] = at;
    at += d->size[c];
  }
  for (size_t i = 0; i < np; i++) d->pixels[d->start[d->comp[i]]++] = (uint32_t)i;
  for (uint32_t c = 0; c < d->ncomp; c++) d->start[c] -= d->size[c];
}

/* Small regions are sorted as size << 32 | region: smallest first, ties
 * to the first in raster order. */
static int by_key(const void *a, const void *b) {
  uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
  return x < y ? -1 : x > y;
}

/* The class region c's border touches most (edges counted, ties to the
 * lower class), or -1 when it has no border; marks its neighbours. */
static int border_class(denoiser *d, uint32_t c) {
  uint32_t count[TS_SEG_MAX_CLASSES] = {0};
  int any = 0;
  for (uint32_t j = 0; j < d->size[c]; j++) {
    uint32_t i = d->pixels[d->start[c] + j];
    int x = (int)(i % (uint32_t)d->w), y = (int)(i / (uint32_t)d->w);
    uint32_t next[4];
    int nn = 0;
    if (x > 0) next[nn++] = i - 1;
    if (x + 1 < d->w) next[nn++] = i + 1;
    if (y > 0) next[nn++] = i - (uint32_t)d->w;
    if (y + 1 < d->h) next[nn++] = i + (uint32_t)d->w;
    for (int q = 0; q < nn; q++) {
      if (d->comp[next[q]] == c) continue;
      count[d->lab[next[q]]]++;
      d->touched[d->comp[next[q]]] = 1;
      any = 1;
    }
  }
  if (!any) return -1;
  int best = 0;
  for (int k = 1; k < TS_SEG_MAX_CLASSES; k++)
    if (count[k] > count[best]) best = k;
  return best;
}

/* One pass; returns the regions it changed. */
static uint32_t denoise_pass(denoiser *d, uint32_t min_area) {
  index_regions(d);
  uint32_t nsmall = 0;
  for (uint32_t c = 0; c < d->ncomp; c++)
    if (d->size[c] < min_area) d->order[nsmall++] = (uint64_t)d->size[c] << 32 | c;
  qsort(d->order, nsmall, sizeof(*d->order), by_key);
  memset(d->touched, 0, d->ncomp);
  uint32_t changed = 0;
  for (uint32_t s = 0; s < nsmall; s++) {
    uint32_t c = (uint32_t)d->order[s];
    if (d->touched[c]) continue;
    int k = border_class(d, c);
    if (k < 0) continue;
    for (uint32_t j = 0; j < d->size[c]; j++) d->lab[d->pixels[d->start[c] + j]] = (uint8_t)k;
    changed++;
  }
  return changed;
}

int ts_seg_denoise(uint8_t *lab, int w, int h, uint32_t min_area, ts_seg_denoise_stats *st) {
  memset(st, 0, sizeof(*st));
  if (min_area <= 1) return 0;
  size_t np = (size_t)w * (size_t)h;
  denoiser d = {lab, w, h, NULL, 0, NULL, NULL, NULL, NULL, NULL};
  d.comp = malloc(np * sizeof(uint32_t));
  d.size = malloc(np * sizeof(uint32_t));
  d.start = malloc(np * sizeof(uint32_t));
  d.pixels = malloc(np * sizeof(uint32_t));
  d.order = malloc(np * sizeof(uint64_t));
  d.touched = malloc(np);
  int rc = d.comp && d.size && d.start && d.pixels && d.order && d.touched ? 0 : TS_ENOMEM;
  for (;;) {
    if (rc == 0) rc = ts_seg_components(lab, w, h, d.comp, &d.ncomp);
    if (rc != 0) break;
    uint32_t changed = denoise_pass(&d, min_area);
    if (changed == 0) break;
    st->merged += changed;
    st->passes++;
  }
  free(d.comp);
  free(d.size);
  free(d.start);
  free(d.pixels);
  free(d.order);
  free(d.touched);
  return rc;
}
