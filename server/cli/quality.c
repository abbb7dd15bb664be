/* quality.c - see quality.h. */
#include "quality.h"

#include <stdlib.h>

#include "error.h"
#include "neigh.h"
#include "rng.h"

typedef struct {
  int x, y;
} point;

/* Seam windows: centres within `half` of an edge, evenly thinned to max. */
static uint32_t seam_points(const ts_plane *img, int half, uint32_t max, point *out) {
  uint64_t total = 0;
  for (int pass = 0; pass < 2; pass++) {
    uint64_t k = 0;
    uint32_t n = 0;
    for (int y = 0; y < img->h; y++)
      for (int x = 0; x < img->w; x++) {
        int seam = x < half || x >= img->w - half || y < half || y >= img->h - half;
        if (!seam) continue;
        if (pass == 1 && (k * max) / total != ((k + 1) * max) / total && n < max)
          out[n++] = (point){x, y};
        k++;
      }
    if (pass == 0) {
      total = k;
      if (total == 0) return 0;
      if (total < max) max = (uint32_t)total;
    } else {
      return n;
    }
  }
  return 0;
}

static uint32_t inner_points(const ts_plane *img, int half, uint32_t n, uint64_t seed, point *out) {
  if (img->w <= 2 * half || img->h <= 2 * half) return 0;
  ts_rng rng;
  ts_rng_seed(&rng, seed, 0x5eed);
  for (uint32_t i = 0; i < n; i++) {
    out[i].x = half + (int)ts_rng_below(&rng, (uint32_t)(img->w - 2 * half));
    out[i].y = half + (int)ts_rng_below(&rng, (uint32_t)(img->h - 2 * half));
  }
  return n;
}

static int mean_error(ts_search *search, int set, const ts_window *shape, const ts_plane *img,
                      const point *pts, uint32_t n, double *mean, char *err) {
  *mean = 0.0;
  if (n == 0) return 0;
  uint32_t *q = malloc(sizeof(uint32_t) * n);
  ts_l1_best *best = malloc(sizeof(ts_l1_best) * n);
  if (q == NULL || best == NULL) {
    free(q);
    free(best);
    return ts_error(err, TS_ENOMEM, "out of memory");
  }
  for (uint32_t i = 0; i < n; i++) q[i] = (uint32_t)pts[i].y * (uint32_t)img->w + (uint32_t)pts[i].x;
  ts_query_batch b = {n, q, 0, NULL, 0};
  int rc = ts_search_query(search, set, &b, best, err);
  double sum = 0.0;
  for (uint32_t i = 0; rc == 0 && i < n; i++) sum += (double)best[i].dist;
  *mean = sum / n / shape->spec.noff[TS_SRC_FINE];
  free(q);
  free(best);
  return rc;
}

int ts_quality_measure(ts_search *search, const ts_plane *ref, const ts_plane *img, int wn,
                       uint32_t samples, uint64_t seed, ts_quality *q, char *err) {
  ts_window shape;
  ts_anchors grid;
  int rc = ts_neigh_window(&shape, TS_SHAPE_SQUARE, wn, 1, 0, 1, 1.0, err);
  if (rc != 0) return rc;
  rc = ts_anchors_init(&grid, &shape, ref->w, ref->h, 0, 0, NULL, 1, NULL, err);
  int half = wn / 2, set = -1;
  point *pts = malloc(sizeof(point) * (samples ? samples : 1));
  if (rc == 0 && pts == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory");
  ts_levelplanes lp = {{ref}, {NULL}};
  /* The measured image is the query image: windows at points of it. */
  ts_replica_desc d = {.w = img->w, .h = img->h, .nplanes = 1, .fine = {img->px}};
  int image = -1;
  if (rc == 0) rc = ts_search_image_open(search, &d, &image, err);
  ts_refset rs = {image, &shape, &grid, &lp, NULL, NULL, 0, NULL};
  if (rc == 0) rc = ts_search_prepare(search, &rs, &set, err);
  if (rc == 0) {
    /* Windows are centred on the point: a W_B = 1 "block" at (x, y). */
    q->n_seam = seam_points(img, half, samples, pts);
    rc = mean_error(search, set, &shape, img, pts, q->n_seam, &q->mean_seam, err);
  }
  if (rc == 0) {
    q->n_inner = inner_points(img, half, samples, seed, pts);
    rc = mean_error(search, set, &shape, img, pts, q->n_inner, &q->mean_inner, err);
  }
  if (set >= 0) ts_search_release(search, set);
  if (image >= 0) ts_search_image_close(search, image);
  free(pts);
  ts_anchors_free(&grid);
  ts_window_free(&shape);
  return rc;
}

int ts_shuffle_blocks(const ts_plane *src, int w, int h, int bs, uint64_t seed,
                      uint32_t *copy_map) {
  if (bs < 1 || bs > src->w || bs > src->h) return TS_EINVAL;
  ts_rng rng;
  ts_rng_seed(&rng, seed, 0x5b);
  for (int by = 0; by < h; by += bs)
    for (int bx = 0; bx < w; bx += bs) {
      int sx = (int)ts_rng_below(&rng, (uint32_t)(src->w - bs + 1));
      int sy = (int)ts_rng_below(&rng, (uint32_t)(src->h - bs + 1));
      for (int dy = 0; dy < bs && by + dy < h; dy++)
        for (int dx = 0; dx < bs && bx + dx < w; dx++) {
          long o = (long)(by + dy) * w + bx + dx;
          copy_map[2 * o] = (uint32_t)(sx + dx);
          copy_map[2 * o + 1] = (uint32_t)(sy + dy);
        }
    }
  return 0;
}
